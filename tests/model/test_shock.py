"""The shock filter (paper Sect. 5.1) from its taps, its streaming, the delay compensation,
and the band-limited peak of a pulse that falls between samples."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from toolkit.analysis.fig5 import fit_line
from toolkit.errors import StageError
from toolkit.model.shock import (
    band_limited_peak,
    design_shock_fir,
    event_shock,
    filter_stream,
    upsample,
)

PERIOD_NS = 10_000_000  # 100 Hz


def response(taps: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """|H| on a fine grid including 0 and Nyquist, computed here from the taps alone."""
    f, h = signal.freqz(taps, worN=16384, fs=rate_hz, include_nyquist=True)
    return f, np.abs(h)


@pytest.mark.parametrize("rate_hz", [100.0, 99.9976, 50.0, 125.0])
def test_fir_meets_its_specification_from_the_taps(rate_hz: float) -> None:
    fir = design_shock_fir(rate_hz, taps=40, stop_hz=10.0, pass_hz=15.0)
    taps = fir.taps
    assert taps.size == 40
    np.testing.assert_allclose(taps, -taps[::-1], atol=1e-15)  # antisymmetric: type IV
    f, gain = response(taps, rate_hz)
    assert gain[0] < 1e-12  # zero at DC: gravity removed
    assert abs(taps.sum()) < 1e-12
    stop_db = 20 * np.log10(gain[f <= 10.0].max())
    passband = gain[f >= 15.0]
    print(
        f"\n{rate_hz} Hz: stopband max {stop_db:.1f} dB on 0-10 Hz, passband gain "
        f"{passband.min():.4f}-{passband.max():.4f} on 15-{rate_hz / 2} Hz"
    )
    assert stop_db <= -30.0
    assert passband.min() >= 0.95 and passband.max() <= 1.05
    # Linear phase: the group delay is (N - 1) / 2 = 19.5 samples across the passband.
    w = np.linspace(16.0, rate_hz / 2 - 1.0, 20)
    _, gd = signal.group_delay((taps, [1.0]), w=w, fs=rate_hz)
    np.testing.assert_allclose(gd, 19.5, atol=1e-6)
    assert fir.delay_samples == 19.5


def test_fir_at_100_hz_numbers() -> None:
    """The numbers the manifest reports at the simulator's rate."""
    fir = design_shock_fir(100.0)
    assert fir.stopband_db == pytest.approx(-42.25, abs=0.05)
    assert 0.985 < fir.passband_min < 1.0 < fir.passband_max < 1.015


@pytest.mark.parametrize(
    ("rate_hz", "taps", "words"),
    [
        (25.0, 40, ["IMU rate 25 Hz", "Nyquist frequency 12.5 Hz", "fir_pass_hz"]),
        (30.0, 40, ["IMU rate 30 Hz", "Nyquist frequency 15 Hz"]),
        # The Husky's IMU: Nyquist 0.005 Hz above the pass edge is no band at all.
        (30.01, 40, ["IMU rate 30.01 Hz", "at least 5 Hz above"]),
        (200.0, 40, ["IMU rate 200 Hz", "40 taps", "label.fir_taps >= 48"]),
        (100.0, 41, ["label.fir_taps = 41", "even"]),
    ],
)
def test_unsupported_band_fails_with_one_line(rate_hz: float, taps: int, words: list[str]) -> None:
    with pytest.raises(StageError) as info:
        design_shock_fir(rate_hz, taps=taps, where="/ws/logs/x/imu.parquet")
    text = str(info.value)
    assert "\n" not in text and text.startswith("/ws/logs/x/imu.parquet: ")
    for w in words:
        assert w in text


def test_more_taps_carry_a_faster_imu() -> None:
    """The hint is right: 48 taps do meet the specification at 200 Hz."""
    fir = design_shock_fir(200.0, taps=48)
    f, gain = response(fir.taps, 200.0)
    assert 20 * np.log10(gain[f <= 10.0].max()) <= -30.0
    assert np.all(np.abs(gain[f >= 15.0] - 1.0) <= 0.05)


def chunks(t: np.ndarray, x: np.ndarray, sizes: list[int]) -> list[tuple[np.ndarray, np.ndarray]]:
    out, i, k = [], 0, 0
    while i < t.size:
        n = sizes[k % len(sizes)]
        out.append((t[i : i + n], x[i : i + n]))
        i, k = i + n, k + 1
    return out


def test_streamed_filter_equals_lfilter_and_compensates_the_half_sample() -> None:
    fir = design_shock_fir(100.0)
    rng = np.random.default_rng(3)
    x = rng.normal(size=3000) + 9.8
    t = 5_000_000_000 + np.arange(x.size, dtype=np.int64) * PERIOD_NS
    whole = signal.lfilter(fir.taps, [1.0], x)
    out = list(filter_stream(chunks(t, x, [1, 7, 39, 40, 41, 500]), fir.taps, 15_000_000))
    y = np.concatenate([o.value for o in out])
    ty = np.concatenate([o.t_ns for o in out])
    # Only outputs with a full window: the first at input 39.
    np.testing.assert_allclose(y, whole[39:], rtol=0, atol=1e-12)
    # Stamped t - 19.5 periods, exactly (195 ms here, not 190 or 200).
    np.testing.assert_array_equal(ty, t[39:] - 195_000_000)
    assert all((o.run == 0).all() for o in out)


