"""Laser returns projected with the TRUE pose lie on the true terrain, within the range noise.

This checks the ray caster, the scan timing (clock offsets, beam times) and the extrinsics
together, from the log alone: per beam, its true time is the header stamp less the laser's
clock offset (metadata) plus ``beam_index * time_increment``; the true ``base_link`` pose at
that time is interpolated from ``/truth/odom`` (positions linearly, rotations by Slerp); the
laser's ``/tf_static`` extrinsic and the beam angle give the ray, the range the point. The
point's height is compared with the true terrain of the world rebuilt from the metadata.

The vertical miss ``dz`` of a point is converted to a miss along the beam: a range error
``e`` moves the point by ``e u`` and the ground under it by ``e (dh/dt)`` (the terrain's
slope along the beam's horizontal direction, ``t`` the range), so ``e = -dz / (u_z - dh/dt)``.
On flat ground this is ``dz / |sin(elevation)|``; the slope term matters for the far lasers,
whose beams meet the ground at a few degrees, where a 2 % crossfall or a 5 % grade changes
the incidence angle severalfold. Both are reported; the assertions use the slope-aware one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from toolkit.sim.profiles import make_profile

from .logdata import LASER_FRAMES, LASER_TOPICS, SimLog

SCAN_STRIDE = 4  # every 4th scan of each laser: about 100 000 beams per laser
SLOPE_STEP_M = 0.025  # half the fine grid's spacing


@dataclass(frozen=True)
class BeamResiduals:
    dz: np.ndarray  # point height minus true terrain height (m)
    range_error: np.ndarray  # dz converted to a miss along the beam, slope-aware (m)
    range_error_flat: np.ndarray  # dz / |sin(elevation)| (m)
    d: np.ndarray  # lateral offset of the point from the route centreline (m)

    def __len__(self) -> int:
        return int(self.dz.size)


def beam_residuals(
    log: SimLog, laser: int, stride: int = SCAN_STRIDE, time_shift_ns: int = 0
) -> BeamResiduals:
    """Residuals of every finite beam of every ``stride``-th scan of laser ``laser`` (0-4);
    ``time_shift_ns`` is added to the beams' true times (0 for the real check)."""
    topic = LASER_TOPICS[laser]
    scans = log.columns[topic]
    world = log.world
    truth = log.truth
    mount_xyz, mount_q = log.static_transform(LASER_FRAMES[laser])
    mount_rot = Rotation.from_quat(mount_q)

    start = log.stamps(topic)[::stride] - log.clock_offsets[topic] + time_shift_ns
    ranges = np.asarray(scans["ranges"][::stride], dtype=np.float64)
    beams = ranges.shape[1]
    k = np.arange(beams)
    dt_beam_ns = float(scans["time_increment"][0]) * 1e9
    t_beam = start[:, None] + np.round(k[None, :] * dt_beam_ns).astype(np.int64)
    angle = float(scans["angle_min"][0]) + k * float(scans["angle_increment"][0])
    ok = np.isfinite(ranges) & truth.covers(t_beam)
    t = t_beam[ok]
    r = ranges[ok]
    a = np.broadcast_to(angle[None, :], ranges.shape)[ok]

    position = truth.interp(t, truth.position)
    world_from_base = truth.rotation_at(t)
    beam_in_laser = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    u = world_from_base.apply(mount_rot.apply(beam_in_laser))
    origin = position + world_from_base.apply(mount_xyz)
    p = origin + r[:, None] * u

    # Route coordinates: the guess is the vehicle's route s plus how far ahead the point is.
    s_vehicle = truth.interp(t, truth.route_s)
    _, _, heading = world.route.sample(s_vehicle)
    ahead = (p[:, 0] - position[:, 0]) * np.cos(heading) + (p[:, 1] - position[:, 1]) * np.sin(
        heading
    )
    s, d = world.route.to_route(p[:, 0], p[:, 1], s_vehicle + ahead)
    ground = world.terrain.height(s, d)
    dz = p[:, 2] - ground

    def ground_at(offset: float) -> np.ndarray:
        x = p[:, 0] + offset * u[:, 0]
        y = p[:, 1] + offset * u[:, 1]
        ss, dd = world.route.to_route(x, y, s)
        return world.terrain.height(ss, dd)

    slope = (ground_at(SLOPE_STEP_M) - ground_at(-SLOPE_STEP_M)) / (2 * SLOPE_STEP_M)
    return BeamResiduals(
        dz=dz,
        range_error=-dz / (u[:, 2] - slope),
        range_error_flat=dz / np.abs(u[:, 2]),
        d=d,
    )


