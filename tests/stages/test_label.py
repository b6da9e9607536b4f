"""Label stage (sect. 5): events along the path, shock, ruggedness, rejects, idempotence, the
sample log against its truth, and Fig. 5 on a calibration log."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from tests.stages.crafted import crafted_record
from toolkit.config import PipelineConfig, default_config, parse_config
from toolkit.errors import ConfigError, StageError
from toolkit.manifest import Manifest, file_sha256
from toolkit.model.shock import design_shock_fir, event_shock, filter_stream
from toolkit.stages.ingest import ingest_log
from toolkit.stages.label import FIG5_CSV, FIG5_PNG, LabelResult
from toolkit.stages.label import SPEC as LABEL
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.runner import run_stage
from toolkit.tableio import read_table, write_table
from toolkit.workspace import Workspace

SAMPLE_LOG = Path(__file__).resolve().parents[2] / "sample_logs" / "sample.mcap"
G = 9.80665
T0_NS = 1_000_000_000_000
LOG_ID = "crafted-000000000000"


# --------------------------------------------------------------------------------------
# Crafted logs: an IMU table and a pose table, recorded as a finished ingest and pose wrote
# them.


def imu_table(t_ns: np.ndarray, accel: np.ndarray) -> pa.Table:
    """The contract's IMU columns: ``accel`` (M, 3) m/s^2, no rotation, no orientation."""
    n = t_ns.size
    cols: dict[str, pa.Array] = {"t_ns": pa.array(t_ns, pa.int64())}
    for k, a in enumerate("xyz"):
        cols[f"accel_{a}"] = pa.array(accel[:, k], pa.float64())
    for a in "xyz":
        cols[f"gyro_{a}"] = pa.array(np.zeros(n), pa.float64())
    for a in "xyzw":
        cols[f"orientation_{a}"] = pa.nulls(n, pa.float64())
    cols["orientation_covariance"] = pa.nulls(n, pa.list_(pa.float64()))
    return pa.table(cols)


def pose_table(t_ns: np.ndarray, x: np.ndarray, speed: np.ndarray) -> pa.Table:
    """A straight drive east along y = 0 at the given speeds."""
    zero = np.zeros(t_ns.size)
    cols = {"t_ns": pa.array(t_ns, pa.int64()), "x": x, "y": zero, "z": zero}
    for c in ("roll", "pitch", "yaw", "vy", "vz", "roll_rate", "pitch_rate", "yaw_rate"):
        cols[c] = zero
    cols["vx"] = speed
    cols["speed"] = speed
    return pa.table({k: pa.array(v) if not isinstance(v, pa.Array) else v for k, v in cols.items()})


def crafted_log(
    root: Path,
    imu_t_ns: np.ndarray,
    accel: np.ndarray,
    pose_t_ns: np.ndarray,
    x: np.ndarray,
    speed: np.ndarray,
    imu_rpy: tuple[float, float, float] | None = (0.0, 0.0, 0.0),
) -> Workspace:
    """A workspace with one log whose ingest and pose records name these tables."""
    ws = Workspace(root)
    ws.create()
    ws.write_config(default_config())
    with ws.change_log(LOG_ID) as gen:
        d = gen.path
        kw = {"source_sha256": "0" * 64, "config_hash": "crafted"}
        write_table(d / "imu.parquet", imu_table(imu_t_ns, accel), "imu", **kw)
        write_table(d / "pose.parquet", pose_table(pose_t_ns, x, speed), "pose", **kw)
        ingested = ["imu.parquet"]
        if imu_rpy is not None:
            from scipy.spatial.transform import Rotation

            roll, pitch, yaw = imu_rpy
            q = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_quat()
            tf = {
                "transforms": [
                    {
                        "parent_frame": "base_link",
                        "child_frame": "imu_link",
                        "translation_m": [0.0, 0.0, 0.9],
                        "rotation_xyzw": q.tolist(),
                        "t_ns": int(imu_t_ns[0]),
                    }
                ]
            }
            (d / "tf_static.json").write_text(json.dumps(tf), encoding="utf-8")
            ingested.append("tf_static.json")
        m = Manifest(d / "manifest.json")
        m.record_stage("ingest", crafted_record("ingest", ingested, d, {"log": "0" * 64}))
        m.record_stage(
            "pose",
            crafted_record("pose", ["pose.parquet"], d, {"imu": file_sha256(d / "imu.parquet")}),
        )
        gen.commit()
    return ws


