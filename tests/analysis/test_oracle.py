"""The oracle's patches: the model's points with z the true height where each beam hit."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from unittest import mock

import numpy as np
import pyarrow as pa
import pytest

from tests.analysis.test_truth_terrain import write_pose_table
from toolkit.analysis import oracle as oracle_module
from toolkit.analysis.oracle import oracle_patches
from toolkit.analysis.truth_terrain import TrueGround, true_ground, where_beams_hit
from toolkit.model.patches import TyrePatches
from toolkit.tableio import read_table
from toolkit.workspace import Workspace

#: The poses' times: 0 to 2 s at 100 Hz (the points' tau lie inside unless said otherwise).
POSE_T_NS = np.arange(0, 2_000_000_001, 10_000_000, dtype=np.int64)
#: Where the modelled terrain ends (x of where the beam hit, m).
TERRAIN_END_X_M = 15.0


class _PlaneGround:
    """A stand-in for :class:`TrueGround` whose frame is the pose's: the plane
    z = 0.1 x - 0.05 y + 1 up to x = TERRAIN_END_X_M, nothing (NaN) beyond; records the
    places it was asked about."""

    def __init__(self) -> None:
        self.asked: list[np.ndarray] = []

    @staticmethod
    def plane(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.asarray(0.1 * x - 0.05 * y + 1.0, np.float64)

    def height_m(self, xyz_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xyz = np.asarray(xyz_m, np.float64).reshape(-1, 3)
        self.asked.append(xyz)
        h = np.where(xyz[:, 0] <= TERRAIN_END_X_M, self.plane(xyz[:, 0], xyz[:, 1]), np.nan)
        return h, xyz[:, 2]  # as TrueGround: the terrain's height, the point's own


def _write_pose(log_dir: Path, name: str, offset_m: tuple[float, float, float]) -> None:
    """A ``pose``-shaped table ``name`` (pose or truth_pose) over POSE_T_NS: driving east at
    10 m/s, level, shifted by ``offset_m``."""
    log_dir.mkdir(parents=True, exist_ok=True)
    s = POSE_T_NS * 1e-9
    xyz = np.c_[10.0 * s + offset_m[0], np.full(s.size, offset_m[1]), np.full(s.size, offset_m[2])]
    path = log_dir / f"{name}.parquet"
    write_pose_table(path, name, POSE_T_NS, xyz, np.zeros((s.size, 3)))


def _simulated_log(ws: Workspace, log_id: str, error_m: tuple[float, float, float]) -> None:
    """A log whose estimated pose is the true one moved by ``error_m`` (no attitude error):
    a point placed with it lies ``error_m`` off the spot its beam hit."""
    _write_pose(ws.log_dir(log_id), "truth_pose", (0.0, 0.0, 0.0))
    _write_pose(ws.log_dir(log_id), "pose", error_m)


def _patches(x: np.ndarray, y: np.ndarray, tau: np.ndarray, valid: np.ndarray) -> TyrePatches:
    """Patches (G, n) of the given points; z the estimated 0.5 m everywhere, gamma, psi,
    lead and the laser distinct per point so that any reshuffle shows."""
    g, n = valid.shape
    k = np.arange(g * n, dtype=np.float64).reshape(g, n)
    laser = np.where(valid, (np.arange(g * n) % 2).reshape(g, n), -1).astype(np.int16)
    return TyrePatches(
        x=x,
        y=y,
        z=np.where(valid, 0.5, 0.0),
        tau=tau,
        gamma=0.01 * k,
        psi=-0.01 * k,
        valid=valid,
        count=valid.sum(axis=1),
        laser=laser,
        lasers=("/laser_1", "/laser_2"),
        lead=0.1 * k,
    )


def _unchanged(a: TyrePatches, b: TyrePatches) -> None:
    """Everything but z, valid and count is the same."""
    for name in ("x", "y", "tau", "gamma", "psi", "laser", "lead"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.lasers == b.lasers


def test_oracle_is_none_for_a_log_that_is_not_simulated(tmp_path: Path) -> None:
    ws = Workspace(tmp_path / "ws")
    ws.log_dir("plain").mkdir(parents=True)  # no mcap_metadata.json: not simulated
    valid = np.ones((2, 3), bool)
    x, y, tau = np.zeros((2, 3)), np.zeros((2, 3)), np.full((2, 3), 0.5)
    events = pa.table({"log_id": ["plain"]})
    assert oracle_patches(ws, events, _patches(x, y, tau, valid)) is None


def test_oracle_is_none_unless_every_log_is_simulated(tmp_path: Path) -> None:
    """Log "a" is simulated (and read first), log "b" is not: no oracle at all."""
    ws = Workspace(tmp_path / "ws")
    _simulated_log(ws, "a", (0.2, 0.0, 0.0))
    ws.log_dir("b").mkdir(parents=True)
    ground = _PlaneGround()

    def fake_true_ground(log_dir: Path) -> _PlaneGround | TrueGround | None:
        return ground if log_dir.name == "a" else true_ground(log_dir)

    valid = np.ones((4, 2), bool)
    x, y, tau = np.full((4, 2), 5.0), np.zeros((4, 2)), np.full((4, 2), 0.5)
    events = pa.table({"log_id": ["b", "a"]})
    with mock.patch.object(oracle_module, "true_ground", fake_true_ground):
        assert oracle_patches(ws, events, _patches(x, y, tau, valid)) is None
    assert len(ground.asked) == 1  # log a was looked up before log b said no


def test_oracle_z_is_the_true_height_where_each_beam_hit(tmp_path: Path) -> None:
    """Two logs with different pose errors (a: 0.2 m east, 0.1 m north; b: 0.3 m west):
    each point's z is the plane's height at the point less its own log's error (to 1e-9 m,
    interpolation's rounding), its place, time and the rest unchanged; the padding stays."""
    ws = Workspace(tmp_path / "ws")
    errors = {"a": (0.2, 0.1, 0.05), "b": (-0.3, 0.0, 0.0)}
    for log_id, error in errors.items():
        _simulated_log(ws, log_id, error)
    # Events: b, a (groups 0-1 are b's, 2-3 a's), three columns, the last padding in two.
    valid = np.array([[1, 1, 1], [1, 1, 0], [1, 1, 1], [1, 0, 0]], bool)
    x = np.array([[3.0, 4.0, 5.0], [3.5, 4.5, 0.0], [10.0, 11.0, 12.0], [10.5, 0.0, 0.0]])
    y = np.array([[1.0, -1.0, 0.5], [0.2, 0.3, 0.0], [2.0, -2.0, 0.0], [1.5, 0.0, 0.0]])
    tau = np.where(valid, 0.3 + 0.1 * np.arange(3), 0.0)
    patches = _patches(x, y, tau, valid)
    events = pa.table({"log_id": ["b", "a"], "event_id": [7, 3]})
    ground = _PlaneGround()
    with mock.patch.object(oracle_module, "true_ground", lambda log_dir: ground):
        truth = oracle_patches(ws, events, patches)
    assert truth is not None
    _unchanged(truth, patches)
    np.testing.assert_array_equal(truth.valid, valid)
    np.testing.assert_array_equal(truth.count, [3, 2, 3, 1])
    of_group = np.array(["b", "b", "a", "a"])
    ex = np.array([errors[k][0] for k in of_group])[:, None]
    ey = np.array([errors[k][1] for k in of_group])[:, None]
    want = np.where(valid, _PlaneGround.plane(x - ex, y - ey), 0.0)
    np.testing.assert_allclose(truth.z, want, rtol=0, atol=1e-9)
    # By hand, event b's first point: 0.1 (3 + 0.3) - 0.05 (1 - 0) + 1; event a's first:
    # 0.1 (10 - 0.2) - 0.05 (2 - 0.1) + 1.
    assert abs(truth.z[0, 0] - 1.28) < 1e-9 and abs(truth.z[2, 0] - 1.885) < 1e-9
    assert not np.array_equal(truth.z, patches.z)
    # Only the valid points were looked up, one log at a time (sorted: a, then b).
    assert [len(a) for a in ground.asked] == [4, 5]


