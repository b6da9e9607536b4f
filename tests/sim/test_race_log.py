"""The ``race`` profile's log: its rough events (paper, Sect. 5 and 7; issue 11), its GPS
against the truth and its IMU's vertical spectrum.

Every test that reads the race log sits in this file, so that one worker simulates it (a test
file goes to one worker; spread over two files the log was simulated twice, 84 s each).

By the label stage itself (ingest, pose, label, with its 40-tap filter): about 0.3-0.6 % of
1.4 m events reach 0.02 G/mph, a share that moves by less than a factor of three as the
filter's band edge moves from 9 to 11 Hz, and the positives come from several kinds of
feature and from the background roughness, and event shocks range from about 0.02 G to
0.6 G. By the reference labeller: the event count. The race seed here (1) is not one of those the
simulator was tuned on (601-606, ``benchmarks/sim_seeds.py``).
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import uniform_filter1d
from scipy.signal import welch

from toolkit.config import default_config
from toolkit.geometry.geodesy import GeodeticOrigin
from toolkit.geometry.map_frame import geodetic_to_world
from toolkit.sim.profiles import make_profile
from toolkit.sim.sensors import SensorParams
from toolkit.sim.simulate import SimResult
from toolkit.sim.suspension import modal_summary
from toolkit.sim.vehicle import VehicleParams
from toolkit.stages.ingest import ingest_log
from toolkit.stages.label import SPEC as LABEL
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.runner import run_stage
from toolkit.tableio import read_table
from toolkit.workspace import Workspace

from .logdata import SimLog, label_log, on_grid_true_times
from .reference_labeller import Events

# The race simulated, ingested, posed and labelled three times: run by .ci/run, left out of
# the README's command.
pytestmark = pytest.mark.slow

NS = 1_000_000_000
VEHICLE = VehicleParams()


def _params(profile: str) -> SensorParams:
    return make_profile(profile).sensors


@pytest.fixture(scope="module")
def events(race_log: SimLog) -> Events:
    ev = label_log(race_log, make_profile("race").sensors.imu.rate_hz)
    pos = ev.positive
    p1, p50, p99 = np.percentile(ev.shock_g, [1, 50, 99])
    print(
        f"\nrace: {len(ev)} events, {pos.sum()} positive ({pos.mean():.3%}); shock G: "
        f"p1 {p1:.4f}, median {p50:.4f}, p99 {p99:.4f}, max {ev.shock_g.max():.4f}; "
        f"speed {ev.speed_mph.min():.1f}-{ev.speed_mph.max():.1f} mph; top ruggedness "
        f"{np.round(np.sort(ev.ruggedness)[-12:], 4).tolist()}"
    )
    return ev


def test_race_has_enough_events(events: Events, race_log: SimLog) -> None:
    travelled = float(race_log.truth.path_length[-1])
    assert len(events) == pytest.approx(travelled / 1.4, abs=3)
    assert len(events) > 2000


@dataclasses.dataclass(frozen=True)
class StageLabels:
    """The label stage's events on the race log: their count, every event's ``shock_g`` at
    the default filter, and the rough events' truth kinds ("background" where no feature
    lies under a rear tyre) by the filter's stop edge (Hz)."""

    events: int
    shock_g: np.ndarray
    rough_kinds: dict[float, list[str]]


@pytest.fixture(scope="module")
def stage_labels(race_result: SimResult, tmp_path_factory: pytest.TempPathFactory) -> StageLabels:
    """Ingest, pose and label the race log; label it again with the filter's stop edge at 9
    and 11 Hz (pass edge 5 Hz above), the default being 10 Hz."""
    cfg = default_config()
    ws = Workspace(tmp_path_factory.mktemp("race_ws") / "ws")
    log_id = ingest_log(Path(race_result.path), ws, cfg).log_id
    run_stage(POSE, ws, cfg, log_id=log_id)
    kinds: dict[float, list[str]] = {}
    for stop in (9.0, 11.0, cfg.label.fir_stop_hz):
        label = dataclasses.replace(cfg.label, fir_stop_hz=stop, fir_pass_hz=stop + 5.0)
        run_stage(LABEL, ws, dataclasses.replace(cfg, label=label), log_id=log_id, overwrite=True)
        events = read_table(ws.log_dir(log_id) / "events.parquet", "events")
        rough = events.filter(events.column("rough")).column("truth_feature_kind").to_pylist()
        kinds[stop] = [kind or "background" for kind in rough]
    out = StageLabels(events.num_rows, events.column("shock_g").to_numpy(), kinds)
    print(
        f"\nlabel stage on the race log: {out.events} events; rough at stop edge "
        + ", ".join(f"{k:g} Hz {len(v)} {dict(Counter(v))}" for k, v in kinds.items())
    )
    return out


def test_race_positive_fraction(stage_labels: StageLabels) -> None:
    """About 0.3-0.6 % of events reach 0.02 G/mph (the paper: 0.36 % and 0.44 %)."""
    rough = stage_labels.rough_kinds[default_config().label.fir_stop_hz]
    fraction = len(rough) / stage_labels.events
    assert 0.003 <= fraction <= 0.006, f"{fraction:.3%} of {stage_labels.events} events"


