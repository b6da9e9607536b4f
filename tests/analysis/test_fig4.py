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


def test_the_fit_is_drawn_over_the_gaps_that_hold_95_percent_of_the_pairs() -> None:
    """Bins of 1 s: 900 pairs under 1 s, 60 under 2 s, then a few out to 7 s: the fit,
    weighted by pairs, is drawn to 2 s (where 95 % of the pairs are counted), not to 7 s,
    where the sparse bins' medians lie far below it; bins the fit did not use are left out."""
    import numpy as np

    from toolkit.analysis.fig4 import Fig4Bins, LinearFit, fit_reach_s

    edges = np.arange(8.0)
    count = np.array([900, 60, 15, 10, 8, 4, 3])
    nan = np.full(7, np.nan)
    fit = LinearFit(0.01, 0.01, 0.9, 7)
    bins = Fig4Bins(
        "all", edges[:-1], edges[1:], count, edges[:-1] + 0.5, nan, nan, nan, nan, nan,
        fit, fit, fit,
    )  # fmt: skip
    assert fit_reach_s(bins, count >= 1) == 2.0
    assert fit_reach_s(bins, count >= 1000) == 7.0  # nothing used: every bin's reach
    assert fit_reach_s(bins, count >= 10) == 2.0
