"""The oracle's points (simulated logs only): the model's own patches with each point's z
replaced by the true terrain height where its beam truly hit, so that the model trained on
them bounds what better z alone could buy (pose, laser and range errors removed; the
points' places and times kept).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import scipy.fft
from numpy.typing import NDArray

from toolkit.analysis.truth_terrain import TrueGround, true_ground, where_beams_hit
from toolkit.arrays import FloatArray
from toolkit.model.patches import TyrePatches
from toolkit.model.roughness import THREADS
from toolkit.workspace import Workspace


def oracle_patches(
    workspace: Workspace, events: pa.Table, patches: TyrePatches
) -> TyrePatches | None:
    """``patches`` with each point's z replaced by the true terrain height where its beam
    truly hit (:func:`~toolkit.analysis.truth_terrain.where_beams_hit`: the point moved by
    the pose's error at its time), or None unless every log is simulated. Points off the
    modelled terrain are dropped.

    The points stay where they are (the same points, under the same tyres, as the model
    scores): only their heights change. Looking the truth up under the point's *estimated*
    position instead read the ground 16 cm (median) beside what the laser saw, and cost the
    oracle its lead (on tuning seeds 801/802, learned test AUC 0.887 there against 0.900 where
    the beams hit; the laser model 0.880: ``benchmarks/README.md``, "The oracle")."""
    log_of_group = np.repeat(np.asarray(events.column("log_id").to_pylist(), dtype=object), 2)
    z = patches.z.copy()
    valid = patches.valid.copy()
    for log_id in sorted(set(log_of_group.tolist())):
        ground = true_ground(workspace.log_dir(log_id))
        if ground is None:
            return None
        rows = np.flatnonzero(log_of_group == log_id)
        mask = patches.valid[rows]
        h = _true_heights(workspace.log_dir(log_id), ground, patches, rows, mask)
        sub = z[rows]
        sub[mask] = h
        z[rows] = sub
        sub_valid = valid[rows]
        sub_valid[mask] = np.isfinite(h)
        valid[rows] = sub_valid
    z[~valid] = 0.0
    return TyrePatches(
        patches.x,
        patches.y,
        z,
        patches.tau,
        patches.gamma,
        patches.psi,
        valid,
        valid.sum(axis=1),
        patches.laser,
        patches.lasers,
        patches.lead,
    )


def _true_heights(
    log_dir: Path,
    ground: TrueGround,
    patches: TyrePatches,
    rows: NDArray[np.intp],
    mask: NDArray[np.bool_],
) -> FloatArray:
    """The true terrain height, in the points' (pose) frame, where each valid point
    (``mask``) of the patches ``rows`` (one log's, in ``log_dir``) truly hit; NaN where the
    true pose does not cover its time or the terrain is not modelled."""
    xyz = np.c_[patches.x[rows][mask], patches.y[rows][mask], patches.z[rows][mask]]
    t_ns = np.round(patches.tau[rows][mask] * 1e9).astype(np.int64)
    hit = where_beams_hit(log_dir, xyz, t_ns)
    placed = np.isfinite(hit).all(axis=1)  # the true pose covers the point's time
    h = np.full(hit.shape[0], np.nan)
    # The terrain's tiles are synthesised by FFT (most of this lookup's time: ~30 s for
    # an hour's route); pocketfft splits each transform's independent lines over the
    # threads, so the heights are the same with one thread or two.
    with scipy.fft.set_workers(THREADS):
        h_sim, z_sim = ground.height_m(hit[placed])
    # The terrain's height comes in the simulator's frame; the points are in the pose's,
    # whose origin is elsewhere (2 m higher on the sample log). The hit point's height
    # above the terrain is the same in both, so the height in the points' frame is the
    # point's z less it: the oracle's patches stay in one frame with their x and y.
    h[placed] = hit[placed, 2] - (z_sim - h_sim)
    return h


__all__ = ["oracle_patches"]
