"""Entry point for ``python -m toolkit``."""

from toolkit.cli import entry

entry()