def test_a_gap_restarts_the_filter() -> None:
    fir = design_shock_fir(100.0)
    t = np.arange(200, dtype=np.int64) * PERIOD_NS
    t[120:] += 50 * PERIOD_NS  # a 0.5 s gap after sample 119
    x = np.sin(np.arange(200) * 0.7)
    out = list(filter_stream(chunks(t, x, [64]), fir.taps, 15_000_000))
    ty = np.concatenate([o.t_ns for o in out])
    run = np.concatenate([o.run for o in out])
    y = np.concatenate([o.value for o in out])
    # 120 - 39 outputs before the gap, 80 - 39 after, none whose window spans it.
    assert (run == 0).sum() == 81 and (run == 1).sum() == 41
    np.testing.assert_allclose(y[run == 1], signal.lfilter(fir.taps, [1.0], x[120:])[39:])
    assert ty[run == 1][0] == t[120 + 39] - 195_000_000


def burst(t_s: np.ndarray, centre_s: float, freq_hz: float, sigma_s: float) -> np.ndarray:
    """A Gaussian-windowed cosine, peak 1 at ``centre_s``."""
    u = t_s - centre_s
    return np.asarray(np.exp(-0.5 * (u / sigma_s) ** 2) * np.cos(2 * np.pi * freq_hz * u))


def test_band_limited_peak_recovers_a_25_hz_burst_between_samples() -> None:
    """A 25 Hz burst is sampled every quarter cycle: the largest sample can read 29 % low; the
    band-limited peak is within 0.5 % at every phase tried."""
    t_ns = np.arange(200, dtype=np.int64) * PERIOD_NS
    t_s = t_ns * 1e-9
    raw_worst, interp = 1.0, []
    for offset_ms in np.linspace(0.0, 10.0, 41)[:-1]:
        centre = 1.0 + offset_ms * 1e-3
        x = 0.7 * burst(t_s, centre, 25.0, 0.04)
        peak, when = band_limited_peak(t_ns, x, t_ns[60], t_ns[140])
        raw_worst = min(raw_worst, float(np.abs(x).max()) / 0.7)
        interp.append(peak / 0.7)
        assert abs(when * 1e-9 - centre) < 0.7e-3  # placed within 0.07 sample
        assert peak >= np.abs(x[60:140]).max()
    print(
        f"\nraw sample max worst {raw_worst:.3f}, band-limited {min(interp):.4f}-{max(interp):.4f}"
    )
    assert raw_worst < 0.75
    assert min(interp) > 0.995 and max(interp) < 1.005


def test_filtered_pulse_peak_and_time() -> None:
    """Through the whole chain: a 0.5 G, 25 Hz cosine burst centred 0.02 sample after an
    input sample, so half-way between two outputs (stamped at t - 19.5 samples).

    The type-IV filter passes it with its envelope delayed by exactly the compensated 19.5
    samples but its carrier in quadrature (antisymmetric taps: +90 deg on top of the linear
    phase), so it comes out as a sine burst: zero at the centre, |peak| a quarter cycle
    (10 ms) either side, on the envelope there (exp(-(10/40)^2 / 2) = 0.97 of 0.5 G). The
    band-limited peak must equal the peak of the continuous filtered signal, measured
    independently: the same burst sampled on 200 grids shifted by fractions of a sample, each
    filtered, the largest output of all."""
    fir = design_shock_fir(100.0)
    t_ns = 7_000_000_000 + np.arange(400, dtype=np.int64) * PERIOD_NS
    centre_ns = int(t_ns[200]) + 200_000
    g = 9.80665
    x = g + 0.5 * g * burst((t_ns - centre_ns) * 1e-9, 0.0, 25.0, 0.04)
    (out,) = filter_stream([(t_ns, x)], fir.taps, 15_000_000)
    got = event_shock(
        out.t_ns,
        out.value,
        out.run,
        centre_ns - 50_000_000,
        centre_ns + 50_000_000,
        "max_abs",
        15_000_000,
    )
    assert got is not None
    t_s = (t_ns - t_ns[0]) * 1e-9
    reference = max(
        float(np.abs(signal.lfilter(fir.taps, [1.0], 0.5 * burst(t_s, 2.0 + d, 25.0, 0.04))).max())
        for d in np.linspace(0.0, 0.01, 200, endpoint=False)
    )
    raw = float(np.abs(out.value).max()) / g
    print(
        f"\nfiltered burst: band-limited {got.shock_mps2 / g:.4f} G, continuous reference "
        f"{reference:.4f} G, largest sample {raw:.4f} G, peak {got.peak_t_ns - centre_ns} ns "
        "from the centre"
    )
    assert got.shock_mps2 / g == pytest.approx(reference, rel=0.002)
    assert raw < 0.9 * reference  # between outputs, the largest sample reads >10 % low
    envelope_at_quarter_cycle = 0.5 * np.exp(-0.5 * (0.010 / 0.04) ** 2)
    assert reference == pytest.approx(envelope_at_quarter_cycle, rel=0.02)
    assert 8_000_000 < abs(got.peak_t_ns - centre_ns) < 11_000_000
    # The compensation is exact: a burst centred on an input sample comes out antisymmetric
    # about that very time (outputs at +-0.5, +-1.5, ... samples from it), which a delay
    # rounded to 19 or 20 samples would not be.
    c0 = int(t_ns[200])
    (out0,) = filter_stream(
        [(t_ns, g + 0.5 * g * burst((t_ns - c0) * 1e-9, 0.0, 25.0, 0.04))], fir.taps, 15_000_000
    )
    k = int(np.searchsorted(out0.t_ns, c0))
    assert out0.t_ns[k] - c0 == 5_000_000 and c0 - out0.t_ns[k - 1] == 5_000_000
    np.testing.assert_allclose(out0.value[k : k + 15], -out0.value[k - 15 : k][::-1], atol=1e-9)
    assert np.abs(out0.value[k - 15 : k + 15]).max() > 0.3 * g


