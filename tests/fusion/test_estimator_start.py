"""The filter's start: the level taken from the first second's specific force, and the
warning when that force is not 1 g (toolkit/fusion/estimator.py)."""

from __future__ import annotations

import dataclasses

import numpy as np

from toolkit.fusion.estimator import STEADY_START_G, _initial_attitude, _unsteady_start
from toolkit.fusion.estimator_io import SensorData
from toolkit.fusion.state import G


def _still(pitch_rad: float, extra_fwd_mps2: float = 0.0) -> SensorData:
    """One second of a still IMU pitched nose-down by ``pitch_rad`` (its specific force is
    gravity's reaction in the body frame), plus an unexplained forward force."""
    t = np.arange(0.0, 1.0, 0.01)
    f = np.array([-G * np.sin(pitch_rad) + extra_fwd_mps2, 0.0, G * np.cos(pitch_rad)])
    fields = {f.name: None for f in dataclasses.fields(SensorData)}
    fields.update(
        imu_t=t,
        accel=np.tile(f, (t.size, 1)),
        gyro=np.zeros((t.size, 3)),
        wheel_t=np.zeros(0),
        wheel_speed=np.zeros(0),
    )
    return SensorData(**fields)


def test_a_steady_start_gives_its_pitch_and_one_g() -> None:
    attitude, force_g = _initial_attitude(_still(0.1), 0.0, 0.3)
    np.testing.assert_allclose(attitude, [0.0, 0.1, 0.3], atol=1e-12)
    assert abs(force_g - 1.0) < 1e-12
    assert _unsteady_start(force_g, "local") == []


def test_an_unexplained_force_at_the_start_is_said() -> None:
    """The real Ouster's first second: 0.41 g forward the wheels do not explain."""
    _, force_g = _initial_attitude(_still(0.0, extra_fwd_mps2=4.05), 0.0, 0.0)
    assert force_g > 1.0 + STEADY_START_G
    (line,) = _unsteady_start(force_g, "local")
    assert f"{force_g:.3f} g, not 1 g" in line and "without GPS nothing corrects them" in line
    (line,) = _unsteady_start(force_g, "gps")
    assert "until the GPS velocities correct them" in line
    assert _unsteady_start(float("nan"), "gps") == []