def test_race_positive_fraction_holds_as_the_band_edge_moves(stage_labels: StageLabels) -> None:
    """From a 9 Hz to an 11 Hz stop edge the positives change by less than a factor of 3."""
    at_9, at_11 = len(stage_labels.rough_kinds[9.0]), len(stage_labels.rough_kinds[11.0])
    assert at_11 > 0 and at_9 / at_11 < 3.0, (at_9, at_11)


def test_race_positives_come_from_features_and_background(stage_labels: StageLabels) -> None:
    kinds = Counter(stage_labels.rough_kinds[default_config().label.fir_stop_hz])
    assert kinds["background"] > 0, kinds
    assert len(set(kinds) - {"background"}) >= 3, kinds


def test_race_shock_span(stage_labels: StageLabels) -> None:
    """Event shocks (the label stage's) range, as Sect. 7's do, from about 0.02 G
    (negligible) to 0.5-0.6 G (severe). Sect. 7 gives the range's ends, so the smallest and
    the largest event are checked: the quietest event is the IMU's noise through the filter
    (0.018 G here; it fails if that floor rises above 0.03 G), the largest a hard hit."""
    low = float(stage_labels.shock_g.min())
    top = float(stage_labels.shock_g.max())
    print(f"\nshock: min {low:.4f} G, median {np.median(stage_labels.shock_g):.4f}, max {top:.4f}")
    assert low <= 0.03
    assert 0.3 <= top <= 1.0


# -- GPS ------------------------------------------------------------------------------------


