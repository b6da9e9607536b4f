"""The race's reactive speed controller (Thrun et al. 2006b; Sect. 7.2 of the paper) and the
route's safe speed profile: ``v <= sqrt(a_lat / |kappa|)`` in bends, braking ahead of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from toolkit.arrays import AnyFloatArray as FloatArray


@dataclass(frozen=True)
class ReactiveSpeedParams:
    """The race's reactive speed controller (Thrun et al. 2006b), after Sect. 7.2 of the paper.

    After a measured shock above ``shock_threshold_g`` the speed cap drops to
    ``(1 - slowdown_fraction)`` of the current speed (never below ``min_speed_mps``) and then
    recovers at ``recovery_mps_per_m`` per metre driven.
    """

    shock_threshold_g: float = 0.35
    slowdown_fraction: float = 0.3
    min_speed_mps: float = 4.0
    recovery_mps_per_m: float = 0.05
    accel_mps2: float = 1.2
    brake_mps2: float = 2.5
    lateral_accel_mps2: float = 2.0
    enabled: bool = True


@dataclass
class ReactiveSpeedController:
    """Speed target from the route's limits, curvature and the reactive shock cap."""

    params: ReactiveSpeedParams
    cap_mps: float = np.inf

    def on_shock(self, shock_g: float, speed_mps: float) -> None:
        if self.params.enabled and shock_g > self.params.shock_threshold_g:
            new_cap = max(
                self.params.min_speed_mps, speed_mps * (1 - self.params.slowdown_fraction)
            )
            self.cap_mps = min(self.cap_mps, new_cap)

    def recover(self, distance_m: float) -> None:
        if np.isfinite(self.cap_mps):
            self.cap_mps += self.params.recovery_mps_per_m * distance_m
            if self.cap_mps > 40.0:
                self.cap_mps = np.inf

    def acceleration(self, speed_mps: float, limit_mps: float) -> float:
        target = min(limit_mps, self.cap_mps)
        a = 0.8 * (target - speed_mps)
        return float(np.clip(a, -self.params.brake_mps2, self.params.accel_mps2))


def safe_speed_profile(
    s_m: FloatArray, limit_mps: FloatArray, curvature_per_m: FloatArray, p: ReactiveSpeedParams
) -> FloatArray:
    """Speed limit along the route that also respects curves and braking ahead of them.

    ``v <= sqrt(a_lat / |kappa|)`` in bends, and a backward pass so that the vehicle can
    brake at ``brake_mps2`` (with margin) to every lower limit ahead.
    """
    v = np.minimum(
        limit_mps, np.sqrt(p.lateral_accel_mps2 / np.maximum(np.abs(curvature_per_m), 1e-9))
    )
    ds = np.diff(s_m)
    a = 0.5 * p.brake_mps2
    out = v.copy()
    for i in range(out.size - 2, -1, -1):
        out[i] = min(out[i], np.sqrt(out[i + 1] ** 2 + 2 * a * ds[i]))
    return out
