"""The paper's Fig. 5 (Sect. 5.2): peak shock over a static obstacle against speed, a line.

Stavens & Thrun find the peak vertical acceleration over one obstacle driven at several
speeds "approximated tightly by a linear function", which is why the ruggedness coefficient
divides shock by speed. The simulator's ``calibration`` profile drives one ridge (five
identical copies) at five constant speeds; :func:`obstacle_passes` finds each pass in a
log's events by the truth columns the label stage adds (events whose rear tyres are on the
ridge), and takes its peak shock over the whole pass: from the front wheels
``before_m`` short of the obstacle (a wheelbase ahead of the rear ones) until the rear
wheels are ``after_m`` past it, since the IMU above the rear axle feels both axles' hits.
:func:`fit_line` fits ``peak_g = slope * speed_mph + intercept`` by least squares with
``r^2 = 1 - SS_res / SS_tot``.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from toolkit.arrays import FloatArray
from toolkit.atomic import atomic_write_bytes, atomic_write_text


@dataclass(frozen=True)
class LineFit:
    """``y = slope * x + intercept`` over ``n`` points, and its coefficient of determination."""

    slope: float
    intercept: float
    r2: float
    n: int

    def to_json(self) -> dict[str, float | int]:
        """A JSON-ready dict (for the manifest)."""
        return {
            "slope_g_per_mph": round(self.slope, 6),
            "intercept_g": round(self.intercept, 6),
            "r2": round(self.r2, 6),
            "passes": self.n,
        }


def fit_line(x: FloatArray, y: FloatArray) -> LineFit:
    """Least-squares line through (x (K,), y (K,)), K >= 2 with x not all equal
    (ValueError otherwise); r^2 is 1 when y is constant and fitted exactly."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    if x.size < 2 or np.ptp(x) == 0.0:
        raise ValueError(f"a line needs two distinct x values, got {x.tolist()}")
    slope, intercept = np.polyfit(x, y, 1)
    ss_res = float(np.sum((y - (slope * x + intercept)) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else 1.0
    return LineFit(float(slope), float(intercept), r2, int(x.size))


@dataclass(frozen=True)
class ObstaclePass:
    """One pass over an obstacle: where (route of the events, m), how fast (mean speed of
    the events with the rear tyres on it, mph) and the peak shock over the pass (G)."""

    s_m: float
    speed_mph: float
    peak_g: float


def obstacle_passes(
    s_start_m: FloatArray,
    s_end_m: FloatArray,
    speed_mph: FloatArray,
    shock_g: FloatArray,
    truth_kind: Sequence[str | None],
    wheelbase_m: float,
    *,
    kind: str = "ridge",
    before_m: float = 1.0,
    after_m: float = 5.0,
) -> list[ObstaclePass]:
    """The passes over obstacles of ``kind`` in a log's events (arrays (E,) in path order).

    Events with ``truth_kind == kind`` less than one event apart form one pass; its peak is
    the largest ``shock_g`` of the events overlapping
    ``[first start - wheelbase_m - before_m, last end + after_m]``.
    """
    on = np.flatnonzero(np.asarray([k == kind for k in truth_kind], dtype=bool))
    if on.size == 0:
        return []
    length = float(np.median(s_end_m - s_start_m))
    groups: list[list[int]] = [[int(on[0])]]
    for i in on[1:].tolist():
        if s_start_m[i] - s_end_m[groups[-1][-1]] > length:
            groups.append([i])
        else:
            groups[-1].append(i)
    out = []
    for g in groups:
        lo = float(s_start_m[g[0]]) - wheelbase_m - before_m
        hi = float(s_end_m[g[-1]]) + after_m
        window = (s_end_m > lo) & (s_start_m < hi)
        out.append(
            ObstaclePass(
                s_m=0.5 * float(s_start_m[g[0]] + s_end_m[g[-1]]),
                speed_mph=float(np.mean(speed_mph[g])),
                peak_g=float(np.max(shock_g[window])),
            )
        )
    return out


def fig5_csv(passes: Sequence[ObstaclePass], fit: LineFit) -> str:
    """One row per pass: s_m, speed_mph, peak_g, fitted_g."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["s_m", "speed_mph", "peak_g", "fitted_g"])
    for p in passes:
        fitted = fit.slope * p.speed_mph + fit.intercept
        w.writerow([f"{p.s_m:.3f}", f"{p.speed_mph:.4f}", f"{p.peak_g:.5f}", f"{fitted:.5f}"])
    return buf.getvalue()


def fig5_png(passes: Sequence[ObstaclePass], fit: LineFit, title: str) -> bytes:
    """The figure as PNG bytes (Agg canvas, no global pyplot state, no timestamp in the
    file, so the same passes give the same bytes)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.0, 3.6), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    v = np.array([p.speed_mph for p in passes])
    g = np.array([p.peak_g for p in passes])
    ax.plot(v, g, "o", label="peak shock over the obstacle")
    xs = np.linspace(0.0, float(v.max()) * 1.1, 50)
    ax.plot(
        xs,
        fit.slope * xs + fit.intercept,
        "-",
        label=f"{fit.slope:.4f} G/mph · v {fit.intercept:+.3f} G, r² = {fit.r2:.3f}",
    )
    ax.set_xlabel("speed (mph)")
    ax.set_ylabel("peak filtered vertical acceleration (G)")
    ax.set_title(title, fontsize=9)
    ax.set_xlim(left=0.0)
    ax.set_ylim(bottom=0.0)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


def write_fig5(
    csv_path: Path, png_path: Path, passes: Sequence[ObstaclePass], fit: LineFit, title: str
) -> None:
    """Write the CSV and the PNG, each atomically."""
    atomic_write_text(csv_path, fig5_csv(passes, fit))
    atomic_write_bytes(png_path, fig5_png(passes, fit, title))


__all__ = [
    "LineFit",
    "ObstaclePass",
    "fig5_csv",
    "fig5_png",
    "fit_line",
    "obstacle_passes",
    "write_fig5",
]