def _gps_residuals(log: SimLog) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ENU fix minus the true antenna position (lever arm from /tf_static), at valid fixes;
    with their true times and the true yaw."""
    p = _params(log.meta["profile"]).gps
    fix = log.columns["/gps/fix"]
    t = on_grid_true_times(
        log.stamps("/gps/fix"),
        log.clock_offsets["/gps/fix"],
        log.start_ns,
        int(round(NS / p.rate_hz)),
    )
    valid = np.asarray(fix["status.status"]) >= 0
    tr = log.truth
    k = np.searchsorted(tr.t_ns, t)
    ok = valid & (k < tr.t_ns.size)
    ok[ok] &= tr.t_ns[k[ok]] == t[ok]
    assert ok.sum() > 0.98 * valid.sum()
    k = k[ok]
    lever, _ = log.static_transform("gps_antenna")
    antenna = tr.position[k] + tr.rotation[k].apply(lever)
    enu = geodetic_to_world(
        fix["latitude"][ok],
        fix["longitude"][ok],
        fix["altitude"][ok],
        GeodeticOrigin(**log.json("origin")),
    )
    yaw = tr.rotation[k].as_euler("ZYX")[:, 0]
    return enu - antenna, t[ok], yaw


def test_gps_noise_and_drift_against_truth(race_log: SimLog) -> None:
    """On the race log (7 minutes, every heading): white noise from fix-to-fix differences,
    slow Gauss-Markov drift from the smoothed residual, and the lever arm applied."""
    p = _params("race").gps
    resid, t, yaw = _gps_residuals(race_log)
    steps = np.diff(resid, axis=0)
    consecutive = np.diff(t) == int(round(NS / p.rate_hz))
    white = steps[consecutive].std(axis=0) / np.sqrt(2)
    smooth = uniform_filter1d(resid, 31, axis=0)  # 3 s: white noise down to 0.02 m
    drift_rms = float(np.sqrt(np.mean(smooth**2)))
    total_h = resid[:, :2].std(axis=0)
    # The antenna's lever arm turns with the vehicle: without it the residual would follow the
    # heading (0.6 m forward) and sit 2.1 m high.
    heading = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    along = float(np.mean(np.sum((resid[:, :2] - resid[:, :2].mean(axis=0)) * heading, axis=1)))
    print(
        f"\nGPS white std e/n/u {white} (configured {p.horizontal_noise_m}, "
        f"{p.vertical_noise_m}); drift rms {drift_rms:.3f} (configured {p.drift_std_m}); "
        f"horizontal std {total_h}; mean {resid.mean(axis=0)}; along-heading {along:.3f}; "
        f"yaw span {np.ptp(yaw):.2f} rad"
    )
    np.testing.assert_allclose(white[:2], p.horizontal_noise_m, rtol=0.15)
    assert white[2] == pytest.approx(p.vertical_noise_m, rel=0.15)
    assert 0.5 * p.drift_std_m < drift_rms < 1.6 * p.drift_std_m
    expected_h = math.hypot(p.horizontal_noise_m, p.drift_std_m)
    assert np.all((total_h > 0.4 * expected_h) & (total_h < 1.6 * expected_h))
    assert np.all(np.abs(resid.mean(axis=0)) < 3 * p.drift_std_m)
    assert abs(along) < 0.2
    assert np.ptp(yaw) > 3.0  # the heading varied enough for the lever check to bite


# -- the IMU's vertical spectrum --------------------------------------------------------------


def test_imu_vertical_spectrum_has_the_wheel_hop_peak(race_log: SimLog) -> None:
    """The IMU's z acceleration over the race log's ordinary road (ISO class D, 2 s windows
    at least 3 m before and 8 m after every rough feature the tyres could meet: the rear axle
    past it, and the wheel hop's ring-down), averaged Hann periodograms: a
    hump at the wheel hop, a local maximum standing above the 5-8 Hz floor between body and
    wheel modes, then the fall above it. (On the rough class E stretches the wheels leave
    the ground so often that the hop cannot build up, and over the whole log the features'
    own lines blur it; both are printed.) The first model's spectrum fell monotonically from
    5 Hz here (-3 dB at 10 Hz, seed 1).

    The hump lies at 10-11.5 Hz, below the modes' 12.4-12.7 Hz: what the IMU sees is the
    hop's response times the road's input, whose displacement spectrum falls as 1/f^2 (ISO
    8608) and which the tyre's footprint smooths further, so the product peaks below the
    damped (0.3) mode; hence the band 9-12.5 Hz. +1.5 dB is about four times the scatter of
    an average of this many half-overlapping 2 s periodograms (~0.4 dB for 100 windows)."""
    p = make_profile("race").sensors.imu
    t = on_grid_true_times(
        race_log.stamps("/imu/data"),
        race_log.clock_offsets["/imu/data"],
        race_log.start_ns,
        int(round(1e9 / p.rate_hz)),
    )
    az = np.asarray(race_log.columns["/imu/data"]["linear_acceleration.z"], dtype=np.float64)
    truth = race_log.truth
    inside = truth.covers(t)
    t, az = t[inside], az[inside]
    s = truth.interp(t, truth.route_s)
    d = truth.interp(t, truth.route_d)
    feats = race_log.columns["/truth/features"]["features"][0]
    near = np.zeros(s.size, dtype=bool)
    # Features whose box reaches the band the tyres sweep (beside it, none is felt).
    reach = VEHICLE.track_m / 2 + VEHICLE.tyre_width_m / 2
    for lo, hi, dc, w in zip(
        feats["s_start_m"], feats["s_end_m"], feats["d_center_m"], feats["width_m"], strict=True
    ):
        near |= (s > lo - 3.0) & (s < hi + 8.0) & (np.abs(d - dc) < reach + w / 2)
    rough = race_log.world.terrain.roughness_scale(s) > 1.05

    def spectrum(skip: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        n = int(2 * p.rate_hz)
        window = np.hanning(n)
        starts = [i for i in range(0, az.size - n, n // 2) if not skip[i : i + n].any()]
        segments = np.stack([az[i : i + n] for i in starts])
        segments = (segments - segments.mean(axis=1, keepdims=True)) * window
        psd = (np.abs(np.fft.rfft(segments, axis=1)) ** 2).mean(axis=0)
        return np.fft.rfftfreq(n, 1.0 / p.rate_hz), psd, len(starts)

    def describe(freq: np.ndarray, psd: np.ndarray) -> tuple[float, float, float]:
        floor = float(psd[(freq >= 5.0) & (freq <= 8.0)].mean())
        band = (freq >= 8.5) & (freq <= 13.0)
        i = int(np.argmax(psd[band]))
        at_16 = float(psd[np.argmin(np.abs(freq - 16.0))])
        return (
            float(freq[band][i]),
            10 * np.log10(psd[band][i] / floor),
            10 * np.log10(at_16 / floor),
        )

    freq, psd, windows = spectrum(near | rough)
    f_peak, above, at_16 = describe(freq, psd)
    whole = welch(az - az.mean(), fs=p.rate_hz, nperseg=int(2 * p.rate_hz))
    f_rough, above_rough, _ = describe(*spectrum(near | ~rough)[:2])
    f_all, above_all, _ = describe(*whole)
    hop = modal_summary(VEHICLE)
    print(
        f"\nIMU z spectrum, ordinary road ({windows} windows of 2 s): peak {f_peak:.1f} Hz, "
        f"{above:+.1f} dB over the 5-8 Hz floor, 16 Hz {at_16:+.1f} dB; rough stretches: "
        f"{f_rough:.1f} Hz {above_rough:+.1f} dB; whole log: {f_all:.1f} Hz {above_all:+.1f} dB; "
        f"wheel-hop modes {hop['wheel_hop_hz_min']:.1f}-{hop['wheel_hop_hz_max']:.1f} Hz"
    )
    assert windows >= 100
    i_peak = int(np.argmin(np.abs(freq - f_peak)))
    assert psd[i_peak] >= psd[i_peak - 1] and psd[i_peak] >= psd[i_peak + 1]
    assert 9.0 <= f_peak <= 12.5
    assert above >= 1.5
    assert at_16 <= above - 6.0
