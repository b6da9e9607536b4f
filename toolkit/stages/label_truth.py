"""What the simulator's truth says lies under the rear tyres during each event.

Simulated logs only (``truth_pose.parquet``, ``truth_features.parquet`` and the
``terrain_sim`` record in ``mcap_metadata.json``, all written by ingest). The features are
published in route coordinates ``(s, d)`` (distance along the route's centreline, lateral
offset left positive; :mod:`toolkit.sim.world`), so the true rear-tyre positions are put in
the same coordinates:

* the truth pose (base_link, on the ground below the rear-axle centre) is moved from the
  pose's frame back to the simulator's (through geodetic coordinates, the inverse of
  :func:`toolkit.stages.truth.truth_to_pose_frame`);
* the tyres sit ``+-track_m / 2`` along base_link's y axis (rotated by the true yaw);
* the route is rebuilt from the world parameters and seed the metadata records
  (:func:`toolkit.sim.world.make_world`, bit for bit the simulator's) and each tyre point
  projected onto it (:meth:`~toolkit.sim.world.Route.to_route`). The rebuilt route is checked
  against the features' published centres (within :data:`ROUTE_CHECK_M`); a mismatch (a log
  from another simulator version) leaves the truth out with a warning.

A feature lies under a tyre when the tyre's centre point is inside its footprint
``[s_start, s_end] x [d_center -+ width / 2]`` at a truth sample inside the event's time
span; the event carries the tallest such feature (``height_m``: the simulator's height,
depth or peak-to-peak of the kind) or none (height 0).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from toolkit.arrays import FloatArray, IntArray
from toolkit.errors import StageError
from toolkit.geometry.geodesy import GeodeticOrigin
from toolkit.geometry.map_frame import move_between_frames
from toolkit.layout import LogFiles
from toolkit.sim.record import SIM_RECORD, sim_origin
from toolkit.sim.route import Route
from toolkit.sim.world import make_world
from toolkit.sim.world_params import WorldParams
from toolkit.tableio import iter_table_batches, read_table_metadata

#: Largest distance (m) between a feature's published centre and the rebuilt route's point
#: at its (s, d): the simulator writes both from one route, so only another route differs.
ROUTE_CHECK_M = 0.01
#: Truth samples projected onto the route per step of the running guess.
_CHUNK = 256
FEATURE_COLUMNS = ("kind", "s_start_m", "s_end_m", "d_center_m", "width_m", "height_m")


@dataclass(frozen=True)
class TruthUnder:
    """Per event (E,): the tallest true feature under a rear tyre, height 0 and kind None
    when there is none."""

    height_m: FloatArray
    kind: list[str | None]


def _tuples(value: Any) -> Any:
    """JSON lists back to the tuples a frozen dataclass field holds."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


@dataclass
class _RouteCursor:
    """Where the last projected point of a path lay: its route distance and position (the
    running guess :func:`_route_coords` carries from one batch of the path to the next)."""

    s_m: float
    x_m: float
    y_m: float


def _route_coords(
    route: Route, x: FloatArray, y: FloatArray, cursor: _RouteCursor | None
) -> tuple[FloatArray, FloatArray, _RouteCursor | None]:
    """Route (s, d) of a path's points (K,), in path order, and the cursor to pass with the
    path's next points: the path's first point from the nearest centreline sample, later
    ones by Newton steps from the previous s plus the distance driven since (within a chunk
    that is within a few metres, where 3 steps reach mm). Batches of a multiple of
    :data:`_CHUNK` points give the same result as the whole path at once."""
    s_out = np.empty(x.size)
    d_out = np.empty(x.size)
    if x.size == 0:
        return s_out, d_out, cursor
    if cursor is None:
        nearest = int(np.argmin(np.hypot(route.x_m - x[0], route.y_m - y[0])))
        cursor = _RouteCursor(float(route.s_m[nearest]), float(x[0]), float(y[0]))
    s_prev, x_prev, y_prev = cursor.s_m, cursor.x_m, cursor.y_m
    for lo in range(0, x.size, _CHUNK):
        xs, ys = x[lo : lo + _CHUNK], y[lo : lo + _CHUNK]
        step = np.hypot(np.diff(np.r_[x_prev, xs]), np.diff(np.r_[y_prev, ys]))
        s, d = route.to_route(xs, ys, s_prev + np.cumsum(step))
        s_out[lo : lo + xs.size], d_out[lo : lo + xs.size] = s, d
        s_prev, x_prev, y_prev = float(s[-1]), float(xs[-1]), float(ys[-1])
    return s_out, d_out, _RouteCursor(s_prev, x_prev, y_prev)


def _origin(text: str | None) -> GeodeticOrigin | None:
    if text is None:
        return None
    o = json.loads(text)
    return GeodeticOrigin(
        float(o["latitude_deg"]), float(o["longitude_deg"]), float(o["altitude_m"])
    )


