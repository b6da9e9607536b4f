"""Shared output helpers of the analyses: CSV tables and matplotlib figures, written
atomically and byte for byte reproducibly.

A file appears only when complete (contract: written aside, then renamed), through the
workspace's one atomic writer (:func:`toolkit.atomic.atomic_write_bytes`). PNGs carry no
``Software`` or date chunk, so the same figure from the same data gives the same bytes.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from toolkit.atomic import atomic_write_bytes

if TYPE_CHECKING:
    from matplotlib.figure import Figure

#: PNG metadata that keeps the file reproducible: no matplotlib version, no timestamp.
PNG_METADATA: dict[str, str | None] = {"Software": None}


def write_bytes_atomic(path: Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically, creating its directory if needed: the one
    writer of :func:`toolkit.atomic.atomic_write_bytes` (aside, fsync, rename), so a
    figure gets the mode a plain ``open`` gives (0666 less the umask), as the Parquet and
    JSON beside it do. Returns ``path``."""
    atomic_write_bytes(path, data)
    return path


def format_value(value: object) -> str:
    """A CSV cell: floats with 9 significant digits (enough to round-trip the millimetres and
    milliseconds these tables hold, short enough to diff), NaN as empty, the rest as str."""
    if isinstance(value, float):
        return "" if value != value else format(value, ".9g")
    return str(value)


def write_csv_atomic(path: Path, header: Sequence[str], rows: Iterable[Sequence[object]]) -> Path:
    """A CSV table (``header`` then ``rows``), written atomically; see :func:`format_value`."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        writer.writerow([format_value(v) for v in row])
    return write_bytes_atomic(path, buf.getvalue().encode("utf-8"))


def new_figure(width_in: float = 7.0, height_in: float = 4.5) -> Figure:
    """A figure on the Agg canvas, independent of pyplot's global state and of any
    interactive backend the caller has selected."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def save_png_atomic(fig: Figure, path: Path) -> Path:
    """Render ``fig`` to PNG without version or date metadata and write it atomically."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata=PNG_METADATA)
    return write_bytes_atomic(path, buf.getvalue())


__all__ = [
    "PNG_METADATA",
    "format_value",
    "new_figure",
    "save_png_atomic",
    "write_bytes_atomic",
    "write_csv_atomic",
]
