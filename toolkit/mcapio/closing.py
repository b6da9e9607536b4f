"""The context manager the MCAP reader and writer share."""

from __future__ import annotations

from abc import ABC, abstractmethod
from types import TracebackType
from typing import Self


class Closing(ABC):
    """Used as a context manager: leaving ``with`` normally calls :meth:`close`, leaving it on
    an exception calls :meth:`abort` (which closes too, unless a subclass discards instead,
    as :class:`~toolkit.mcapio.writer.LogWriter` does)."""

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    @abstractmethod
    def close(self) -> None:
        """Finish and release the file."""

    def abort(self) -> None:
        """Give up on an exception: by default, close."""
        self.close()
