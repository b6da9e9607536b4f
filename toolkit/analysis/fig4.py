"""Fig. 4's parameters, results and files: the bins of pairs by the time between two scans of
the same ground, their statistics and fits, and the CSV and figure written from them.

The measurement itself (streaming, pairing, the reason for each choice) is
:mod:`toolkit.analysis.scan_agreement`'s. Statistics per ``dt`` bin, over its pairs: count,
mean ``dt``, mean / median / 90th percentile of ``|dz|`` (median and percentile from the
fixed histogram of ``|dz|``, :func:`~toolkit.analysis.histograms.histogram_quantile`, its
last bin the overflow), mean ``dz`` and RMS ``dz``. Fits (:class:`LinearFit`), ordinary or
weighted least squares of ``y = slope dt + intercept``::

    Sxx = sum w x^2 - (sum w x)^2 / W     Sxy = sum w x y - (sum w x)(sum w y) / W
    slope = Sxy / Sxx     intercept = (sum w y - slope sum w x) / W     r2 = Sxy^2 / (Sxx Syy)

(``W = sum w``): the figure's fit of the bin medians weighted by their pairs, the same
unweighted, and all pairs' ``|dz|`` from the accumulated sums.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from toolkit.analysis.figures import new_figure, save_png_atomic, write_csv_atomic
from toolkit.analysis.histograms import bins_covering, histogram_quantile
from toolkit.arrays import BoolArray, FloatArray, IntArray
from toolkit.errors import ConfigError

#: Pair classes, in the order of the accumulators' first axis.
SAME_LASER, DIFFERENT_LASER = 0, 1
CLASS_NAMES = ("same_laser", "different_laser")
#: Name of the class that adds both.
ALL_PAIRS = "all"
CSV_NAME = "fig4_z_difference_vs_dt.csv"
PNG_NAME = "fig4_z_difference_vs_dt.png"


@dataclass(frozen=True)
class ScanAgreementConfig:
    """Parameters of the Fig. 4 measurement (see the module docstring for each choice)."""

    cell_m: float = 0.2
    max_dt_s: float = 10.0
    bin_s: float = 0.1
    pairs_per_observation: int = 8
    flat_window_beams: int = 3
    max_slope: float = 0.1
    max_bump_m: float = 0.03
    dz_resolution_m: float = 0.001
    dz_max_m: float = 1.0
    min_bin_pairs: int = 30

    def __post_init__(self) -> None:
        positive = ("cell_m", "max_dt_s", "bin_s", "dz_resolution_m", "dz_max_m")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"scan agreement: {name} must be positive, got {value!r}")
        if self.pairs_per_observation < 1:
            raise ConfigError(
                "scan agreement: pairs_per_observation must be at least 1, "
                f"got {self.pairs_per_observation!r}"
            )
        if self.flat_window_beams < 0 or self.min_bin_pairs < 1:
            raise ConfigError(
                "scan agreement: flat_window_beams must be >= 0 and min_bin_pairs >= 1, got "
                f"{self.flat_window_beams!r}, {self.min_bin_pairs!r}"
            )
        if not (self.max_slope >= 0 and self.max_bump_m >= 0):
            raise ConfigError(
                "scan agreement: max_slope and max_bump_m must be >= 0, got "
                f"{self.max_slope!r}, {self.max_bump_m!r}"
            )

    @property
    def n_dt_bins(self) -> int:
        """Bins of ``bin_s`` covering ``[0, max_dt_s)`` (the last may reach past it)."""
        return bins_covering(self.max_dt_s, self.bin_s)

    @property
    def n_dz_bins(self) -> int:
        """Histogram bins of ``|dz|`` below ``dz_max_m``; one overflow bin follows them."""
        return bins_covering(self.dz_max_m, self.dz_resolution_m)


@dataclass(frozen=True)
class LinearFit:
    """``y = slope * dt + intercept`` by ordinary least squares over ``n`` points (bins or
    pairs); NaN when fewer than two distinct ``dt`` were available."""

    slope_m_per_s: float
    intercept_m: float
    r2: float
    n: int

    def describe(self) -> str:
        """E.g. ``|dz| = 0.41 cm/s dt + 1.20 cm (r2 0.93, 98 bins)``."""
        return (
            f"|dz| = {100 * self.slope_m_per_s:.3g} cm/s dt + {100 * self.intercept_m:.3g} cm "
            f"(r2 {self.r2:.3f}, n {self.n})"
        )


@dataclass(frozen=True, eq=False)
class Fig4Bins:
    """The non-empty ``dt`` bins of one pair class (``pairs``: ``"all"``, ``"same_laser"``
    or ``"different_laser"``); every array has shape (B,), B bins with at least one pair."""

    pairs: str
    dt_lo_s: FloatArray
    dt_hi_s: FloatArray
    count: IntArray
    mean_dt_s: FloatArray
    mean_abs_dz_m: FloatArray
    median_abs_dz_m: FloatArray
    p90_abs_dz_m: FloatArray
    mean_dz_m: FloatArray
    rms_dz_m: FloatArray
    #: The figure's fit: bin medians (bins of >= min_bin_pairs pairs) against mean dt, each
    #: bin weighted by its pairs.
    fit_medians: LinearFit
    #: The same with every bin weighing the same (the sparse long-dt bins count fully).
    fit_medians_unweighted: LinearFit
    #: All pairs' |dz| against dt.
    fit_pairs: LinearFit

    @property
    def pairs_total(self) -> int:
        return int(self.count.sum())


@dataclass(frozen=True, eq=False)
class ScanAgreementResult:
    """Fig. 4 of one log: the bins per pair class and what went into them."""

    config: ScanAgreementConfig
    #: "all", "same_laser", "different_laser".
    classes: Mapping[str, Fig4Bins]
    points: int
    flat_points: int
    observations: int
    pairs: int
    #: Pairs whose beam times were ``max_dt_s`` or more apart (pairs are windowed by scan
    #: stamps, and beam times can be a few ms farther apart); not binned.
    pairs_beyond_max_dt: int
    #: Most observations held at once (the bounded memory).
    max_live_observations: int
    seconds: float

    @property
    def fit(self) -> LinearFit:
        """The figure's fit over all pairs (bin medians against dt)."""
        return self.classes[ALL_PAIRS].fit_medians

    def summary(self) -> str:
        return (
            f"Fig. 4: {self.fit.describe()}; {self.pairs} pairs from {self.observations} "
            f"observations of {self.flat_points} flat points (of {self.points})"
        )


