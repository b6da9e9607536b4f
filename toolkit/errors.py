"""The toolkit's error family.

Every error a user can cause is a :class:`ToolkitError`. Its message names the file (or
configuration key) and the offending value, so the command line can print it as one clear
line and exit 1. Programming errors are ordinary Python exceptions and keep their traceback.
"""

from __future__ import annotations

from pathlib import Path


class ToolkitError(Exception):
    """Root of every error the toolkit raises on bad input or a failed stage."""

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        self.path = None if path is None else Path(path)
        super().__init__(f"{self.path}: {message}" if self.path is not None else message)

    def moved(self, old: Path, new: Path) -> None:
        """Name ``new`` wherever the error names ``old`` (a path or a directory above it): a
        stage works in a hidden copy of a log's directory, but the user knows it by its
        public name (see :mod:`toolkit.generations`)."""
        if self.path is not None and self.path.is_relative_to(old):
            self.path = new / self.path.relative_to(old)
        self.args = tuple(
            a.replace(str(old), str(new)) if isinstance(a, str) else a for a in self.args
        )


class ConfigError(ToolkitError):
    """A configuration file or value is unusable (names the key and the value)."""


class LogReadError(ToolkitError):
    """An MCAP log cannot be read at all (nothing usable in it)."""


class SchemaError(ToolkitError):
    """A message definition or table schema is missing or malformed."""


class CdrError(ToolkitError):
    """A CDR payload does not match its message layout."""


class WorkspaceError(ToolkitError):
    """The workspace is missing, locked or inconsistent."""


class StageError(ToolkitError):
    """A pipeline stage failed on its inputs."""


class SimulationError(ToolkitError):
    """The simulator was asked for something it cannot produce."""


class CloudError(CdrError):
    """A ``sensor_msgs/PointCloud2`` of one topic cannot be read; carries ``topic`` and
    ``problem`` (one line, what is wrong) as well as the message naming both."""

    def __init__(self, topic: str, problem: str) -> None:
        self.topic = topic
        self.problem = problem
        super().__init__(f"topic {topic}: {problem}")

    def __reduce__(self) -> tuple[type[CloudError], tuple[str, str]]:
        # Rebuilt from its data, not from the formatted message, so it crosses processes.
        return (type(self), (self.topic, self.problem))


class CloudPayloadError(CloudError):
    """A PointCloud2 payload is truncated or its CDR is inconsistent (bad header, string)."""


class CloudLayoutError(CloudError):
    """A PointCloud2's point layout is unusable: overlapping or unknown fields, no x/y/z,
    steps that do not fit its data, or a time field the caller asked for that is missing."""