def burst(t_ns: np.ndarray, centre_ns: int, amplitude_g: float) -> np.ndarray:
    """A 25 Hz cosine burst under a 40 ms Gaussian, peak ``amplitude_g`` G, in m/s^2."""
    u = (t_ns - centre_ns) * 1e-9
    return np.asarray(amplitude_g * G * np.exp(-0.5 * (u / 0.04) ** 2) * np.cos(2 * np.pi * 25 * u))


SPEED_MPS = 10.0
EVENT_S = 0.14  # 1.4 m at 10 m/s
PERIOD_NS = 10_000_000


@pytest.fixture(scope="module")
def bump_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[Workspace, LabelResult]:
    """20 s straight at 10 m/s; the IMU reads g except two 0.5 G bursts, centred in events
    50 and 100 (7.07 s and 14.07 s: 3 ms off the sample grid)."""
    t = T0_NS + np.arange(2000, dtype=np.int64) * PERIOD_NS
    az = np.full(t.size, G)
    for k in (50, 100):
        az += burst(t, T0_NS + int(round((k + 0.5) * EVENT_S * 1e9)) + 3_000_000, 0.5)
    accel = np.stack([np.zeros(t.size), np.zeros(t.size), az], axis=1)
    x = SPEED_MPS * (t - T0_NS) * 1e-9
    ws = crafted_log(tmp_path_factory.mktemp("bump"), t, accel, t, x, np.full(t.size, SPEED_MPS))
    return ws, run_stage(LABEL, ws, default_config(), log_id=LOG_ID)


def test_bump_lands_in_its_event(bump_log: tuple[Workspace, LabelResult]) -> None:
    ws, result = bump_log
    ev = read_table(ws.log_table(LOG_ID, "events"), "events").to_pydict()
    ids = np.array(ev["event_id"])
    shock = np.array(ev["shock_g"])
    # 199.9 m of path: 142 whole events; the filter's first output is 19.5 samples after the
    # IMU's start and its last 19.5 before its end, so events 0, 1 and 141 are not covered.
    assert result.events == 139 and result.rejects == {"too_slow": 0, "no_imu": 3}
    assert ids.tolist() == list(range(2, 141))
    for k in (50, 100):
        near = (ids >= k - 3) & (ids <= k + 3)
        assert ids[near][np.argmax(shock[near])] == k
        # The sine-burst it leaves the filter as peaks a quarter cycle off the centre, on the
        # envelope there: 0.97 x 0.5 G, within the filter's 1.2 % ripple.
        assert shock[ids == k][0] == pytest.approx(0.5 * np.exp(-0.5 * 0.25**2), rel=0.02)
        centre = T0_NS + (k + 0.5) * EVENT_S * 1e9 + 3e6
        assert abs(np.array(ev["shock_t_ns"])[ids == k][0] - centre) < 11e6
    quiet = np.ones(ids.size, dtype=bool)
    for k in (50, 100):
        quiet &= np.abs(ids - k) > 3
    assert shock[quiet].max() < 1e-9  # gravity leaves nothing: zero gain at DC
    np.testing.assert_allclose(ev["speed_mph"], SPEED_MPS / 0.44704, rtol=1e-8)
    np.testing.assert_allclose(ev["ruggedness"], shock / (SPEED_MPS / 0.44704), rtol=1e-12)
    assert np.array(ev["rough"]).tolist() == (np.array(ev["ruggedness"]) >= 0.02).tolist()
    assert np.array(ev["rough"]).sum() == 2  # 0.48 G / 22.4 mph = 0.022 G/mph
    np.testing.assert_allclose(np.array(ev["s_start_m"]), ids * 1.4, atol=1e-9)
    np.testing.assert_array_equal(ev["imu_samples"], 14)
    assert all(k is None for k in ev["truth_feature_kind"])  # not a simulated log
    header = ws.manifest(LOG_ID).read()["label"]
    assert len(header["fir"]["taps"]) == 40 and header["imu_rate_hz"] == pytest.approx(100.0)
    assert header["fir"]["stopband_max_db"] <= -30.0
    summary = result.summary()
    assert "\n" not in summary and "139 events, 2 rough (1.44 %)" in summary


