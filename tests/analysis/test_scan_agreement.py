"""Fig. 4 from the log itself: z-difference between scans of the same ground against the time
between them (paper sect. 3, Fig. 4)."""

from __future__ import annotations

from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest

from toolkit.analysis.fig4 import (
    ScanAgreementConfig,
    ScanAgreementResult,
    write_fig4,
)
from toolkit.analysis.scan_agreement import ScanAgreement, scan_agreement_of
from toolkit.errors import ConfigError, StageError
from toolkit.workspace import Workspace

SAMPLE_LOG = Path(__file__).resolve().parents[2] / "sample_logs" / "sample.mcap"
T0 = 1_128_783_600_000_000_000
BEAM_NS = 18_519  # 1/75 s / 720, as a 181-beam scan of Stanley's lasers


def scans(
    scan_times_s: list[float],
    *,
    lasers: list[str] | None = None,
    x0: float = 5.0,
    beams: int = 40,
    rate_m_per_s: float = 0.0,
    dx_per_scan: float = 0.0,
) -> dict[str, np.ndarray]:
    """Points of scans in stream order: scan k at ``T0 + scan_times_s[k]``, its beams along
    y every 0.2 m at x = ``x0 + k dx_per_scan`` (cell centres for 0.2 m cells), on a flat
    plane whose height rises ``rate_m_per_s`` with time (a pose drifting in z)."""
    names = ("t_ns", "laser", "beam", "x", "y", "z", "scan_t_ns")
    rows: dict[str, list[np.ndarray]] = {c: [] for c in names}
    for k, ts in enumerate(scan_times_s):
        b = np.arange(beams)
        scan_t = T0 + round(ts * 1e9)
        t = scan_t + b * BEAM_NS
        rows["t_ns"].append(t.astype(np.int64))
        rows["laser"].append(np.full(beams, (lasers or ["/laser/a"] * len(scan_times_s))[k]))
        rows["beam"].append(b)
        rows["x"].append(np.full(beams, x0 + k * dx_per_scan + 0.1))
        rows["y"].append(b * 0.2 + 0.1)
        rows["z"].append(rate_m_per_s * (t - T0) * 1e-9)
        rows["scan_t_ns"].append(np.full(beams, scan_t, np.int64))
    return {c: np.concatenate(v) for c, v in rows.items()}


def cut(points: dict[str, np.ndarray], at: list[int]) -> list[dict[str, np.ndarray]]:
    """The stream cut into batches at row indices ``at`` (anywhere, also inside a scan)."""
    edges = [0, *at, points["t_ns"].size]
    return [{c: v[a:b] for c, v in points.items()} for a, b in pairwise(edges)]


def run(batches: list[dict[str, np.ndarray]], **config: float) -> ScanAgreementResult:
    acc = ScanAgreement(ScanAgreementConfig(**config))  # type: ignore[arg-type]
    for b in batches:
        acc.feed(b)
    return acc.result()


def test_a_linear_drift_in_z_is_recovered_as_the_slope() -> None:
    """A vehicle standing still over a flat plane whose projected height drifts 5 cm/s: every
    pair of scans of a cell differs by exactly 0.05 dt. The all-pairs fit is exact; the fit of
    the bin medians is exact to the 1 mm histogram bins."""
    times = [0.5 * k for k in range(30)]  # 15 s: the 10 s window cuts the longest pairs
    result = run([scans(times, rate_m_per_s=0.05)], pairs_per_observation=30)
    allp = result.classes["all"]
    assert result.pairs_beyond_max_dt == 0
    assert allp.fit_pairs.slope_m_per_s == pytest.approx(0.05, rel=1e-9)
    assert allp.fit_pairs.intercept_m == pytest.approx(0.0, abs=1e-9)
    assert allp.fit_pairs.r2 == pytest.approx(1.0, abs=1e-9)
    assert allp.fit_medians.slope_m_per_s == pytest.approx(0.05, abs=2e-4)
    assert allp.fit_medians.intercept_m == pytest.approx(0.0, abs=1e-3)
    assert allp.fit_medians.r2 > 0.9999
    np.testing.assert_allclose(allp.mean_abs_dz_m, 0.05 * allp.mean_dt_s, atol=1e-9)
    np.testing.assert_allclose(allp.mean_dz_m, allp.mean_abs_dz_m)  # later is higher
    # Pairs at 0.5, 1.0, ..., 9.5 s apart (beam times: scan stamps + the same beam offset).
    np.testing.assert_allclose(allp.mean_dt_s, 0.5 * np.arange(1, 20), atol=1e-9)
    # 34 flat cells (3 beams at each end of a scan line are left out); scan k pairs with the
    # min(k, 19) scans less than 10 s before it.
    assert result.pairs == 34 * sum(min(k, 19) for k in range(30))
    assert (allp.count > 0).all() and allp.count.sum() == result.pairs
    assert result.classes["different_laser"].count.size == 0


def test_pairs_per_observation_are_spread_over_the_window() -> None:
    times = [0.1 * k for k in range(101)]  # the last scan has 100 candidates in 10 s
    result = run([scans(times, beams=5)], pairs_per_observation=4, flat_window_beams=0)
    assert result.pairs == 5 * sum(min(k, 4) for k in range(101))
    # Scan 100 (t = 10 s) has the 99 scans from 0.1 s on as candidates: it takes ranks
    # 12, 37, 61, 86 of them, 8.7, 6.2, 3.8 and 1.3 s before it.
    dts = sorted({round(b, 1) for b in result.classes["all"].dt_lo_s})
    assert {8.7, 6.2, 3.8, 1.3} <= set(dts)


