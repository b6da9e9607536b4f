"""The race controller's shock meter: the vehicle's own IMU read through the labeller's filter.

Stanley's reactive speed controller (Thrun et al. 2006b; the paper's sect. 7.2) slowed down
after the vehicle *felt* a shock, so it can only know what its IMU reports: 100 Hz samples of
specific force, each an average over its 10 ms, with the IMU's noise and bias. The meter
therefore reads the simulated IMU's vertical axis (the samples the log will hold), filters it
with the label stage's shock filter (:func:`toolkit.model.shock.design_shock_fir`: the
40-tap type-IV FIR that removes 0-10 Hz, designed from the default configuration's ``[label]``
section) and reports the largest ``|filtered|`` of each block in G. Reading the true 1 kHz
acceleration instead (as the simulator did before) let the controller react to shocks no
sensor on the vehicle could see.

The filter runs as a stream: the last ``N - 1`` samples of a block are kept and prepended to
the next, and only outputs whose whole window of N samples is known are used (no start-up
transient; the same ``valid`` convolution the label stage uses).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import FloatArray
from toolkit.config import LabelConfig
from toolkit.model.shock import ShockFir, design_shock_fir


@dataclass
class ShockMeter:
    """Peak shock per block of IMU samples (see the module docstring)."""

    fir: ShockFir
    #: 1 G, m/s^2 (the label configuration's ``gravity_mps2``).
    gravity_mps2: float
    _tail: FloatArray = field(default_factory=lambda: np.zeros(0))

    @classmethod
    def for_imu(cls, rate_hz: float, label: LabelConfig) -> ShockMeter:
        """The meter for an IMU at ``rate_hz``, with the label stage's filter for ``label``."""
        fir = design_shock_fir(rate_hz, label.fir_taps, label.fir_stop_hz, label.fir_pass_hz)
        return cls(fir, label.gravity_mps2)

    def read(self, accel_z_mps2: NDArray[np.floating[Any]]) -> float:
        """The largest ``|filtered vertical specific force|`` (G) over the outputs that the
        new samples ``accel_z_mps2`` (n,) complete; 0 until N samples have been seen."""
        x = np.concatenate([self._tail, np.asarray(accel_z_mps2, dtype=np.float64)])
        n = self.fir.taps.size
        self._tail = x[-(n - 1) :] if n > 1 else np.zeros(0)
        if x.size < n:
            return 0.0
        y = np.convolve(x, self.fir.taps, mode="valid")
        return float(np.abs(y).max()) / self.gravity_mps2


__all__ = ["ShockMeter"]