def truth_under_events(
    log_dir: Path, bounds_ns: IntArray, track_m: float
) -> tuple[TruthUnder | None, str | None]:
    """(what lies under the rear tyres in each event ``[bounds[k], bounds[k+1])``, a warning)
    for a simulated log; (None, None) for a real one; (None, warning) when the truth cannot be
    placed. ``bounds_ns`` (E + 1,) increasing."""
    files = LogFiles(log_dir)
    meta_path, truth_path, feat_path = files.mcap_metadata, files.truth_pose, files.truth_features
    if not (meta_path.is_file() and truth_path.is_file() and feat_path.is_file()):
        return None, None
    try:
        records = json.loads(meta_path.read_text(encoding="utf-8"))
        sim = records.get(SIM_RECORD)
        if not sim or "world" not in sim:
            return None, None
        params = WorldParams(**{k: _tuples(v) for k, v in json.loads(sim["world"]).items()})
        seed = int(sim["seed"])
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise StageError(
            f"not the simulator metadata ingest writes ({type(exc).__name__}: {exc}); "
            "run `terrain ingest --overwrite` on its log",
            path=meta_path,
        ) from exc
    route = make_world(params, seed).route
    # truth_features has no contract schema (ingest writes the simulator's message as is),
    # so tableio's schema-checked reader does not apply; read it plainly.
    feats = pq.read_table(feat_path, columns=[*FEATURE_COLUMNS, "x_m", "y_m"]).to_pydict()
    n_feat = len(feats["kind"])
    if n_feat:
        sc = 0.5 * (np.asarray(feats["s_start_m"]) + np.asarray(feats["s_end_m"]))
        cx, cy = route.to_world(sc, np.asarray(feats["d_center_m"], np.float64))
        miss = float(np.max(np.hypot(cx - np.asarray(feats["x_m"]), cy - np.asarray(feats["y_m"]))))
        if miss > ROUTE_CHECK_M:
            return None, (
                f"truth features lie up to {miss:.2f} m from the route rebuilt from the log's "
                "metadata (another simulator version?); events carry no truth"
            )
    frame_origin = _origin(read_table_metadata(truth_path).get("enu_origin"))
    sim_o = sim_origin(records)
    n_events = max(bounds_ns.size - 1, 0)
    under = _Under(n_events)
    if n_events == 0 or n_feat == 0:
        return TruthUnder(under.height_m, under.kind()), None
    features = _Features(feats)
    cursors: dict[float, _RouteCursor | None] = {1.0: None, -1.0: None}
    # The truth is streamed (its rows grow with the log; only a batch is held at once).
    for batch in iter_table_batches(
        truth_path,
        "truth_pose",
        columns=["t_ns", "x", "y", "z", "yaw"],
        batch_rows=_BATCH_ROWS,
        lean=True,
    ):
        t = np.asarray(batch.column("t_ns").to_numpy(), np.int64)
        xyz = np.stack([batch.column(c).to_numpy(zero_copy_only=False) for c in "xyz"], 1)
        yaw = np.asarray(batch.column("yaw").to_numpy(zero_copy_only=False), np.float64)
        if frame_origin is not None and sim_o is not None and frame_origin != sim_o:
            xyz, moved_yaw = move_between_frames(xyz, yaw, frame_origin, sim_o)
            yaw = yaw if moved_yaw is None else moved_yaw
        ev = np.searchsorted(bounds_ns, t, side="right") - 1
        left = np.stack([-np.sin(yaw), np.cos(yaw)], 1) * (track_m / 2.0)  # base_link +y
        for sign in (1.0, -1.0):
            # Every sample goes through the cursor (the path stays continuous); only those
            # inside an event are matched.
            s, d, cursors[sign] = _route_coords(
                route, xyz[:, 0] + sign * left[:, 0], xyz[:, 1] + sign * left[:, 1], cursors[sign]
            )
            inside = (ev >= 0) & (ev < n_events)
            under.add(features, s[inside], d[inside], ev[inside])
    return TruthUnder(under.height_m, under.kind()), None


#: Truth rows read at once (a multiple of _CHUNK: the same route coordinates as the whole).
_BATCH_ROWS = 256 * _CHUNK


class _Features:
    """The truth's feature footprints in route coordinates, (F,) each, in the file's order."""

    def __init__(self, feats: dict[str, list[Any]]) -> None:
        self.s_lo = np.asarray(feats["s_start_m"], np.float64)
        self.s_hi = np.asarray(feats["s_end_m"], np.float64)
        self.d_c = np.asarray(feats["d_center_m"], np.float64)
        self.half_w = np.asarray(feats["width_m"], np.float64) / 2.0
        self.height = np.asarray(feats["height_m"], np.float64)
        self.kind = [str(k) for k in feats["kind"]]


class _Under:
    """The tallest feature found under a tyre so far, per event (E,): its height and index
    (-1 none). Among features of equal height the first in the file wins, so the answer does
    not depend on the order the tyre samples arrive in."""

    def __init__(self, n_events: int) -> None:
        self.height_m = np.zeros(n_events)
        self.feature = np.full(n_events, -1, np.int64)
        self._kinds: list[str] = []

    def add(self, features: _Features, s: FloatArray, d: FloatArray, ev: IntArray) -> None:
        """Tyre samples at route ``(s, d)`` (K,) during events ``ev`` (K,)."""
        if s.size == 0:
            return
        self._kinds = features.kind
        order = np.argsort(s, kind="stable")
        s_sorted = s[order]
        near = (features.s_hi >= s_sorted[0]) & (features.s_lo <= s_sorted[-1])
        for f in np.flatnonzero(near).tolist():
            a, b = np.searchsorted(s_sorted, [features.s_lo[f], features.s_hi[f]], side="left")
            rows = order[a:b]
            rows = rows[np.abs(d[rows] - features.d_c[f]) <= features.half_w[f]]
            h = features.height[f]
            for e in np.unique(ev[rows]).tolist():
                best = self.feature[e]
                if h > self.height_m[e] or (h == self.height_m[e] and best >= 0 and f < best):
                    self.height_m[e], self.feature[e] = h, f

    def kind(self) -> list[str | None]:
        return [self._kinds[f] if f >= 0 else None for f in self.feature.tolist()]


__all__ = ["ROUTE_CHECK_M", "TruthUnder", "truth_under_events"]
