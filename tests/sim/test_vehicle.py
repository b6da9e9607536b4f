"""Tyres and suspension of the simulated vehicle (issue 11): tyres of real width that envelope
the road and never pull, a pothole and a rock of equal size felt differently, one wheel on a
rock rolling the body, the modal fast path equal to the step-by-step path, and the wheel-hop
peak in the IMU's vertical spectrum.

The single-feature tests drive the real :class:`~toolkit.sim.drive.Driver` along a straight
ISO class A road holding one feature, at a constant speed with the reactive controller off.
"""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest
from scipy.signal import lfilter

from toolkit.sim.drive import Driver, TrueBlock, make_driven_path
from toolkit.sim.features import RoughFeature
from toolkit.sim.profiles import make_profile
from toolkit.sim.speed_control import ReactiveSpeedParams
from toolkit.sim.suspension import (
    ALL_DOWN,
    INPUT_ONE,
    INPUT_ROAD,
    INPUT_ROAD_RATE,
    N_INPUTS,
    Suspension,
    modal_summary,
)
from toolkit.sim.terrain import Terrain
from toolkit.sim.tyre import TyreFootprint
from toolkit.sim.vehicle import VehicleParams
from toolkit.sim.world import World, make_world

from .logdata import GRAVITY_MPS2
from .reference_labeller import shock_filter_taps

VEHICLE = VehicleParams()
FEATURE_S_M = 100.0
FEATURE_SIZE_M = 0.4
FEATURE_HEIGHT_M = 0.08
SPEED_MPS = 10.0
DT_S = 1e-3


# -- helpers ----------------------------------------------------------------------------------


@cache
def _smooth_world() -> World:
    params = dataclasses.replace(
        make_profile("calibration", 300.0).world, road_class="A", fixed_features=()
    )
    return make_world(params, 5)


@cache
def _drive(kind: str | None, speed_mps: float = SPEED_MPS) -> dict[str, np.ndarray]:
    """Drive past one feature (or none) in the left wheel track; the blocks' truth joined."""
    world = _smooth_world()
    features: tuple[RoughFeature, ...] = ()
    if kind is not None:
        s0 = FEATURE_S_M
        left_track = VEHICLE.track_m / 2
        features = (
            RoughFeature(
                kind, s0, s0 + FEATURE_SIZE_M, left_track, FEATURE_SIZE_M, FEATURE_HEIGHT_M
            ),
        )
    terrain = Terrain(params=world.params, seed=world.seed, route=world.route, features=features)
    path = make_driven_path(world.route, np.random.default_rng(0), wander_amplitude_m=0.0)
    driver = Driver(
        world.route,
        terrain,
        path,
        VEHICLE,
        dataclasses.replace(ReactiveSpeedParams(), enabled=False),
        make_profile("race").sensors.imu.mount.xyz_m,
        0,
        speed_mps,
        ((0.0, speed_mps),),
    )
    blocks: list[TrueBlock] = []
    while driver.sigma_m < FEATURE_S_M + 30.0:
        blocks.append(driver.step(100))
    names = [f.name for f in dataclasses.fields(TrueBlock)]
    return {n: np.concatenate([getattr(b, n) for b in blocks]) for n in names}


def _shock_g(run: dict[str, np.ndarray]) -> float:
    """What the labeller would read: 100 Hz IMU samples (each the mean of its 10 ms), the
    40-tap 0-10 Hz-removing FIR, peak |output| / g while the axles pass the feature."""
    fz = run["specific_force_body_mps2"][:, 2]
    n = fz.size // 10 * 10
    imu = fz[:n].reshape(-1, 10).mean(axis=1)
    out = lfilter(shock_filter_taps(100.0), [1.0], imu)
    s = run["s_m"][9:n:10]  # rear axle, at each IMU sample's end
    near = (s > FEATURE_S_M - VEHICLE.wheelbase_m - 3.0) & (s < FEATURE_S_M + 6.0)
    return float(np.abs(out[near]).max() / GRAVITY_MPS2)


# -- the tyre's effective road height -------------------------------------------------------


