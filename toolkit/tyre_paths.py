"""The rear tyres' paths over the ground, and which laser points lie near them.

The tables stage lists, per event, the points within ``[model] wheel_window_radius_m`` of the
ground each rear tyre traversed (paper sect. 7); the project stage may keep only the points
near the tyres' paths at all (``[project] keep = "near_path"``). Both sample the paths here
(:func:`tyre_paths`) and sieve points by grid cells first (:func:`near_cells`).

What the paths are drawn from is defined here once (:data:`PATH_SETTINGS`,
:data:`PATH_INPUTS`): the project stage's up-to-date key holds it when it cuts, and it is
stamped on the cut cloud (:func:`cut_metadata`), which a reader checks against its own
(:func:`cut_differences`): a change that moves the paths redoes the cut or is refused, never
matched against a strip cut around other paths.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from toolkit.arrays import FloatArray, IntArray

#: Largest spacing of the samples of a tyre's path, m.
PATH_STEP_M = 0.05
#: Key-value metadata of a point cloud that keeps only the points near the tyres' paths: how
#: near, m (the tables stage refuses a cloud cut narrower than its radius).
META_KEPT_WITHIN_M = "kept_within_m_of_tyre_paths"
#: ... and what those paths were drawn from (:meth:`PathsDrawnFrom.to_text`).
META_CUT_AROUND = "tyre_paths_drawn_from"
#: The configuration the rear tyres' paths are drawn from, by dotted key: the track between
#: the tyres (:func:`tyre_paths`, :class:`NearPath`). The wheelbase, the mounts and the pose's
#: own settings move them only through the pose, below.
PATH_SETTINGS = ("vehicle.track_m",)
#: The files they are drawn from, by layout name: the pose (its ``t_ns``, ``x``, ``y``,
#: ``yaw``; the whole log's, so the events do not move the cut).
PATH_INPUTS = ("pose",)
#: Largest bitmap of grid cells sieve 1 marks (32 M cells, 32 MB: open tyre paths 1.7 km
#: across at 30 cm cells; larger ones use sorted cell keys).
MAX_BITMAP_CELLS = 1 << 25


@dataclass(frozen=True)
class TyrePaths:
    """Samples of both rear tyres' paths over every event of a log: ``xy`` (M, 2) m,
    ``event`` (M,) row index into the log's events, ``wheel`` (M,) 0 left / 1 right."""

    xy: FloatArray
    event: IntArray
    wheel: IntArray
    #: Per wheel, the first sample row of each event (E + 1,): event ``e`` of wheel ``w`` is
    #: rows ``first[w][e]:first[w][e + 1]``.
    first: tuple[IntArray, IntArray]


def tyre_paths(
    pose_t_ns: IntArray,
    pose_xy: FloatArray,
    pose_yaw: FloatArray,
    t_start_ns: IntArray,
    t_end_ns: IntArray,
    track_m: float,
) -> TyrePaths:
    """Sample each rear tyre's path over each event ``[t_start, t_end]`` (E,), from the pose
    (K,) / (K, 2) / (K,) (see the module docstring). Vectorised over events: the pose times
    inside all events at once, densified so no two samples are more than :data:`PATH_STEP_M`
    apart."""
    # The pose rows inside each event, plus its two ends (interpolated).
    lo = np.searchsorted(pose_t_ns, t_start_ns, side="right")
    hi = np.searchsorted(pose_t_ns, t_end_ns, side="left")
    inner = np.maximum(hi - lo, 0)
    n_ev = t_start_ns.size
    counts = inner + 2
    ev = np.repeat(np.arange(n_ev), counts)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    k = np.arange(ev.size) - first[ev]
    t = np.empty(ev.size, dtype=np.int64)
    is_start, is_end = k == 0, k == counts[ev] - 1
    t[is_start] = t_start_ns
    t[is_end] = t_end_ns
    mid = ~(is_start | is_end)
    t[mid] = pose_t_ns[lo[ev[mid]] + k[mid] - 1]
    tf = (t - pose_t_ns[0]).astype(np.float64)
    tp = (pose_t_ns - pose_t_ns[0]).astype(np.float64)
    x = np.interp(tf, tp, pose_xy[:, 0])
    y = np.interp(tf, tp, pose_xy[:, 1])
    yaw = np.interp(tf, tp, np.unwrap(pose_yaw))
    # Densify: each step split into ceil(length / PATH_STEP_M) pieces (within an event).
    same = ev[1:] == ev[:-1]
    step = np.hypot(np.diff(x), np.diff(y))
    pieces = np.where(same, np.maximum(np.ceil(step / PATH_STEP_M), 1), 1).astype(np.int64)
    j = np.repeat(np.arange(pieces.size), pieces)
    f = (np.arange(j.size) - np.concatenate([[0], np.cumsum(pieces)[:-1]])[j]) / pieces[j]
    f = np.where(same[j], f, 0.0)

    def lerp(v: FloatArray) -> FloatArray:
        return np.concatenate([v[j] + f * (v[j + 1] - v[j]), v[-1:]])

    xs, ys, yaws = lerp(x), lerp(y), lerp(yaw)
    evs = np.concatenate([ev[j], ev[-1:]])
    half = 0.5 * track_m
    # Left tyre at +y of base_link, right at -y: (x, y) + R(yaw) (0, +-half).
    nx, ny = -np.sin(yaws) * half, np.cos(yaws) * half
    xy = np.concatenate([np.c_[xs + nx, ys + ny], np.c_[xs - nx, ys - ny]])
    first_left = np.searchsorted(evs, np.arange(n_ev + 1), side="left").astype(np.int64)
    return TyrePaths(
        xy=xy,
        event=np.concatenate([evs, evs]).astype(np.int64),
        wheel=np.repeat(np.array([0, 1], dtype=np.int64), xs.size),
        first=(first_left, first_left + xs.size),
    )


