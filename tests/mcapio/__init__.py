"""Tests of toolkit.mcapio (a package so its conftest cannot clash with others)."""