@pytest.fixture(scope="module")
def residuals(sample_log: SimLog) -> list[BeamResiduals]:
    return [beam_residuals(sample_log, i) for i in range(len(LASER_TOPICS))]


def _robust_std(x: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def _summary(name: str, x: np.ndarray) -> str:
    a = np.abs(x)
    p90, p99, p999 = np.percentile(a, [90, 99, 99.9])
    return (
        f"{name}: n={x.size} median|e|={np.median(a):.4f} p90={p90:.4f} p99={p99:.4f} "
        f"p99.9={p999:.4f} robust std={_robust_std(x):.4f} median e={np.median(x):+.5f}"
    )


def test_laser_points_lie_on_true_terrain(residuals: list[BeamResiduals]) -> None:
    noise = make_profile("sample").sensors.laser.range_noise_m
    print()
    for i, res in enumerate(residuals):
        print(_summary(f"{LASER_FRAMES[i]} slope-aware", res.range_error))
        print(_summary(f"{LASER_FRAMES[i]} dz/|sin el| ", res.range_error_flat))
    e = np.concatenate([res.range_error for res in residuals])
    print(_summary("all lasers slope-aware", e))
    flat = np.concatenate([res.range_error_flat for res in residuals])
    print(_summary("all lasers dz/|sin el| ", flat))

    assert all(len(res) > 50_000 for res in residuals)
    a = np.abs(e)
    assert np.median(a) < 2 * noise
    assert np.percentile(a, 99) < 6 * noise
    # The bulk is the configured Gaussian range noise: robust std within 20 %, no bias.
    assert _robust_std(e) == pytest.approx(noise, rel=0.2)
    assert abs(np.median(e)) < 0.1 * noise
    for i, res in enumerate(residuals):
        ai = np.abs(res.range_error)
        assert np.median(ai) < 2 * noise, LASER_FRAMES[i]
        assert abs(np.median(res.range_error)) < 0.15 * noise, LASER_FRAMES[i]


def test_nearest_laser_residuals_are_pure_range_noise(residuals: list[BeamResiduals]) -> None:
    """laser_1 looks down steeply (8 m ahead), so pose and timing errors hardly matter: its
    residuals must be the configured range noise alone (Gaussian: median |e| = 0.674 sigma,
    99th percentile 2.58 sigma)."""
    noise = make_profile("sample").sensors.laser.range_noise_m
    e = residuals[0].range_error
    assert _robust_std(e) == pytest.approx(noise, rel=0.1)
    assert np.median(np.abs(e)) == pytest.approx(0.6745 * noise, rel=0.1)
    assert np.percentile(np.abs(e), 99) < 3.5 * noise


def test_laser_clock_offset_is_where_points_fit_best(sample_log: SimLog) -> None:
    """Shifting the far laser's beam times by +-1 ms from the metadata's clock offset makes the
    points fit the terrain worse: the offset and the beam timing are right to well under 1 ms."""
    laser = len(LASER_TOPICS) - 1
    med = {
        shift: float(
            np.median(
                np.abs(beam_residuals(sample_log, laser, stride=8, time_shift_ns=shift).range_error)
            )
        )
        for shift in (-1_000_000, 0, 1_000_000)
    }
    print(f"\n{LASER_FRAMES[laser]} median |range error| by time shift (ns): {med}")
    assert med[0] < 0.95 * med[-1_000_000]
    assert med[0] < 0.95 * med[1_000_000]