def test_footprint_reads_flat_ground_exactly_and_solves_its_load_balance() -> None:
    fp = TyreFootprint.build(VEHICLE)
    rng = np.random.default_rng(3)
    flat = np.full((5, 4, fp.cells), 0.3) + rng.uniform(-1, 1, (5, 1, 1))
    np.testing.assert_allclose(fp.effective_height(flat), flat[..., 0], atol=1e-12)

    # Rough ground: the bed's load at the returned height equals the flat-ground load.
    rough = rng.normal(0.0, 0.03, (200, 4, fp.cells))
    r = fp.effective_height(rough)
    z = r - fp.bed_deflection_m
    load = (np.maximum(rough - fp.lift_m - z[..., None], 0.0) * fp.weight).sum(axis=-1)
    np.testing.assert_allclose(load, np.broadcast_to(fp.bed_volume_m, load.shape), rtol=1e-9)


def test_print_and_modes_are_those_documented() -> None:
    """The print length, the modes and their damping that VehicleParams' docstring states."""
    np.testing.assert_allclose(VEHICLE.print_length_m(), [0.128, 0.128, 0.141, 0.141], atol=1e-3)
    m = modal_summary(VEHICLE)
    documented = {
        "heave_hz": 1.13,
        "heave_damping_ratio": 0.26,
        "pitch_hz": 1.25,
        "pitch_damping_ratio": 0.29,
        "roll_hz": 1.53,
        "roll_damping_ratio": 0.35,
        "wheel_hop_hz_min": 12.4,
        "wheel_hop_hz_max": 12.7,
        "wheel_hop_damping_ratio_min": 0.29,
        "wheel_hop_damping_ratio_max": 0.30,
    }
    for name, value in documented.items():
        assert abs(m[name] - value) <= 0.006 + 0.004 * value, (name, m)
    # Gillespie (1992, ch. 5): body modes 1-1.5 Hz, wheel hop 10-15 Hz.
    assert 1.0 <= m["heave_hz"] <= 1.5 and 0.2 <= m["heave_damping_ratio"] <= 0.4, m
    assert 10.0 <= m["wheel_hop_hz_min"] <= m["wheel_hop_hz_max"] <= 15.0, m


def test_pothole_is_bridged_and_rock_is_felt_by_its_top() -> None:
    """8 cm deep and 0.4 m across under the left wheels: the footprint bridges the pothole
    (the tread sinks until its outline meets the rims) and rides on the rock's dome.

    The pothole (a vertical rim to half its depth, then a bowl) is deep enough for the tread
    to hang in it: the dip is about the sag of the tyre's round outline over the hole's
    0.4 m, ``R - sqrt(R^2 - 0.2^2)`` = 5.7 cm, plus the bed's own deflection, and short of
    the full 8 cm."""
    base = _drive(None)["tyre_road_m"][:, 0]
    rock = _drive("rock")["tyre_road_m"][:, 0]
    hole = _drive("pothole")["tyre_road_m"][:, 0]
    lift, dip = float((rock - base).max()), float((base - hole).max())
    print(f"\nfront-left effective road: rock +{lift * 100:.2f} cm, pothole -{dip * 100:.2f} cm")
    assert 0.85 * FEATURE_HEIGHT_M <= lift <= FEATURE_HEIGHT_M
    r = VEHICLE.wheel_radius_m
    sag = r - np.sqrt(r**2 - (FEATURE_SIZE_M / 2) ** 2)
    bed = float(TyreFootprint.build(VEHICLE).bed_deflection_m.max())
    assert 0.2 * FEATURE_HEIGHT_M <= dip <= 0.9 * FEATURE_HEIGHT_M
    # The footprint's stations are 2-4 cm apart: the outline is met within a few mm of sag.
    assert sag - 0.005 <= dip <= sag + bed + 0.005


def test_pothole_and_rock_of_equal_size_give_different_shocks() -> None:
    shocks = {
        (kind, v): _shock_g(_drive(kind, v)) for kind in ("rock", "pothole") for v in (5.0, 10.0)
    }
    smooth = _shock_g(_drive(None))
    text = ", ".join(f"{k} at {v:g} m/s {g:.3f} G" for (k, v), g in shocks.items())
    print(f"\nshock: {text}; smooth road at 10 m/s {smooth:.3f} G")
    for v in (5.0, 10.0):
        rock, hole = shocks[("rock", v)], shocks[("pothole", v)]
        assert min(rock, hole) > 4 * smooth, text
        assert abs(rock - hole) > 0.15 * max(rock, hole), f"at {v:g} m/s: {text}"


