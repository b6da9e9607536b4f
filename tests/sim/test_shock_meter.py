"""The race controller's shock meter reads the IMU through the label stage's filter."""

from __future__ import annotations

import numpy as np

from toolkit.config import default_config
from toolkit.model.shock import design_shock_fir
from toolkit.sim.shock_meter import ShockMeter

RATE_HZ = 100.0
G = 9.80665


def test_streamed_blocks_read_what_the_label_filter_gives_on_the_whole_signal() -> None:
    """Ten-sample blocks (0.1 s at 100 Hz), as the simulator feeds it: each block's reading
    is the peak of the label filter's valid outputs that block completes."""
    label = default_config().label
    meter = ShockMeter.for_imu(RATE_HZ, label)
    fir = design_shock_fir(RATE_HZ, label.fir_taps, label.fir_stop_hz, label.fir_pass_hz)
    assert np.array_equal(meter.fir.taps, fir.taps)
    rng = np.random.default_rng(3)
    x = G + rng.normal(0, 2.0, 400)
    y = np.abs(np.convolve(x, fir.taps, mode="valid")) / G  # output j ends at sample j + 39
    readings = [meter.read(x[k : k + 10]) for k in range(0, x.size, 10)]
    n = fir.taps.size
    for b, got in enumerate(readings):
        last = 10 * b + 9  # the block's last sample
        done = y[max(0, 10 * b - (n - 1)) : max(0, last - (n - 1) + 1)]
        assert got == (float(done.max()) if done.size else 0.0)


def test_it_passes_a_shock_and_not_the_body_motion() -> None:
    """A 25 Hz vibration of 0.5 G reads 0.5 G within the filter's 5 % (at the sampling phase
    that puts a filtered sample on the crest; a sampled peak under-reads by up to cos 45 deg
    at other phases, as any 100 Hz meter does); a 2 Hz body bounce of 1 G (and gravity)
    reads at most 3 % of it (the filter's -30 dB stopband)."""
    t = np.arange(300) / RATE_HZ

    def peak(amplitude_g: float, hz: float, phase: float) -> float:
        meter = ShockMeter.for_imu(RATE_HZ, default_config().label)
        x = G * (1.0 + amplitude_g * np.sin(2 * np.pi * hz * t + phase))
        return max(meter.read(x[k : k + 10]) for k in range(0, x.size, 10))

    phases = np.linspace(0, np.pi / 2, 9)
    shock = [peak(0.5, 25.0, ph) for ph in phases]
    assert 0.475 <= max(shock) <= 0.525 and min(shock) >= 0.5 * np.cos(np.pi / 4) * 0.95, shock
    assert max(peak(1.0, 2.0, ph) for ph in phases) <= 0.03
