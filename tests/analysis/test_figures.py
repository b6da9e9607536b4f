"""The analyses' shared writers: atomic, reproducible, and readable as the umask allows."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from toolkit.analysis.figures import new_figure, save_png_atomic, write_csv_atomic


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o077])
def test_report_files_get_the_users_umask(tmp_path: Path, mask: int) -> None:
    """A PNG or CSV of the report has the mode a plain open gives (0666 less the umask),
    not a temporary file's 0600, and no temporary file is left beside it."""
    old = os.umask(mask)
    try:
        png = save_png_atomic(new_figure(), tmp_path / "sub" / "roc.png")
        csv_path = write_csv_atomic(tmp_path / "t.csv", ["a"], [[1.5]])
    finally:
        os.umask(old)
    for path in (png, csv_path):
        assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~mask
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["roc.png", "sub", "t.csv"]
