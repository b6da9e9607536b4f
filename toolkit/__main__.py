"""Entry point for ``python -m toolkit``."""

from toolkit.launch import entry

entry()