def fig4_bins(
    name: str,
    c: ScanAgreementConfig,
    count: IntArray,
    s: Mapping[str, FloatArray],
    hist: IntArray,
) -> Fig4Bins:
    """The non-empty bins of one pair class and their fits (module docstring) from its
    accumulators: pairs per ``dt`` bin ``count`` (B,), the per-bin sums ``s`` of ``dt``,
    ``dt^2``, ``|dz|`` (``abs``), ``dz``, ``dz^2``, ``dt |dz|`` (each (B,)), and the ``|dz|``
    histogram per bin ``hist`` (B, n_dz_bins + 1, the last the overflow)."""
    nz = np.flatnonzero(count)
    n = count[nz].astype(np.float64)
    lo = nz * c.bin_s
    median = np.array([_quantile(hist[b], 0.5, c.dz_resolution_m) for b in nz])
    p90 = np.array([_quantile(hist[b], 0.9, c.dz_resolution_m) for b in nz])
    mean_dt = s["dt"][nz] / n
    fit_ok = count[nz] >= c.min_bin_pairs
    weights = count[nz][fit_ok].astype(np.float64)
    fit_medians = _ols(mean_dt[fit_ok], median[fit_ok], weights)
    fit_medians_unweighted = _ols(mean_dt[fit_ok], median[fit_ok])
    fit_pairs = _ols_from_sums(
        float(count.sum()),
        float(s["dt"].sum()),
        float(s["dt2"].sum()),
        float(s["abs"].sum()),
        float(s["dt_abs"].sum()),
        float(s["dz2"].sum()),
    )
    return Fig4Bins(
        pairs=name,
        dt_lo_s=lo.astype(np.float64),
        dt_hi_s=np.minimum(lo + c.bin_s, max(c.max_dt_s, c.bin_s)).astype(np.float64),
        count=count[nz].astype(np.int64),
        mean_dt_s=mean_dt,
        mean_abs_dz_m=s["abs"][nz] / n,
        median_abs_dz_m=median.astype(np.float64),
        p90_abs_dz_m=p90.astype(np.float64),
        mean_dz_m=s["dz"][nz] / n,
        rms_dz_m=np.sqrt(s["dz2"][nz] / n),
        fit_medians=fit_medians,
        fit_medians_unweighted=fit_medians_unweighted,
        fit_pairs=fit_pairs,
    )