def test_event_shock_refuses_spans_it_cannot_cover() -> None:
    t = np.arange(100, dtype=np.int64) * PERIOD_NS
    v = np.ones(100)
    run = np.zeros(100, np.int64)
    run[50:] = 1
    gap = 15_000_000
    assert event_shock(t, v, run, t[10], t[20], "max_abs", gap) is not None
    assert event_shock(t, v, run, t[45], t[55], "max_abs", gap) is None  # across a restart
    assert event_shock(t, v, run, -100_000_000, t[5], "rms", gap) is None  # before the IMU
    assert event_shock(t, v, run, t[95], t[99] + 100_000_000, "rms", gap) is None  # after it
    rms = event_shock(t, np.arange(100.0), run, t[10], t[13], "rms", gap)
    assert rms is not None and rms.samples == 3
    assert rms.shock_mps2 == pytest.approx(np.sqrt((100 + 121 + 144) / 3))


def test_fit_line() -> None:
    x = np.array([10.0, 20.0, 30.0, 40.0])
    fit = fit_line(x, 0.02 * x - 0.1)
    assert fit.slope == pytest.approx(0.02) and fit.intercept == pytest.approx(-0.1)
    assert fit.r2 == pytest.approx(1.0)
    noisy = fit_line(x, np.array([0.1, 0.35, 0.45, 0.7]))
    assert 0.9 < noisy.r2 < 1.0
    with pytest.raises(ValueError):
        fit_line(np.array([1.0, 1.0]), np.array([0.0, 1.0]))


def test_a_repeated_stamp_is_dropped_not_taken_for_a_gap() -> None:
    """Five repeated stamps in 30 s of 100 Hz: one run, the same outputs as without them."""
    from toolkit.model.shock import design_shock_fir, filter_stream

    fir = design_shock_fir(100.0, 40, 10.0, 15.0)
    rng = np.random.default_rng(3)
    t = np.arange(3000, dtype=np.int64) * 10_000_000
    x = rng.normal(size=t.size)
    dup = np.sort(rng.choice(np.arange(100, 2900), 5, replace=False))
    t_bad = np.insert(t, dup + 1, t[dup])
    x_bad = np.insert(x, dup + 1, 99.0)  # the repeat carries a wild value: it must not count
    clean = list(filter_stream([(t, x)], fir.taps, 15_000_000))
    bad = list(
        filter_stream(
            [(t_bad[:1500], x_bad[:1500]), (t_bad[1500:], x_bad[1500:])], fir.taps, 15_000_000
        )
    )
    cat = lambda chunks, f: np.concatenate([getattr(c, f) for c in chunks])  # noqa: E731
    np.testing.assert_array_equal(cat(bad, "t_ns"), cat(clean, "t_ns"))
    np.testing.assert_allclose(cat(bad, "value"), cat(clean, "value"))
    assert set(cat(bad, "run").tolist()) == {0}


def test_upsample_is_resample_polys_own_interpolation() -> None:
    """The interpolating filter designed once gives what resample_poly designs on each call,
    bit for bit: the span peak (and so ``label.attribution = "span_peak"``) is unchanged."""
    rng = np.random.default_rng(11)
    for n in (2, 3, 14, 46, 91, 700):
        x = rng.normal(size=n) * 5.0
        np.testing.assert_array_equal(
            upsample(x), signal.resample_poly(x, 16, 1)[: (n - 1) * 16 + 1]
        )


def test_a_design_that_does_not_converge_is_one_line_naming_the_key() -> None:
    """1,000 taps (the largest the configuration accepts) over a 5 Hz transition at 100 Hz:
    the Parks-McClellan exchange fails; that is the user's setting, said as such."""
    with pytest.raises(StageError, match=r"label.fir_taps = 1000: .*does not converge") as err:
        design_shock_fir(100.0, taps=1000, where="/ws/logs/x/imu.parquet")
    assert "imu.parquet" in str(err.value) and "\n" not in str(err.value)