def test_rerun_is_up_to_date_and_overwrite_is_deterministic(
    bump_log: tuple[Workspace, LabelResult],
) -> None:
    ws, first = bump_log
    path = ws.log_table(LOG_ID, "events")
    sha = file_sha256(path)
    record = ws.manifest(LOG_ID).stage("label")
    assert record is not None
    again = run_stage(LABEL, ws, default_config(), log_id=LOG_ID)
    assert again.status == "up_to_date"
    assert (again.events, again.rough, again.rejects) == (first.events, first.rough, first.rejects)
    assert ws.manifest(LOG_ID).stage("label") == record  # nothing rewritten
    assert file_sha256(path) == sha
    redone = run_stage(LABEL, ws, default_config(), log_id=LOG_ID, overwrite=True)
    assert redone.status == "labelled"
    assert file_sha256(ws.log_table(LOG_ID, "events")) == sha  # same bytes


def test_a_rotated_imu_is_read_through_its_mount(
    bump_log: tuple[Workspace, LabelResult], tmp_path: Path
) -> None:
    """The IMU rolled +90 deg: its y axis is base_link's z, so the shock is read from accel_y,
    and the events are those of the upright IMU."""
    ws0, _ = bump_log
    imu = read_table(ws0.log_table(LOG_ID, "imu"), "imu")
    t = np.asarray(imu.column("t_ns").to_numpy())
    az = np.asarray(imu.column("accel_z").to_numpy())
    accel = np.stack([np.zeros(t.size), az, np.zeros(t.size)], axis=1)  # z_base = y_imu
    x = SPEED_MPS * (t - T0_NS) * 1e-9
    ws = crafted_log(
        tmp_path, t, accel, t, x, np.full(t.size, SPEED_MPS), imu_rpy=(np.pi / 2, 0.0, 0.0)
    )
    result = run_stage(LABEL, ws, default_config(), log_id=LOG_ID)
    assert not result.warnings
    a = read_table(ws0.log_table(LOG_ID, "events"), "events").to_pydict()
    b = read_table(ws.log_table(LOG_ID, "events"), "events").to_pydict()
    assert a["event_id"] == b["event_id"]
    np.testing.assert_allclose(b["shock_g"], a["shock_g"], atol=1e-12)


# --------------------------------------------------------------------------------------
# Attribution (issue 26): a filtered impact labels the one event that holds it


def ring(t_ns: np.ndarray, onset_ns: int, amplitude_g: float) -> np.ndarray:
    """An impact as the body feels it: a 25 Hz oscillation starting at ``onset_ns`` and
    decaying in 30 ms, its first crest ``amplitude_g`` G x 0.68, in m/s^2."""
    u = (t_ns - onset_ns) * 1e-9
    return np.where(u >= 0, amplitude_g * G * np.exp(-u / 0.03) * np.sin(2 * np.pi * 25 * u), 0.0)


def boundary_ns(k: int) -> int:
    """Where event k starts on the 10 m/s straight of the crafted logs."""
    return T0_NS + int(round(k * EVENT_S * 1e9))


def with_attribution(rule: str) -> PipelineConfig:
    cfg = default_config()
    return dataclasses.replace(cfg, label=dataclasses.replace(cfg.label, attribution=rule))


AttributionRun = tuple[Workspace, LabelResult, dict[str, np.ndarray]]