def test_no_pair_is_made_within_a_scan_even_across_a_batch_boundary() -> None:
    """One scan whose 100 beams fall in 3 cells, cut into batches mid-scan: one observation
    per cell, no pair."""
    one = scans([0.0], beams=100)
    one["y"] = np.repeat([0.1, 0.3, 0.5], [30, 30, 40])
    for batches in ([one], cut(one, [10, 55, 99])):
        result = run(batches, flat_window_beams=0)
        assert result.pairs == 0 and result.observations == 3 and result.points == 100


def test_lasers_are_classed_same_or_different() -> None:
    pts = scans([0.0, 0.3, 0.6, 0.9], lasers=["/l/far", "/l/far", "/l/near", "/l/near"])
    result = run([pts])
    same, diff = result.classes["same_laser"], result.classes["different_laser"]
    # far-far (0.3 s), near-near (0.3 s), and 4 far-near pairs (0.3, 0.6, 0.6, 0.9 s).
    assert same.pairs_total == 2 * 34 and diff.pairs_total == 4 * 34  # 34 flat cells
    np.testing.assert_allclose(same.mean_dt_s, [0.3], atol=1e-6)
    np.testing.assert_allclose(diff.mean_dt_s, [0.3, 0.6, 0.9], atol=1e-6)
    np.testing.assert_array_equal(diff.count, [34, 68, 34])


def test_the_result_does_not_depend_on_how_the_stream_is_batched() -> None:
    rng = np.random.default_rng(7)
    times = np.cumsum(rng.uniform(0.005, 0.05, 400)).tolist()
    names = [f"/laser/{k}" for k in rng.integers(0, 3, 400)]
    pts = scans(times, lasers=names, rate_m_per_s=0.02, dx_per_scan=0.01, beams=30)
    pts["z"] = pts["z"] + rng.normal(0, 0.003, pts["z"].size)
    whole = run([pts], max_dt_s=2.0)
    cuts = sorted(rng.choice(pts["t_ns"].size, 25, replace=False).tolist())
    pieces = run(cut(pts, cuts), max_dt_s=2.0)
    assert whole.pairs == pieces.pairs > 10_000
    for name, a in whole.classes.items():
        b = pieces.classes[name]
        np.testing.assert_array_equal(a.count, b.count)
        np.testing.assert_array_equal(a.median_abs_dz_m, b.median_abs_dz_m)
        np.testing.assert_allclose(a.mean_abs_dz_m, b.mean_abs_dz_m, rtol=1e-12)


def test_cells_older_than_the_window_are_evicted() -> None:
    """A cell seen at 0 s, then ground elsewhere for 20 s, then the cell again: its first
    observation is gone after 10 s, and no pair spans the gap. Memory stays at one window."""
    acc = ScanAgreement(ScanAgreementConfig(max_dt_s=10.0))
    acc.feed(scans([0.0], x0=0.0))
    elsewhere = [1.0 + 0.1 * k for k in range(200)]  # a moving vehicle: new cells each scan
    for k in range(0, 200, 20):
        acc.feed(scans(elsewhere[k : k + 20], x0=100.0 + 0.2 * k, dx_per_scan=0.2))
    # Held: the scans of the last 10 s (100 of them, 40 cells each), not the one at 0 s.
    assert acc.live_observations <= 101 * 40
    acc.feed(scans([21.5], x0=0.0))
    result = acc.result()
    assert result.pairs == 0
    assert result.max_live_observations <= 102 * 40


def test_bad_input_is_refused() -> None:
    with pytest.raises(ConfigError, match="cell_m"):
        ScanAgreementConfig(cell_m=0.0)
    with pytest.raises(ConfigError, match="pairs_per_observation"):
        ScanAgreementConfig(pairs_per_observation=0)
    acc = ScanAgreement()
    acc.feed(scans([1.0]))
    with pytest.raises(StageError, match="scan order"):
        acc.feed(scans([0.5]))
    with pytest.raises(StageError, match="no column 'beam'"):
        ScanAgreement().feed({c: v for c, v in scans([0.0]).items() if c != "beam"})
    acc = ScanAgreement()
    acc.result()
    with pytest.raises(StageError, match="after result"):
        acc.feed(scans([0.0]))


# --------------------------------------------------------------------------------------
# The sample log
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sample_points(sample_projected: tuple[Path, str]) -> Path:
    """The sample log's points.parquet (shared, read-only)."""
    root, log_id = sample_projected
    return Workspace(root).log_table(log_id, "points")


def test_fig4_of_the_sample_log(sample_points: Path, tmp_path: Path) -> None:
    """Measured (61 s, 4.1 M points, ~5 s): 6.7 M pairs of 2.4 M flat points; |dz| median
    0.6 cm at dt < 0.1 s, 7.5 cm at 2 s; fit 2.4 cm/s dt + 1.5 cm, r2 0.77."""
    result = scan_agreement_of(sample_points)
    allp = result.classes["all"]
    assert result.points > 4_000_000
    assert result.flat_points > result.points // 3
    assert result.pairs > 1_000_000
    assert (allp.count > 0).all() and allp.count.sum() == result.pairs
    for bins in result.classes.values():
        assert (bins.count > 0).all()
    fit = result.fit
    assert np.isfinite([fit.slope_m_per_s, fit.intercept_m, fit.r2]).all()
    # The pose drifts: scans seconds apart disagree more than consecutive ones.
    assert fit.slope_m_per_s > 0.005 and fit.r2 > 0.5
    assert allp.median_abs_dz_m[0] < allp.median_abs_dz_m[allp.mean_dt_s > 1.5][0]
    # Memory: about one 10 s window of observations.
    assert result.max_live_observations < 68_000 * 10 * 1.2
    csv_path, png_path = write_fig4(result, tmp_path, "sample")
    assert csv_path.stat().st_size > 1000 and png_path.stat().st_size > 10_000
