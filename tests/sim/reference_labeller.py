"""A small reference labeller after the paper's Sect. 5, for checking simulated logs.

* The IMU's z acceleration is filtered by a 40-tap FIR that removes 0-10 Hz (an even-length
  high-pass FIR must be a type-II design, so it is a 10-45 Hz band-pass at the IMU's 100 Hz;
  45 Hz leaves the response well-defined up to Nyquist). The filter is causal, so each output
  is credited to the time of its input shifted by the filter's group delay (19.5 samples).
* Events are consecutive ``event_length_m`` stretches of the rear axle's horizontal travel
  (``base_link`` is on the ground below the rear axle), from the true positions.
* Per event: ``shock_g`` = max |filtered| / g over the event, ``speed_mph`` = mean true speed
  * 2.23694, ``ruggedness`` = shock_g / speed_mph, positive when >= 0.02 G/mph.

The first samples, while the filter has not yet seen 40 inputs, and the incomplete events at
both ends are left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.signal import firwin, lfilter

FloatArray = NDArray[np.float64]

GRAVITY_MPS2 = 9.80665
MPS_TO_MPH = 2.23694
FIR_TAPS = 40
EVENT_LENGTH_M = 1.4
POSITIVE_G_PER_MPH = 0.02


def shock_filter_taps(rate_hz: float = 100.0, taps: int = FIR_TAPS) -> FloatArray:
    """The 40-tap FIR removing 0-10 Hz (a type-II band-pass 10-45 Hz)."""
    return np.asarray(firwin(taps, [10.0, 45.0], pass_zero=False, fs=rate_hz))


def filtered_shock(
    t_ns: NDArray[np.int64],
    accel_z: FloatArray,
    rate_hz: float = 100.0,
    taps: FloatArray | None = None,
) -> tuple[NDArray[np.int64], FloatArray, NDArray[np.bool_]]:
    """Filtered z acceleration, the delay-compensated times of its samples, and a mask of the
    samples past the filter's start-up (the first ``taps`` outputs are transients). ``taps``
    another linear-phase FIR than this module's (its delay is its half length too)."""
    taps = shock_filter_taps(rate_hz) if taps is None else taps
    out = lfilter(taps, [1.0], accel_z)
    delay_ns = int(round((taps.size - 1) / 2 * 1e9 / rate_hz))
    settled = np.arange(out.size) >= taps.size
    return t_ns - delay_ns, np.asarray(out), settled


@dataclass(frozen=True)
class Events:
    shock_g: FloatArray
    speed_mph: FloatArray

    @property
    def ruggedness(self) -> FloatArray:
        return self.shock_g / self.speed_mph

    @property
    def positive(self) -> NDArray[np.bool_]:
        return self.ruggedness >= POSITIVE_G_PER_MPH

    def __len__(self) -> int:
        return int(self.shock_g.size)


def label_events(
    imu_t_ns: NDArray[np.int64],
    imu_accel_z: FloatArray,
    truth_t_ns: NDArray[np.int64],
    truth_xy: FloatArray,
    truth_speed: FloatArray,
    event_length_m: float = EVENT_LENGTH_M,
    imu_rate_hz: float = 100.0,
) -> Events:
    """Label a drive: IMU samples at true times ``imu_t_ns``; truth poses (rear axle) and
    speeds at ``truth_t_ns``."""
    t0 = truth_t_ns[0]
    tt = (truth_t_ns - t0) * 1e-9
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(truth_xy, axis=0).T))])
    n_events = int(travel[-1] // event_length_m)

    t_f, shock, settled = filtered_shock(imu_t_ns, imu_accel_z, imu_rate_hz)
    inside = settled & (t_f >= truth_t_ns[0]) & (t_f <= truth_t_ns[-1])
    where = np.interp((t_f - t0) * 1e-9, tt, travel)
    ev = np.floor(where / event_length_m).astype(np.int64)
    use = inside & (ev < n_events)
    peak = np.zeros(n_events)
    np.maximum.at(peak, ev[use], np.abs(shock[use]) / GRAVITY_MPS2)

    ev_truth = np.floor(travel / event_length_m).astype(np.int64)
    ok = ev_truth < n_events
    count = np.bincount(ev_truth[ok], minlength=n_events)
    speed = np.bincount(ev_truth[ok], weights=truth_speed[ok], minlength=n_events)
    speed = speed / np.maximum(count, 1)

    # Complete events only: after the first settled filter output, with truth samples.
    first = int(ev[use].min()) + 1
    keep = (np.arange(n_events) >= first) & (count > 0)
    return Events(shock_g=peak[keep], speed_mph=speed[keep] * MPS_TO_MPH)