@pytest.fixture(scope="module")
def attribution_runs(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[np.ndarray, np.ndarray, dict[str, AttributionRun]]:
    """20 s straight at 10 m/s (1.4 m events of 0.14 s, 22.4 mph: rough from 0.447 G) on flat
    ground but for three impacts: a 1.5 G one starting 16 ms before event 50 (its largest
    crest in event 50, its leading flank reaching into event 49), and two separate ones in
    events 100 and 101 (1.2 G 80 ms into event 100, 0.9 G 20 ms into event 101: crests
    80 ms apart). Labelled under each rule: (IMU times, z accel, rule -> (workspace, result,
    events))."""
    t = T0_NS + np.arange(2000, dtype=np.int64) * PERIOD_NS
    az = np.full(t.size, G)
    az += ring(t, boundary_ns(50) - 16_000_000, 1.5)
    az += ring(t, boundary_ns(100) + 80_000_000, 1.2)
    az += ring(t, boundary_ns(101) + 20_000_000, 0.9)
    accel = np.stack([np.zeros(t.size), np.zeros(t.size), az], axis=1)
    x = SPEED_MPS * (t - T0_NS) * 1e-9
    runs: dict[str, AttributionRun] = {}
    for rule in ("impact", "span_peak"):
        root = tmp_path_factory.mktemp(f"attribution_{rule}")
        ws = crafted_log(root, t, accel, t, x, np.full(t.size, SPEED_MPS))
        result = run_stage(LABEL, ws, with_attribution(rule), log_id=LOG_ID)
        table = read_table(ws.log_table(LOG_ID, "events"), "events").to_pydict()
        runs[rule] = (ws, result, {k: np.array(v) for k, v in table.items()})
    return t, az, runs


def by_event(ev: dict[str, np.ndarray], column: str, k: int) -> float:
    (i,) = np.flatnonzero(ev["event_id"] == k)
    return float(ev[column][i])


def test_one_impact_labels_one_event(
    attribution_runs: tuple[np.ndarray, np.ndarray, dict[str, AttributionRun]],
) -> None:
    """The impact at the start of event 50: under span_peak its flank at the boundary makes
    event 49 rough too; under impact only event 50, which holds the compensated time of its
    largest crest, is rough, with the same shock as before. The manifest and the summary say
    what changed."""
    _, _, runs = attribution_runs
    ws, result, ev = runs["impact"]
    _, old_result, old = runs["span_peak"]
    assert old["event_id"][old["rough"]].tolist() == [49, 50, 100, 101]
    assert ev["event_id"][ev["rough"]].tolist() == [50, 100, 101]
    # The largest crest's time lies in event 50, and its shock is the span peak bit for bit.
    t50 = by_event(ev, "shock_t_ns", 50)
    assert boundary_ns(50) <= t50 < boundary_ns(51)
    assert by_event(ev, "shock_g", 50) == by_event(old, "shock_g", 50)
    assert by_event(ev, "shock_t_ns", 50) == by_event(old, "shock_t_ns", 50)
    # Under span_peak, event 49's shock was the flank at its very end.
    assert boundary_ns(50) - by_event(old, "shock_t_ns", 49) < 1_000_000
    assert by_event(old, "shock_g", 49) > 0.9 * by_event(old, "shock_g", 50)
    header = ws.manifest(LOG_ID).read()["label"]
    changed = header["attribution"]
    assert changed == result.attribution
    assert changed["rule"] == "impact" and changed["applied"] is True
    assert (changed["rough_span_peak"], changed["rough"], changed["rough_lost"]) == (4, 3, 1)
    assert changed["rough_span_peak"] == old_result.rough and changed["rough"] == result.rough
    assert changed["events_reduced"] == int((ev["shock_g"] < old["shock_g"]).sum()) >= 1
    assert "rough_lost_featureless" not in changed  # no truth on a crafted log
    assert "impact attribution: 1 of span_peak's 4 rough events" in result.summary()
    assert "attribution" not in old_result.summary()
    assert ws.manifest(LOG_ID).stage("label") is not None
    up_to_date = run_stage(LABEL, ws, default_config(), log_id=LOG_ID)
    assert up_to_date.status == "up_to_date" and up_to_date.attribution == changed


def test_two_impacts_keep_their_own(
    attribution_runs: tuple[np.ndarray, np.ndarray, dict[str, AttributionRun]],
) -> None:
    """Two impacts 80 ms apart across the boundary of events 100 and 101: the smaller is not
    the filter's response to the larger, so each event keeps its own, as under span_peak."""
    _, _, runs = attribution_runs
    ev, old = runs["impact"][2], runs["span_peak"][2]
    for k in (100, 101):
        assert by_event(ev, "rough", k)
        assert by_event(ev, "shock_g", k) == by_event(old, "shock_g", k)
        assert boundary_ns(k) <= by_event(ev, "shock_t_ns", k) < boundary_ns(k + 1)
    assert by_event(ev, "shock_g", 101) < 0.9 * by_event(ev, "shock_g", 100)


def test_span_peak_is_the_rule_before(
    attribution_runs: tuple[np.ndarray, np.ndarray, dict[str, AttributionRun]],
) -> None:
    """span_peak gives, bit for bit, what the old function path gives (the filter streamed,
    event_shock's band-limited peak over each event's span), and the impact rule never
    raises a shock above it."""
    t, az, runs = attribution_runs
    ws, result, old = runs["span_peak"]
    fir = design_shock_fir(100.0)
    (out,) = filter_stream([(t, az)], fir.taps, 15_000_000)
    for i, k in enumerate(old["event_id"].tolist()):
        got = event_shock(
            out.t_ns, out.value, out.run, boundary_ns(k), boundary_ns(k + 1), "max_abs", 15_000_000
        )
        assert got is not None
        assert old["shock_g"][i] == got.shock_mps2 / G
        assert old["shock_t_ns"][i] == got.peak_t_ns
    assert ws.manifest(LOG_ID).read()["label"]["attribution"] == {
        "rule": "span_peak",
        "applied": False,
    }
    new = runs["impact"][2]
    assert new["event_id"].tolist() == old["event_id"].tolist()
    assert runs["impact"][1].rejects == result.rejects
    assert np.all(new["shock_g"] <= old["shock_g"])


def test_a_neighbours_smear_is_small_and_still_labelled(
    attribution_runs: tuple[np.ndarray, np.ndarray, dict[str, AttributionRun]],
) -> None:
    """Event 49 holds nothing but the flank of event 50's impact: a small shock (its own
    crest of the impact's lead-in, 0.13 G against 0.81), not NaN, not rejected. Event 102
    holds only the decaying tail of event 101's: all of it is the filter's response to that
    crest, so 0.0, labelled all the same."""
    _, _, runs = attribution_runs
    ev, old = runs["impact"][2], runs["span_peak"][2]
    assert {49, 102} <= set(ev["event_id"].tolist())
    assert np.all(np.isfinite(ev["shock_g"])) and np.all(np.isfinite(ev["ruggedness"]))
    s49 = by_event(ev, "shock_g", 49)
    print(f"\nevent 49: {by_event(old, 'shock_g', 49):.3f} G -> {s49:.3f} G")
    assert 0.0 < s49 < 0.2 * by_event(ev, "shock_g", 50)
    assert boundary_ns(49) <= by_event(ev, "shock_t_ns", 49) < boundary_ns(50)
    assert by_event(old, "shock_g", 102) > 0.02
    assert by_event(ev, "shock_g", 102) == 0.0 and not by_event(ev, "rough", 102)
    assert runs["impact"][1].attribution["events_without_own_impact"] >= 1  # type: ignore[index]


def test_attribution_is_configured() -> None:
    """``[label] attribution``: "impact" by default, "span_peak" the rule before; anything
    else is refused, naming the key."""
    assert default_config().label.attribution == "impact"
    assert parse_config("[label]\nattribution = 'span_peak'\n").label.attribution == "span_peak"
    with pytest.raises(ConfigError) as info:
        parse_config("[label]\nattribution = 'nearest'\n", "x.toml")
    message = str(info.value)
    assert message.startswith("x.toml: label.attribution") and "one of" in message


def test_a_stop_makes_no_event_and_divides_by_nothing(tmp_path: Path) -> None:
    """10 m/s, brake to a 5 s standstill, drive on: the events around the stop are too slow
    and rejected, and no event spans it."""
    dt = 0.01
    n = 2400
    tt = np.arange(n) * dt
    speed = np.interp(tt, [0, 5, 7, 12, 14, 24], [10, 10, 0, 0, 10, 10])
    x = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * dt)])
    t = T0_NS + np.arange(n, dtype=np.int64) * PERIOD_NS
    rng = np.random.default_rng(7)
    az = G + 0.05 * rng.standard_normal(n)  # road noise, quiet
    accel = np.stack([np.zeros(n), np.zeros(n), az], axis=1)
    ws = crafted_log(tmp_path, t, accel, t, x, speed)
    result = run_stage(LABEL, ws, default_config(), log_id=LOG_ID)
    ev = read_table(ws.log_table(LOG_ID, "events"), "events").to_pydict()
    t0, t1 = np.array(ev["t_start_ns"]), np.array(ev["t_end_ns"])
    stop_lo, stop_hi = T0_NS + 7_000_000_000, T0_NS + 12_000_000_000
    assert not np.any((t0 < stop_hi) & (t1 > stop_lo))
    # Braking at 5 m/s^2 keeps every whole event before the stop above 2 m/s on average
    # (the last starts at sqrt(2 * 5 * 1.4) = 3.7 m/s): only the one holding the stop is slow.
    assert result.rejects == {"too_slow": 1, "no_imu": result.rejects["no_imu"]}
    ids = np.array(ev["event_id"])
    (hole,) = np.flatnonzero(np.diff(ids) == 2)
    assert t1[hole] < stop_lo and t0[hole + 1] > stop_hi  # the missing event held the stop
    total = int(np.floor(x[-1] / 1.4))
    assert result.events + sum(result.rejects.values()) == total
    assert min(ev["speed_mph"]) >= 2.0 / 0.44704
    assert np.all(np.isfinite(ev["ruggedness"])) and not any(ev["rough"])
    record = ws.manifest(LOG_ID).stage("label")
    assert record is not None and record.rejects["too_slow"] == result.rejects["too_slow"]
    assert record.row_counts["events"] == len(ev["event_id"]) == result.events > 100


