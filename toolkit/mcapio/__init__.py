"""mcapio"""