def near_cells(sample_xy: FloatArray, x: FloatArray, y: FloatArray, cell_m: float) -> IntArray:
    """The points (x, y) (N,) in a grid cell of side ``cell_m`` that holds a sample (M, 2)
    or is next to one that does: their indices, ascending (:class:`CellSieve`, built for
    one use)."""
    return CellSieve(sample_xy, cell_m).points(x, y)


class CellSieve:
    """The grid cells of side ``cell_m`` that hold a sample (M, 2) or are next to one, built
    once and asked of many batches of points (:meth:`points`).

    The cells are marked in a bitmap over the samples' bounding box (a point is then one
    lookup: ~3x faster than binary search in sorted cell keys, measured). A box too large
    for a bitmap (open tyre paths kilometres across) falls back to the sorted keys."""

    def __init__(self, sample_xy: FloatArray, cell_m: float) -> None:
        self.cell_m = cell_m
        sx = np.floor(sample_xy[:, 0] / cell_m).astype(np.int64)
        sy = np.floor(sample_xy[:, 1] / cell_m).astype(np.int64)
        self.x0, self.y0 = int(sx.min()) - 1, int(sy.min()) - 1
        self.nx, self.ny = int(sx.max()) - self.x0 + 2, int(sy.max()) - self.y0 + 2
        self.keys: IntArray | None = None
        self.marked: NDArray[np.bool_] | None = None
        if self.nx * self.ny > MAX_BITMAP_CELLS:
            shifted = [cell_key(sx + dx, sy + dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)]
            self.keys = np.unique(np.concatenate(shifted))
            return
        self.marked = np.zeros((self.nx, self.ny), dtype=bool)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                self.marked[sx - self.x0 + dx, sy - self.y0 + dy] = True

    def points(self, x: FloatArray, y: FloatArray) -> IntArray:
        """The indices of the points (x, y) (N,) in a marked cell, ascending."""
        with np.errstate(invalid="ignore"):
            px, py = np.floor(x / self.cell_m), np.floor(y / self.cell_m)
        if self.keys is not None:
            keys = cell_key(np.nan_to_num(px), np.nan_to_num(py))
            at = np.minimum(np.searchsorted(self.keys, keys), self.keys.size - 1)
            return np.flatnonzero(self.keys[at] == keys)
        assert self.marked is not None  # one of the two is built
        ix, iy = px - self.x0, py - self.y0
        inside = np.flatnonzero((ix >= 0) & (ix < self.nx) & (iy >= 0) & (iy < self.ny))
        return inside[self.marked[ix[inside].astype(np.int64), iy[inside].astype(np.int64)]]