def test_an_imu_too_slow_for_the_band_fails_with_one_line(tmp_path: Path) -> None:
    t = T0_NS + np.arange(500, dtype=np.int64) * 40_000_000  # 25 Hz
    accel = np.stack([np.zeros(500), np.zeros(500), np.full(500, G)], axis=1)
    x = SPEED_MPS * (t - T0_NS) * 1e-9
    ws = crafted_log(tmp_path, t, accel, t, x, np.full(500, SPEED_MPS))
    with pytest.raises(StageError) as info:
        run_stage(LABEL, ws, default_config(), log_id=LOG_ID)
    text = str(info.value)
    assert "\n" not in text and "IMU rate 25 Hz" in text and "imu.parquet" in text
    assert ".gen" not in text  # named by the log's public directory
    assert not ws.log_table(LOG_ID, "events").exists()
    assert ws.manifest(LOG_ID).stage("label") is None


def test_label_needs_a_finished_pose(tmp_path: Path) -> None:
    t = T0_NS + np.arange(300, dtype=np.int64) * PERIOD_NS
    accel = np.stack([np.zeros(300), np.zeros(300), np.full(300, G)], axis=1)
    ws = crafted_log(tmp_path, t, accel, t, np.zeros(300), np.zeros(300))
    (ws.log_dir(LOG_ID) / "pose.parquet").unlink()
    with pytest.raises(StageError, match="run `terrain pose` first"):
        run_stage(LABEL, ws, default_config(), log_id=LOG_ID)