def test_oracle_drops_points_off_the_terrain_or_outside_the_true_pose(tmp_path: Path) -> None:
    """A beam that hit beyond the modelled terrain, and a point seen before the poses begin
    or after they end, lose their point (valid False, z 0, the count one less); the others
    keep theirs."""
    ws = Workspace(tmp_path / "ws")
    _simulated_log(ws, "a", (0.2, 0.0, 0.0))
    valid = np.ones((2, 3), bool)
    # Hits at x - 0.2: 14.8 on the terrain, 15.05 beyond its end.
    x = np.array([[14.8 + 0.2, TERRAIN_END_X_M + 0.25, 5.0], [5.0, 6.0, 7.0]])
    y = np.zeros((2, 3))
    tau = np.array([[1.0, 1.0, 1.0], [-0.5, 1.5, 2.5]])  # poses cover 0-2 s
    patches = _patches(x, y, tau, valid)
    events = pa.table({"log_id": ["a"]})
    with mock.patch.object(oracle_module, "true_ground", lambda log_dir: _PlaneGround()):
        truth = oracle_patches(ws, events, patches)
    assert truth is not None
    _unchanged(truth, patches)
    kept = np.array([[True, False, True], [False, True, False]])
    np.testing.assert_array_equal(truth.valid, kept)
    np.testing.assert_array_equal(truth.count, [2, 1])
    assert truth.z[0, 1] == 0.0 and truth.z[1, 0] == 0.0 and truth.z[1, 2] == 0.0
    np.testing.assert_allclose(
        truth.z[kept], _PlaneGround.plane(x[kept] - 0.2, y[kept]), rtol=0, atol=1e-9
    )


