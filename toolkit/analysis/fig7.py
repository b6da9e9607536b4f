"""The paper's Fig. 7 (Sect. 7.2) drawn and tabulated: shock against completion time.

The speed-control computation is :mod:`toolkit.model.speed_control`; this module writes its
trade-off curves as the report's CSV (one row per point, its Pareto front marked) and PNG.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from toolkit.analysis.figures import new_figure, save_png_atomic, write_csv_atomic
from toolkit.model.speed_control import METHOD_LABELS, TradeoffPoint, pareto_front

CSV_NAME = "speed_tradeoff.csv"
PNG_NAME = "speed_tradeoff.png"
CSV_HEADER = (
    "method",
    "slow_fraction",
    "recovery_mps2",
    "time_s",
    "shock_g",
    "time_norm",
    "shock_norm",
    "on_front",
)


def _front_ids(curve: Sequence[TradeoffPoint]) -> set[int]:
    return {id(p) for p in pareto_front(curve)}


def write_tradeoff_csv(out_dir: Path, curves: Sequence[Sequence[TradeoffPoint]]) -> Path:
    """Write ``out_dir / CSV_NAME``: one row per point of every curve, in the given order,
    columns :data:`CSV_HEADER`; ``on_front`` is whether the point is on its own curve's
    Pareto front. The no-change run has no slow fraction or recovery (empty cells)."""
    rows: list[tuple[object, ...]] = []
    for curve in curves:
        front = _front_ids(curve)
        for p in curve:
            used = p.method != "no_change"
            rows.append(
                (
                    p.method,
                    float(p.params.slow_fraction) if used else math.nan,
                    float(p.params.recovery_mps2) if used else math.nan,
                    p.time_s,
                    p.shock_g,
                    p.time_norm,
                    p.shock_norm,
                    "true" if id(p) in front else "false",
                )
            )
    return write_csv_atomic(Path(out_dir) / CSV_NAME, CSV_HEADER, rows)


def tradeoff_png(out_dir: Path, curves: Sequence[Sequence[TradeoffPoint]], title: str = "") -> Path:
    """Draw Fig. 7 to ``out_dir / PNG_NAME``: every point of each curve faintly, its Pareto
    front as a line, normalised shock against normalised completion time, and the no-change
    run at (1, 1)."""
    fig = new_figure()
    ax = fig.add_subplot(1, 1, 1)
    floor = next((p.params.shock_floor_g for c in curves for p in c), 0.0)
    for curve in curves:
        if not curve:
            continue
        method = curve[0].method
        label = METHOD_LABELS.get(method, method)
        if method == "no_change":
            ax.plot(
                [p.time_norm for p in curve],
                [p.shock_norm for p in curve],
                "k*",
                ms=10,
                label=label,
            )
            continue
        (line,) = ax.plot(
            [p.time_norm for p in pareto_front(curve)],
            [p.shock_norm for p in pareto_front(curve)],
            "-o",
            ms=4,
            label=label,
        )
        ax.plot(
            [p.time_norm for p in curve],
            [p.shock_norm for p in curve],
            ".",
            color=line.get_color(),
            alpha=0.3,
        )
    ax.set_xlabel("completion time / no speed change")
    what = "shock experienced" if floor == 0 else f"shock above {floor:g} G"
    ax.set_ylabel(f"{what} / no speed change")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")
    ax.set_title(title or "Fig. 7: shock against completion time (Sect. 7.2)")
    fig.tight_layout()
    return save_png_atomic(fig, Path(out_dir) / PNG_NAME)


__all__ = ["CSV_HEADER", "CSV_NAME", "PNG_NAME", "tradeoff_png", "write_tradeoff_csv"]
