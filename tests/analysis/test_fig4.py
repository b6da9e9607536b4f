"""Fig. 4's files: the CSV and the figure, written atomically and reproducibly."""

from __future__ import annotations

import csv
from pathlib import Path

from tests.analysis.test_scan_agreement import run, scans
from toolkit.analysis.fig4 import CSV_HEADER, CSV_NAME, PNG_NAME, write_fig4


def test_the_files_are_written_atomically_and_reproducibly(tmp_path: Path) -> None:
    times = [0.25 * k for k in range(30)]
    result = run([scans(times, rate_m_per_s=0.03, lasers=["/a", "/b"] * 15)], min_bin_pairs=1)
    csv_a, png_a = write_fig4(result, tmp_path / "a", "synthetic")
    csv_b, png_b = write_fig4(result, tmp_path / "b", "synthetic")
    assert (csv_a.name, png_a.name) == (CSV_NAME, PNG_NAME)
    assert csv_a.read_bytes() == csv_b.read_bytes()
    assert png_a.read_bytes() == png_b.read_bytes()
    assert png_a.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == sorted([CSV_NAME, PNG_NAME])
    rows = list(csv.DictReader(csv_a.open()))
    assert tuple(rows[0]) == CSV_HEADER
    assert {r["pairs"] for r in rows} == {"all", "same_laser", "different_laser"}
    assert sum(int(r["count"]) for r in rows if r["pairs"] == "all") == result.pairs