# -- one wheel on a rock --------------------------------------------------------------------


def test_rock_under_the_left_wheels_rolls_the_body_left_side_up() -> None:
    run, base = _drive("rock"), _drive(None)
    # The right wheels meet nothing of it: their road is the smooth run's (to round-off: the
    # footprint's solver takes as many steps for all four tyres as the left ones need).
    np.testing.assert_allclose(
        run["tyre_road_m"][:, [1, 3]], base["tyre_road_m"][:, [1, 3]], rtol=0, atol=1e-15
    )
    assert np.abs(run["tyre_road_m"][:, [0, 2]] - base["tyre_road_m"][:, [0, 2]]).max() > 0.07

    roll_rate = run["roll_rate_radps"] - base["roll_rate_radps"]
    # While the front-left tyre climbs (its road rising), the body rolls left side up.
    climbing = np.flatnonzero(np.diff(run["tyre_road_m"][:, 0] - base["tyre_road_m"][:, 0]) > 0)
    first = slice(int(climbing[0]), int(climbing[0]) + 120)
    peak_up, peak_down = (
        float(roll_rate[first].max()),
        max(float(-roll_rate[first].min()), 0.0) + 0.0,
    )
    # No faster than the road itself rolls under the tyres (the suspension filters it).
    road_roll = np.diff(run["tyre_road_m"][:, 0] - run["tyre_road_m"][:, 1]) / (
        DT_S * VEHICLE.track_m
    )
    print(
        f"\nroll rate while the front-left tyre climbs: up to {peak_up:.3f} rad/s left side up, "
        f"{peak_down:.3f} rad/s right side up; "
        f"the road's own roll rate peaks at {road_roll.max():.2f} rad/s"
    )
    assert peak_up > 0.1
    assert peak_up > 3 * peak_down
    assert peak_up < 0.5 * road_roll.max()


# -- unilateral contact ---------------------------------------------------------------------


def test_modal_path_equals_step_by_step_path_while_all_tyres_push() -> None:
    sus = Suspension.build(VEHICLE, DT_S)
    rng = np.random.default_rng(7)
    n = 400
    u = np.zeros((n, N_INPUTS))
    u[:, INPUT_ROAD] = np.cumsum(rng.normal(0, 1e-4, (n, 4)), axis=0)
    u[:, INPUT_ROAD_RATE] = np.diff(u[:, INPUT_ROAD], axis=0, prepend=0.0) / DT_S
    u[:, INPUT_ONE] = 1.0
    x0 = sus.equilibrium(u[0])
    modal, end_modal = sus.step_modal(x0, u)
    stepped = np.empty_like(modal)
    end_stepped = sus.step_switched(x0, u, out=stepped)
    assert sus.contact_force(modal, u).min() > 0.5 * sus.static_load_n.min()
    np.testing.assert_allclose(stepped, modal, rtol=0, atol=1e-12)
    np.testing.assert_allclose(end_stepped, end_modal, rtol=0, atol=1e-12)
    block = sus.step_block(x0, u)
    assert block.stepped == 0 and block.on_ground.all()
    np.testing.assert_array_equal(block.states, modal)

    # A 15 cm drop under the front-left tyre at sample 100: from there on, the block is
    # stepped, and it equals the modal path before.
    u[100:, 0] -= 0.15
    block = sus.step_block(x0, u)
    assert block.stepped == n - 100
    assert not block.on_ground[100:, 0].all()
    np.testing.assert_array_equal(block.states[:100], modal[:100])
    assert np.all(block.tyre_force_n >= 0.0)
    assert sus.A[ALL_DOWN].shape == (14, 14)