def cell_key(cx: FloatArray | IntArray, cy: FloatArray | IntArray) -> IntArray:
    """One int64 per grid cell (cell indices within +-2^31)."""
    return (cx.astype(np.int64) << 32) + (cy.astype(np.int64) & 0xFFFFFFFF)


class NearPath:
    """Which points lie within ``distance_m`` of either rear tyre's path over a whole log.

    The paths are sampled from the pose as the tables stage samples an event's
    (:func:`tyre_paths`, one "event" from the first pose row to the last): the tables' own
    samples then lie within ``PATH_STEP_M / 2`` (plus the millimetres a yaw interpolated
    between other rows moves a tyre) of these, so every point the tables take within their
    radius ``r`` of a tyre is within ``r + PATH_STEP_M`` of a sample here. Built once per log
    (the sorted cell keys and a KD-tree of ~40 samples a metre of path); :meth:`mask` is two
    vectorised sieves per batch of points, as in the tables stage.

    ``pose_t_ns`` (K,), ``pose_xy`` (K, 2) m, ``pose_yaw`` (K,) rad; ``track_m`` between the
    rear tyres.
    """

    def __init__(
        self,
        pose_t_ns: IntArray,
        pose_xy: FloatArray,
        pose_yaw: FloatArray,
        track_m: float,
        distance_m: float,
    ) -> None:
        self.distance_m = distance_m
        if pose_t_ns.size < 2:
            self._samples = np.zeros((0, 2))
        else:
            t, xy, yaw = _densify_turns(pose_t_ns, pose_xy, pose_yaw, 0.5 * track_m)
            whole = tyre_paths(t, xy, yaw, t[:1], t[-1:], track_m)
            self._samples = whole.xy[np.isfinite(whole.xy).all(axis=1)]
        self._tree = cKDTree(self._samples) if self._samples.size else None
        self._cells = CellSieve(self._samples, distance_m) if self._samples.size else None

    def mask(self, x: FloatArray, y: FloatArray) -> NDArray[np.bool_]:
        """True for each point (x, y) (N,) within ``distance_m`` of a sample (N,)."""
        keep = np.zeros(x.size, dtype=bool)
        if self._tree is None or self._cells is None or x.size == 0:
            return keep
        candidate = self._cells.points(x, y)
        if candidate.size:
            xy = np.c_[np.take(x, candidate), np.take(y, candidate)]
            dist, _ = self._tree.query(xy, k=1, distance_upper_bound=self.distance_m)
            keep[candidate[np.isfinite(dist)]] = True
        return keep


def _densify_turns(
    t_ns: IntArray, xy: FloatArray, yaw: FloatArray, half_track_m: float
) -> tuple[IntArray, FloatArray, FloatArray]:
    """The pose rows (K,) with rows interpolated between them wherever the vehicle turns so
    fast that a tyre swings more than :data:`PATH_STEP_M` about the axle's centre
    (``half_track_m * |d yaw|``): :func:`tyre_paths` densifies by the centre's step alone,
    which a robot turning on the spot does not make. Unwrapped yaw; times strictly rising."""
    yaw = np.unwrap(yaw)
    swing = half_track_m * np.abs(np.diff(yaw))
    pieces = np.maximum(np.ceil(swing / PATH_STEP_M), 1).astype(np.int64)
    if not (pieces > 1).any():
        return t_ns, xy, yaw
    # Never more pieces than nanoseconds between the rows (times must stay distinct).
    pieces = np.minimum(pieces, np.maximum(np.diff(t_ns), 1))
    j = np.repeat(np.arange(pieces.size), pieces)
    f = (np.arange(j.size) - np.concatenate([[0], np.cumsum(pieces)[:-1]])[j]) / pieces[j]
    t = np.concatenate(
        [t_ns[j] + np.round(f * (t_ns[j + 1] - t_ns[j])).astype(np.int64), t_ns[-1:]]
    )
    x = np.concatenate([xy[j, 0] + f * (xy[j + 1, 0] - xy[j, 0]), xy[-1:, 0]])
    y = np.concatenate([xy[j, 1] + f * (xy[j + 1, 1] - xy[j, 1]), xy[-1:, 1]])
    a = np.concatenate([yaw[j] + f * (yaw[j + 1] - yaw[j]), yaw[-1:]])
    return t, np.c_[x, y], a