# --------------------------------------------------------------------------------------
# The sample log against its truth


@pytest.fixture(scope="module")
def sample_label(tmp_path_factory: pytest.TempPathFactory) -> tuple[Workspace, LabelResult]:
    ws = Workspace(tmp_path_factory.mktemp("label_sample") / "ws")
    ingested = ingest_log(SAMPLE_LOG, ws, default_config())
    run_stage(POSE, ws, default_config(), log_id=ingested.log_id)
    return ws, run_stage(LABEL, ws, default_config(), log_id=ingested.log_id)


def test_sample_rough_events_are_true_features(
    sample_label: tuple[Workspace, LabelResult],
) -> None:
    """Events whose truth puts a feature under a rear tyre against events with none: every
    rough event has one, the featureless road stays mostly far below the threshold, and the tall
    features (>= 8 cm) read above nearly all of the featureless road."""
    ws, result = sample_label
    ev = read_table(ws.log_table(result.log_id, "events"), "events").to_pydict()
    h = np.array(ev["truth_feature_height_m"], dtype=np.float64)
    r = np.array(ev["ruggedness"])
    rough = np.array(ev["rough"])
    none, some, tall = h == 0, h > 0, h >= 0.08
    print(
        f"\n{result.summary()}\nfeatureless: {none.sum()} events, ruggedness median "
        f"{np.median(r[none]):.4f} p95 {np.percentile(r[none], 95):.4f} max {r[none].max():.4f}; "
        f"with a feature: {some.sum()} events, {rough[some].sum()} rough, median "
        f"{np.median(r[some]):.4f}; tall: {tall.sum()} events, median {np.median(r[tall]):.4f}"
    )
    assert result.events == pytest.approx(619 / 1.4, rel=0.05)  # the sample drives 619 m
    assert result.rejects == {"too_slow": 0, "no_imu": result.rejects["no_imu"]}
    assert result.rejects["no_imu"] <= 6  # filter start-up and the end only
    assert rough.sum() >= 10  # as the reference labeller finds on this log
    assert not rough[none].any()
    # The featureless road's bulk stays far below the threshold (p95 0.0097). Its tail comes
    # near it (max 0.019): the sample's rough stretches (ISO class E, a quarter of its road)
    # are the background roughness that makes some of the race's rough events (issue 11);
    # none reaches it here (checked above).
    assert np.percentile(r[none], 95) < 0.5 * 0.02
    assert rough[some].mean() >= 0.1
    assert tall.sum() >= 5 and np.median(r[tall]) > np.percentile(r[none], 95)
    kinds = {k for k, rr in zip(ev["truth_feature_kind"], rough, strict=True) if rr}
    assert kinds and None not in kinds
    assert result.truth == {
        "with_feature": int(some.sum()),
        "rough_with_feature": int(rough[some].sum()),
        "without_feature": int(none.sum()),
        "rough_without_feature": 0,
    }