def _quantile(hist: IntArray, q: float, width: float) -> float:
    """Quantile ``q`` of ``|dz|`` in bins ``[k w, (k + 1) w)``, the last the overflow
    (reported at its lower edge)."""
    return histogram_quantile(hist, q, 0.0, width, open_low=False)


def _ols(x: FloatArray, y: FloatArray, w: FloatArray | None = None) -> LinearFit:
    """Least squares line through points (x, y), each of weight ``w`` (default 1); the
    fit's ``n`` is the number of points."""
    if x.size < 2 or np.ptp(x) == 0:
        return LinearFit(math.nan, math.nan, math.nan, int(x.size))
    w = np.ones_like(x) if w is None else np.asarray(w, np.float64)
    fit = _ols_from_sums(
        float(w.sum()),
        float((w * x).sum()),
        float((w * x * x).sum()),
        float((w * y).sum()),
        float((w * x * y).sum()),
        float((w * y * y).sum()),
    )
    return LinearFit(fit.slope_m_per_s, fit.intercept_m, fit.r2, int(x.size))


def _ols_from_sums(n: float, sx: float, sxx: float, sy: float, sxy: float, syy: float) -> LinearFit:
    """Least squares line from the sums: ``slope = Sxy / Sxx`` with the centred sums
    ``Sxx = sxx - sx^2/n``, ``Sxy = sxy - sx sy / n``; ``r2 = Sxy^2 / (Sxx Syy)``."""
    if n < 2:
        return LinearFit(math.nan, math.nan, math.nan, int(n))
    cxx = sxx - sx * sx / n
    cxy = sxy - sx * sy / n
    cyy = syy - sy * sy / n
    if cxx <= 0:
        return LinearFit(math.nan, math.nan, math.nan, int(n))
    slope = cxy / cxx
    intercept = (sy - slope * sx) / n
    r2 = cxy * cxy / (cxx * cyy) if cyy > 0 else math.nan
    return LinearFit(float(slope), float(intercept), float(r2), int(n))


CSV_HEADER = (
    "pairs",
    "dt_lo_s",
    "dt_hi_s",
    "count",
    "mean_dt_s",
    "mean_abs_dz_m",
    "median_abs_dz_m",
    "p90_abs_dz_m",
    "mean_dz_m",
    "rms_dz_m",
)


#: The share of the pairs over whose dt the fit is drawn: the fit weighs bins by their
#: pairs, so it speaks for the short gaps that hold most of them (95 % under 2 s on the
#: sample); drawn to the last bin (7 s) it overshot those bins' medians by 35-65 %.
FIT_DRAWN_SHARE = 0.95


def fit_reach_s(bins: Fig4Bins, usable: BoolArray) -> float:
    """How far along dt the figure draws the fit (s): the upper edge of the bin (among
    ``usable``, those the fit used) by which :data:`FIT_DRAWN_SHARE` of their pairs are
    counted, bins in order of dt."""
    if not usable.any():
        return float(bins.dt_hi_s.max())
    count = bins.count[usable].astype(np.float64)
    hi = bins.dt_hi_s[usable]
    order = np.argsort(hi)
    covered = np.cumsum(count[order]) / count.sum()
    k = int(np.searchsorted(covered, FIT_DRAWN_SHARE - 1e-12))
    return float(hi[order][min(k, hi.size - 1)])


