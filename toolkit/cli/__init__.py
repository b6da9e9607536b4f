"""The ``terrain`` command line: parses arguments, calls one stage, maps errors to exit codes.

Exit codes (the contract): 0 on success; 1 on bad input or a failed stage, with one line
``terrain: error: <message>`` on stderr and no traceback unless ``--debug``; 2 on usage
errors (click's own handling). Every verb registered on :data:`main` gets this mapping from
:class:`~toolkit.cli.base.TerrainGroup`, so a verb only raises
:class:`~toolkit.errors.ToolkitError`.

Verbs import their implementation lazily, so ``terrain --help`` stays fast and a verb's
heavy dependencies load only when it runs.

The modules: :mod:`~toolkit.cli.base` (global flags, exit codes, logging),
:mod:`~toolkit.cli.group` (the ``terrain`` group, :data:`main`), :mod:`~toolkit.cli.stages`
(one command per registered stage), :mod:`~toolkit.cli.batch` (``ingest`` and ``run``, the
executor and shard options), :mod:`~toolkit.cli.tools` (``sim``, ``info``, ``config init``,
``viz``, ``export``, ``logs``). Importing a command module registers its verbs on
:data:`main`.
"""

from toolkit.cli import batch, tools  # noqa: F401  (importing them registers their verbs)
from toolkit.cli.group import entry, main

__all__ = ["entry", "main"]