@dataclass(frozen=True)
class _SampleOracle:
    """The oracle on the sample log's own points, and what it should hold."""

    patches: TyrePatches
    truth: TyrePatches
    #: Where the true pose puts each valid point's beam, in the points' (pose) frame.
    hit: np.ndarray
    #: The simulator's terrain height there, in the points' frame.
    height_m: np.ndarray


@pytest.fixture(scope="module")
def sample_oracle(sample_projected: tuple[Path, str]) -> _SampleOracle:
    """The oracle of four tyres' worth of the sample log's points (the session's projected
    workspace, read-only): each tyre ten neighbouring points of one scan, a metre or two
    apart, the last tyre two of them padding."""
    root, log_id = sample_projected
    ws = Workspace(root)
    log_dir = ws.log_dir(log_id)
    table = read_table(log_dir / "points.parquet", "points", columns=["t_ns", "x", "y", "z"])
    starts = table.num_rows // 5 * np.arange(1, 5)
    rows = (starts[:, None] + np.arange(10)).ravel()
    pick = {c: table.column(c).to_numpy()[rows].astype(np.float64) for c in ("x", "y", "z")}
    t_ns = table.column("t_ns").to_numpy()[rows]
    shape = (4, 10)
    valid = np.ones(shape, bool)
    valid[3, 8:] = False  # padding
    patches = _patches(
        pick["x"].reshape(shape), pick["y"].reshape(shape), (t_ns * 1e-9).reshape(shape), valid
    )
    patches = dataclasses.replace(patches, z=np.where(valid, pick["z"].reshape(shape), 0.0))
    truth = oracle_patches(ws, pa.table({"log_id": [log_id, log_id]}), patches)
    assert truth is not None
    ground = true_ground(log_dir)
    assert isinstance(ground, TrueGround)
    xyz = np.c_[pick["x"], pick["y"], pick["z"]][valid.ravel()]
    hit = where_beams_hit(log_dir, xyz, t_ns[valid.ravel()])
    height_sim, hit_z_sim = ground.height_m(hit)
    # The simulator's frame and the pose's are ENU frames at different origins: the same
    # place's heights differ by (nearly) a constant, the origins' altitudes apart.
    height = height_sim - (hit_z_sim - hit[:, 2])
    return _SampleOracle(patches, truth, hit, height)


def test_oracle_on_the_sample_log_reads_the_terrain_where_beams_hit(
    sample_oracle: _SampleOracle,
) -> None:
    """On the simulated sample log no point is dropped (all on the route, within the poses'
    times), nothing but z changes, and within each tyre's patch the heights rise and fall
    as the simulator's terrain does where the true pose puts each beam (to 0.1 mm: the two
    frames' tilt over a patch is micrometres, the time's round trip through float seconds
    a quarter of a microsecond)."""
    patches, truth = sample_oracle.patches, sample_oracle.truth
    _unchanged(truth, patches)
    np.testing.assert_array_equal(truth.valid, patches.valid)
    np.testing.assert_array_equal(truth.count, [10, 10, 10, 8])
    assert (truth.z[~patches.valid] == 0.0).all()
    want = np.zeros(patches.valid.shape)
    want[patches.valid] = sample_oracle.height_m
    for g in range(truth.groups):
        n = int(truth.count[g])
        np.testing.assert_allclose(
            truth.z[g, :n] - truth.z[g, 0], want[g, :n] - want[g, 0], rtol=0, atol=1e-4
        )
    # The terrain varies within a patch (the check above could not pass on a flat one).
    assert np.ptp(want[0, :10]) > 0.005


def test_oracle_z_is_in_the_frame_of_the_points_it_replaces(sample_oracle: _SampleOracle) -> None:
    """The oracle keeps each point's x and y (the pose frame) and replaces its z: the new z
    must be the true terrain height in that same frame, within a few centimetres of where the
    true pose puts the beam (the sample lasers' own error, median 25 mm here).

    Found failing when written: the height was left in the simulator's frame, whose origin
    is 2.03 m lower than the pose's on the sample log, so every oracle z stood 2.03 m above
    the points' frame (the scores were unaffected: the model uses differences of z within
    a patch).
    """
    valid = sample_oracle.patches.valid
    oracle_z = sample_oracle.truth.z[valid]
    assert np.median(np.abs(oracle_z - sample_oracle.hit[:, 2])) < 0.05
    np.testing.assert_allclose(oracle_z, sample_oracle.height_m, rtol=0, atol=1e-3)