#: A setting's value as stamped on a cloud (JSON's scalars).
Setting = float | int | str | bool


@dataclass(frozen=True)
class PathsDrawnFrom:
    """What a log's rear tyres' paths are drawn from: the value of each of
    :data:`PATH_SETTINGS` and the sha256 of each of :data:`PATH_INPUTS`. The same code draws
    the same paths from two equal ones."""

    settings: Mapping[str, Setting]
    inputs: Mapping[str, str]

    @classmethod
    def of(cls, config: object, inputs: Mapping[str, str]) -> PathsDrawnFrom:
        """From a configuration (anything holding its sections as attributes: the whole
        configuration or a stage's settings) and the inputs' sha256 by layout name (KeyError
        when one of :data:`PATH_INPUTS` is not among them: a stage that cuts must need it)."""
        settings: dict[str, Setting] = {}
        for dotted in PATH_SETTINGS:
            section, _, key = dotted.partition(".")
            settings[dotted] = getattr(getattr(config, section), key)
        return cls(settings, {name: inputs[name] for name in PATH_INPUTS})

    def to_text(self) -> str:
        """Canonical JSON (``{"inputs": {...}, "settings": {...}}``, keys sorted)."""
        body = {"settings": dict(self.settings), "inputs": dict(self.inputs)}
        return json.dumps(body, sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_text(cls, text: str) -> PathsDrawnFrom:
        """Read :meth:`to_text`'s JSON back; ValueError when it is not of that form."""
        body = json.loads(text)
        if not (
            isinstance(body, dict)
            and isinstance(body.get("settings"), dict)
            and isinstance(body.get("inputs"), dict)
        ):
            raise ValueError(f"not an object of settings and inputs: {text!r}")
        return cls(body["settings"], body["inputs"])

    def differences(self, now: PathsDrawnFrom) -> list[str]:
        """What differs between these (a cut's) and ``now``, in words, one item each."""
        out = [
            f"{name} = {self.settings.get(name)!r} when cut, {now.settings.get(name)!r} now"
            for name in sorted({*self.settings, *now.settings})
            if self.settings.get(name) != now.settings.get(name)
        ]
        out += [
            f"{name} sha256 {str(self.inputs.get(name))[:12]} when cut, "
            f"{str(now.inputs.get(name))[:12]} now"
            for name in sorted({*self.inputs, *now.inputs})
            if self.inputs.get(name) != now.inputs.get(name)
        ]
        return out


def cut_metadata(distance_m: float, drawn_from: PathsDrawnFrom) -> dict[str, str]:
    """The key-value metadata of a cloud keeping only the points within ``distance_m`` of
    the tyres' paths drawn from ``drawn_from``."""
    return {META_KEPT_WITHIN_M: repr(distance_m), META_CUT_AROUND: drawn_from.to_text()}


def cut_differences(metadata: Mapping[str, str], now: PathsDrawnFrom, reach_m: float) -> list[str]:
    """Why a cloud of key-value ``metadata`` cannot give every point within ``reach_m`` of
    the tyres' paths drawn from ``now`` (plus :data:`PATH_STEP_M`, the paths' sampling), in
    words, one item each: cut narrower, around paths drawn from other settings or inputs, or
    with no record of them (cut before they were recorded). Empty when it can: a cloud that
    keeps every point, or one cut for these paths at least that wide."""
    if META_KEPT_WITHIN_M not in metadata:
        return []
    out: list[str] = []
    text = metadata[META_KEPT_WITHIN_M]
    try:
        kept = float(text)
    except ValueError:
        out.append(f"metadata {META_KEPT_WITHIN_M} = {text!r} is not a distance")
    else:
        if kept < reach_m + PATH_STEP_M:
            out.append(
                f"kept only within {kept:g} m of the paths, and the tables reach {reach_m:g} m "
                f"(+ {PATH_STEP_M:g} m of path sampling)"
            )
    stamp = metadata.get(META_CUT_AROUND)
    if stamp is None:
        out.append(
            f"no record of what its paths were drawn from: no metadata {META_CUT_AROUND}, "
            "cut by an earlier version"
        )
        return out
    try:
        then = PathsDrawnFrom.from_text(stamp)
    except ValueError:
        out.append(f"metadata {META_CUT_AROUND} = {stamp!r} is unreadable")
        return out
    return out + then.differences(now)
