"""Tiny tyre patches for the model's tests, and eqs. (2)-(5) written out as plain loops."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pyarrow as pa

from toolkit.model.patches import TyrePatches, build_patches
from toolkit.model.roughness import RoughnessParams

#: One point: (x, y, z, tau, gamma, psi).
Point = tuple[float, float, float, float, float, float]


def events_table(n: int, log_id: str = "log") -> pa.Table:
    return pa.table({"log_id": [log_id] * n, "event_id": pa.array(range(n), pa.int64())})


COLUMNS = ("log_id", "event_id", "wheel", "x", "y", "z", "tau", "roll_rate", "pitch_rate",
           "laser", "t_ns")  # fmt: skip
FLOAT_COLUMNS = ("x", "y", "z", "tau", "roll_rate", "pitch_rate")


def points_table(
    patches: Sequence[Sequence[Sequence[Point]]], laser: str = "/laser/a", log_id: str = "log"
) -> pa.Table:
    """``patches[e][w]``: the points under wheel w (0 left, 1 right) of event e, as rows of
    ``tables/event_points.parquet``; a point's ``t_ns`` (its identity) comes from its tau."""
    rows = [
        (log_id, e, ("left", "right")[w], x, y, z, tau, gamma, psi, laser, round(tau * 1e9))
        for e, wheels in enumerate(patches)
        for w, pts in enumerate(wheels)
        for x, y, z, tau, gamma, psi in pts
    ]
    columns = list(zip(*rows, strict=True)) if rows else [()] * len(COLUMNS)

    def arrow_type(name: str) -> pa.DataType:
        if name in FLOAT_COLUMNS:
            return pa.float64()
        return pa.int64() if name in ("event_id", "t_ns") else pa.string()

    return pa.table(
        {n: pa.array(list(c), arrow_type(n)) for n, c in zip(COLUMNS, columns, strict=True)}
    )


def make_patches(patches: Sequence[Sequence[Sequence[Point]]], cap: int = 0) -> TyrePatches:
    return build_patches(events_table(len(patches)), points_table(patches), cap)


def delta_loop(a: Sequence[float], p: Point, q: Point) -> float:
    """Eq. (4), term by term."""
    dz = abs(p[2] - q[2])
    dt = abs(p[3] - q[3])
    dxy = math.hypot(p[0] - q[0], p[1] - q[1])
    return (
        a[0] * dz ** a[1]
        - a[2] * dt ** a[3]
        - a[4] * dxy ** a[5]
        - a[6] * abs(p[4]) ** a[7]
        - a[6] * abs(q[4]) ** a[7]
        - a[8] * abs(p[5]) ** a[9]
        - a[8] * abs(q[5]) ** a[9]
    )


def r_loop(points: Sequence[Point], params: RoughnessParams) -> float:
    """Eqs. (2) and (3) as sect. 4 words them: the N x N matrix S, times the lower triangular
    matrix of ones (zeros on and above the diagonal), its omega largest elements ascending,
    R = sum_i W_i upsilon^i, i = 0..omega-1; with decision 2, zeros without end (a small
    patch's matrix is padded with zeros to omega elements and beyond)."""
    n = len(points)
    masked = [
        delta_loop(params.alpha, points[r], points[c]) if r > c else 0.0
        for r in range(n)
        for c in range(n)
    ] + [0.0] * params.omega
    top = sorted(masked, reverse=True)[: params.omega]
    top += [0.0] * (params.omega - len(top))
    w = sorted(top)  # ascending
    return sum(w_i * params.upsilon**i for i, w_i in enumerate(w))


def combined_loop(left: float, right: float, zeta: float) -> float:
    """Eq. (5) with the signed power."""

    def sp(r: float) -> float:
        return math.copysign(abs(r) ** zeta, r) if r != 0 else 0.0

    return sp(left) + sp(right)


def random_patches(
    rng: np.random.Generator, events: int, max_points: int
) -> list[list[list[Point]]]:
    out = []
    for _ in range(events):
        wheels = []
        for _w in range(2):
            n = int(rng.integers(0, max_points + 1))
            wheels.append(
                [
                    (
                        float(rng.uniform(0, 1.4)),
                        float(rng.uniform(-0.3, 0.3)),
                        float(rng.normal(0, 0.05)),
                        float(rng.uniform(0, 3)),
                        float(rng.normal(0, 0.1)),
                        float(rng.normal(0, 0.1)),
                    )
                    for _ in range(n)
                ]
            )
        out.append(wheels)
    return out


def planted(
    rng: np.random.Generator, events: int, drift_m: tuple[float, float] | None = None
) -> tuple[list[list[list[Point]]], np.ndarray]:
    """Smooth events: a slow pose drift, 8 cm between points seen 2 s apart (as Fig. 4's
    error growing with time; with ``drift_m``, drawn uniformly from that range per event).
    Rough events: a 5 cm step between points seen 0.05 s apart. Height difference alone
    ranks the drift above the step; the time term (alpha_3 > 0) separates them."""
    out, labels = [], []
    for e in range(events):
        rough = e % 5 == 0
        drift = 0.08 if drift_m is None else float(rng.uniform(*drift_m))
        wheels = []
        for w in range(2):
            pts: list[Point] = []
            for k in range(8):
                x = 0.15 * k
                noise = float(rng.normal(0, 0.003))
                if rough and w == 0:
                    tau = 10.0 + 0.01 * k
                    z = (0.05 if k >= 4 else 0.0) + noise
                else:
                    tau = 10.0 + (2.0 if k >= 4 else 0.0) + 0.01 * k
                    z = (drift if k >= 4 else 0.0) + noise
                pts.append((x, 0.01 * w, z, tau, 0.0, 0.0))
            wheels.append(pts)
        out.append(wheels)
        labels.append(rough)
    return out, np.array(labels)