def _draw_fit(ax: Any, bins: Fig4Bins, usable: BoolArray) -> None:
    """The fit of the medians on ``ax``, over the gaps it speaks for (:func:`fit_reach_s`)."""
    fit = bins.fit_medians
    if not (math.isfinite(fit.slope_m_per_s) and bins.count.size):
        return
    reach = fit_reach_s(bins, usable)
    xs = np.array([0.0, reach])
    ax.plot(
        xs,
        fit.intercept_m + fit.slope_m_per_s * xs,
        "-",
        color="black",
        lw=1.2,
        label=(
            "least-squares fit of the medians, bins weighted by pairs (drawn where "
            f"{100 * FIT_DRAWN_SHARE:.0f} % of the pairs lie, dt < {reach:.2g} s)"
        ),
    )


def write_fig4(result: ScanAgreementResult, out_dir: Path, log_id: str) -> tuple[Path, Path]:
    """Write :data:`CSV_NAME` (every non-empty bin of every pair class, one row each, columns
    :data:`CSV_HEADER`) and :data:`PNG_NAME` (bin medians of all pairs against dt with the
    fitted line, the two laser classes faintly behind) into ``out_dir``, each atomically.
    Returns the two paths."""
    out_dir = Path(out_dir)
    rows: list[tuple[object, ...]] = []
    for bins in result.classes.values():
        for k in range(bins.count.size):
            rows.append(
                (
                    bins.pairs,
                    float(bins.dt_lo_s[k]),
                    float(bins.dt_hi_s[k]),
                    int(bins.count[k]),
                    float(bins.mean_dt_s[k]),
                    float(bins.mean_abs_dz_m[k]),
                    float(bins.median_abs_dz_m[k]),
                    float(bins.p90_abs_dz_m[k]),
                    float(bins.mean_dz_m[k]),
                    float(bins.rms_dz_m[k]),
                )
            )
    csv_path = write_csv_atomic(out_dir / CSV_NAME, CSV_HEADER, rows)

    fig = new_figure()
    ax = fig.add_subplot(1, 1, 1)
    styles = {
        "same_laser": ("tab:orange", "same laser"),
        "different_laser": ("tab:green", "different lasers"),
    }
    for name, (colour, label) in styles.items():
        b = result.classes[name]
        ax.plot(
            b.mean_dt_s,
            b.median_abs_dz_m,
            ".",
            ms=3,
            color=colour,
            alpha=0.5,
            label=f"median |dz|, {label}",
        )
    allp = result.classes[ALL_PAIRS]
    ok = allp.count >= result.config.min_bin_pairs
    ax.plot(
        allp.mean_dt_s[ok],
        allp.median_abs_dz_m[ok],
        "o",
        ms=4,
        color="tab:blue",
        label=f"median |dz|, all pairs (bins of >= {result.config.min_bin_pairs})",
    )
    fit = allp.fit_medians
    _draw_fit(ax, allp, ok)
    ax.set_xlabel("time between the two scans, dt (s)")
    ax.set_ylabel("z-difference of the same ground cell, |dz| (m)")
    ax.set_xlim(left=0.0)
    ax.set_ylim(bottom=0.0)
    ax.grid(True, lw=0.3)
    ax.legend(loc="upper left", fontsize=7)
    ax.set_title(
        f"{log_id}: z-difference between scans of flat ground (cf. paper Fig. 4)\n"
        f"fit |dz| = {fit.slope_m_per_s:.4g} m/s x dt + {fit.intercept_m:.4g} m, "
        f"r2 = {fit.r2:.3f}; {result.pairs} pairs, {result.config.cell_m:g} m cells",
        fontsize=9,
    )
    fig.tight_layout()
    png_path = save_png_atomic(fig, out_dir / PNG_NAME)
    return csv_path, png_path


__all__ = [
    "ALL_PAIRS",
    "CLASS_NAMES",
    "CSV_HEADER",
    "CSV_NAME",
    "DIFFERENT_LASER",
    "PNG_NAME",
    "SAME_LASER",
    "Fig4Bins",
    "LinearFit",
    "ScanAgreementConfig",
    "ScanAgreementResult",
    "fig4_bins",
    "write_fig4",
]