@pytest.fixture(scope="module")
def rough_stretch() -> dict[str, np.ndarray]:
    """400 m of a race route's roughest stretch (ISO class E), at the route's speed limits."""
    prof = make_profile("race", 2000.0)
    world = make_world(prof.world, 21)
    scale = world.terrain.roughness_scale(world.route.s_m)
    start = float(world.route.s_m[int(np.argmax(scale))]) - 200.0
    path = make_driven_path(world.route, np.random.default_rng([21, 4]), prof.lane_wander_m)
    driver = Driver(
        world.route,
        world.terrain,
        path,
        VEHICLE,
        dataclasses.replace(prof.controller, enabled=False),
        prof.sensors.imu.mount.xyz_m,
        0,
        12.0,
    )
    driver.sigma_m = max(start, 2.0)
    blocks = []
    while driver.sigma_m < start + 400.0:
        blocks.append(driver.step(100))
    names = [f.name for f in dataclasses.fields(TrueBlock)]
    return {n: np.concatenate([getattr(b, n) for b in blocks[5:]]) for n in names}


def test_no_tensile_tyre_force_over_a_rough_race_stretch(
    rough_stretch: dict[str, np.ndarray],
) -> None:
    """The force the ground applies to each wheel, recovered from the truth by Newton's
    second law over each 1 ms step (``T = mu zu'' + F_suspension + W``), never pulls. The
    wheels do leave the ground, where a bilateral tyre would have pulled, and then the ground
    applies nothing; on the ground it applies the tyre's spring and damper force."""
    run, p = rough_stretch, VEHICLE
    xi, yi = p.corners()
    pitch, roll = run["pitch_rad"], run["roll_rad"]
    pitch_rate, roll_rate = run["pitch_rate_radps"][:, None], run["roll_rate_radps"][:, None]
    zs = run["position_m"][:, 2] - p.cg_from_rear_m * pitch
    zs_rate = run["velocity_world_mps"][:, 2] - p.cg_from_rear_m * run["pitch_rate_radps"]
    corner = zs[:, None] - xi * pitch[:, None] + yi * roll[:, None]
    corner_rate = zs_rate[:, None] - xi * pitch_rate + yi * roll_rate
    zu, zu_rate = run["wheel_height_m"], run["wheel_rate_mps"]
    travel = zu - corner
    spring = p.spring_n_per_m * travel + p.damper_ns_per_m * (zu_rate - corner_rate)
    # A bump stop is met for a whole step when its corner starts the step beyond the
    # clearance (Suspension.step_switched); it pushes with its rate beyond the clearance.
    on_stop = travel[:-1] > p.bump_stop_clearance_m
    stop = p.bump_stop_n_per_m * (travel - p.bump_stop_clearance_m)
    w = p.static_wheel_load_n()
    # Step k runs from sample k to k + 1; the mean of the forces at its ends against the
    # change of speed over it.
    applied = p.unsprung_mass_kg * np.diff(zu_rate, axis=0) / DT_S
    applied += 0.5 * (spring[1:] + spring[:-1]) + w
    applied += np.where(on_stop, 0.5 * (stop[1:] + stop[:-1]), 0.0)
    # The tyre's force at both ends of each step under the step's held road input.
    r = run["tyre_road_m"]
    r_rate = np.diff(r, axis=0, prepend=r[:1]) / DT_S
    kt, ct = p.tyre_n_per_m, p.tyre_damping_ns_per_m
    start = w + kt * (r - zu) + ct * (r_rate - zu_rate)
    end = w + kt * (r[:-1] - zu[1:]) + ct * (r_rate[:-1] - zu_rate[1:])
    down = run["tyre_force_n"][:-1] > 0.0
    expected = np.where(down, 0.5 * (start[:-1] + end), 0.0)
    applied, expected, down, start, end = applied[1:], expected[1:], down[1:], start[1:-1], end[1:]
    print(
        f"\n{1 - down.mean():.3%} of tyre-steps airborne; least applied force "
        f"{applied.min():.1f} N; a bilateral tyre would have pulled with up to "
        f"{-start.min():.0f} N; |applied - spring and damper| <= "
        f"{np.abs(applied - expected).max():.1f} N"
    )
    assert 1 - down.mean() > 1e-3
    assert start.min() < -0.2 * w.min()
    assert applied.min() > -0.005 * w.min()
    # A tyre counted as down pushes at the end of its step too (it pushes at the start by
    # construction: tyre_force_n is that force, clipped).
    assert np.all(end[down] >= 0.0)
    np.testing.assert_allclose(applied, expected, rtol=0, atol=0.005 * w.min())