# --------------------------------------------------------------------------------------
# Fig. 5 on a calibration log


@pytest.fixture(scope="module")
def calibration_label(tmp_path_factory: pytest.TempPathFactory) -> tuple[Workspace, LabelResult]:
    """The calibration profile cut to 800 m: its first three ridges, at 5, 7.5, 10 m/s (the
    drive ends some 75 m before the route does)."""
    from toolkit.sim.simulate import simulate

    root = tmp_path_factory.mktemp("label_calibration")
    log = root / "calibration.mcap"
    simulate(log, profile="calibration", distance_m=800.0, seed=1)
    ws = Workspace(root / "ws")
    ingested = ingest_log(log, ws, default_config())
    run_stage(POSE, ws, default_config(), log_id=ingested.log_id)
    return ws, run_stage(LABEL, ws, default_config(), log_id=ingested.log_id)


@pytest.mark.slow  # an 800 m calibration drive simulated and labelled (28 s); run by .ci/run
def test_calibration_log_gives_fig5(calibration_label: tuple[Workspace, LabelResult]) -> None:
    ws, result = calibration_label
    fig5 = result.fig5
    print(f"\n{result.summary()}")
    assert fig5 is not None and fig5["passes"] == 3
    assert fig5["slope_g_per_mph"] > 0 and fig5["r2"] >= 0.9
    log_dir = ws.log_dir(result.log_id)
    rows = (log_dir / FIG5_CSV).read_text(encoding="utf-8").splitlines()
    assert rows[0] == "s_m,speed_mph,peak_g,fitted_g" and len(rows) == 4
    speeds = [float(r.split(",")[1]) for r in rows[1:]]
    np.testing.assert_allclose(speeds, np.array([5.0, 7.5, 10.0]) / 0.44704, rtol=0.02)
    assert (log_dir / FIG5_PNG).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    record = ws.manifest(result.log_id).stage("label")
    assert record is not None and set(record.outputs) == {"events.parquet", FIG5_CSV, FIG5_PNG}
    assert ws.manifest(result.log_id).read()["label"]["fig5"] == fig5
