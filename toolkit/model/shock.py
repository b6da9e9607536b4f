"""The shock filter of the paper's Sect. 5.1 and the shock of one event (Sect. 5.2).

**Filter.** The vertical specific force (the IMU's z accelerometer turned into base_link) is
filtered by a ``fir_taps``-tap (40 in the paper) linear-phase FIR that "removes 0-10 Hz":
0 Hz is gravity (whose projection on z changes with pitch and roll), 1-10 Hz the body's
suspension resonances that would smear one shock over several events. A linear-phase
high-pass of even length must be *antisymmetric* (type IV, ``h[k] = -h[N-1-k]``): a
symmetric even-length FIR (type II) has a forced zero at Nyquist, an antisymmetric one a
forced zero at DC instead, which is exactly what removes gravity. It is designed by the
Parks-McClellan exchange (:func:`scipy.signal.remez`, ``type="hilbert"`` gives the
antisymmetric kinds) as an equiripple fit of gain 0 on ``[0, stop_hz]`` and 1 on
``[pass_hz, fs/2]``, for the log's own IMU rate ``fs``, the two bands weighted so both
errors end equally far inside their limits (weight ``PASSBAND_RIPPLE / 10^(STOPBAND_DB/20)``
on the stopband). The design is then checked from its taps (:func:`fir_response`): at most
:data:`STOPBAND_DB` anywhere in ``[0, stop_hz]`` and a gain within ``1 +- PASSBAND_RIPPLE``
on ``[pass_hz, fs/2]``; a rate where ``fir_taps`` taps cannot do that (Nyquist not above
``pass_hz``, or a transition too narrow in samples at a high rate) is a StageError naming
the rate. At 100 Hz the 40 taps reach -42 dB and +-1.2 % from 15 Hz up to Nyquist.

**Delay.** The filter is causal: output ``n`` is ``sum_k h[k] x[n-k]``, symmetric about
input ``n - (N-1)/2`` = ``n - 19.5`` for 40 taps. Half a sample is a delay no integer shift
of the output removes, so each output is stamped with the *mean of the N input stamps in
its window* (:func:`filter_stream`): on a uniform grid that is ``t_n - 19.5/fs`` exactly, and
on a jittered one it averages the jitter of single stamps down by ``sqrt(N)``.

**Quadrature.** Antisymmetric taps give ``H(f) = j A(f) exp(-j 2 pi f (N-1)/(2 fs))`` with
``A`` real: linear phase *plus a constant +90 deg*. What passes comes out with its envelope
delayed by exactly the compensated (N-1)/2 samples, but its carrier a quarter cycle shifted
(a cosine burst leaves as a sine burst, a symmetric pulse as an antisymmetric one about the
same time). So the largest |filtered| of a shock lies up to a quarter period of its dominant
frequency either side of it (10 ms at 25 Hz: 0.1 m at 10 m/s, against 1.4 m events), and
reads the envelope there rather than at its crest (0.97 of it for a 25 Hz burst of 40 ms
sigma). That is the price of a zero at DC with an even length; a symmetric (type II) design
keeps the carrier but has its forced zero at Nyquist instead, so it could only be a
band-pass.

**Peak.** ``shock_g`` is the peak absolute filtered acceleration in an event. At 100 Hz a
short pulse is sampled a few times per cycle: a 25 Hz burst is sampled every quarter
cycle, so the largest sample can be ``cos 45 deg = 0.71`` of the peak between samples, and a
parabola through the three largest samples still reads 12 % low there. The filtered signal is
band-limited (it is sampled), so the continuous signal between samples is its band-limited
(sinc) interpolation: :func:`event_peak` upsamples the event's samples, with
:data:`INTERP_MARGIN` samples either side, :data:`INTERP_UP` times by polyphase FIR
interpolation (:func:`scipy.signal.resample_poly`, Kaiser-windowed sinc, beta 5, 10 input
samples a side) and takes the largest magnitude inside the event's time span. On Gaussian
bursts it recovers the true peak within 0.2 % up to 0.7 Nyquist and within 1 % at 0.8
Nyquist; above that, content too close to Nyquist to be told from its alias, it may read
low (never lower than the largest sample, which it never goes below).

**Attribution** (``label.attribution``): ``span_peak`` is the rule above, an event's shock
the band-limited peak over every filtered sample in its span; ``impact`` attributes each
impact to the one event that holds it (:mod:`toolkit.model.shock_attribution`).

Times are int64 ns; accelerations m/s^2. Shapes in the docstrings: (N,) taps, (M,) samples.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import signal

from toolkit.arrays import FloatArray, IntArray
from toolkit.errors import StageError

#: Largest gain allowed on [0, stop_hz], dB: what is left of gravity and the body modes is
#: then at most 3 % of them (a 1 G pitch change leaves < 0.03 G).
STOPBAND_DB = -30.0
#: Largest deviation of the gain from 1 on [pass_hz, Nyquist]: shocks read within 5 %.
PASSBAND_RIPPLE = 0.05
#: Narrowest passband (pass edge to Nyquist) a rate must leave, Hz: as wide as the default
#: transition band. A shock lasting tens of ms spreads its energy over tens of Hz; a 30.01 Hz
#: IMU left 0.005 Hz above a 15 Hz pass edge and "labelled" with it, which measures nothing.
MIN_PASSBAND_HZ = 5.0
#: Longest filter the hint of a design that misses the bounds searches up to (the largest
#: ``[label] fir_taps`` the configuration accepts).
MAX_TAPS = 1000
#: Frequency grid of the check (points on [0, fs/2]).
RESPONSE_POINTS = 8192
#: Upsampling factor of the peak interpolation: a 25 Hz tone at 1.6 kHz is read within
#: 1 - cos(pi * 25 / 1600) = 0.12 % at the worst grid phase.
INTERP_UP = 16
#: Input samples either side of an event that the interpolation sees: more than the
#: 10 a side of resample_poly's interpolating filter, so the event's samples are not
#: reconstructed from its zero padding.
INTERP_MARGIN = 16
#: 1 mph = 1609.344 m / 3600 s (international mile), exactly.
MPS_PER_MPH = 0.44704
#: The interpolating filter :func:`scipy.signal.resample_poly` designs for ``up =``
#: :data:`INTERP_UP` (its own call: ``firwin`` of 10 input samples a side, cutoff 1 / up, its
#: default Kaiser window of beta 5), designed once: the same coefficients give the same
#: samples bit for bit (tested), and designing them took 2/3 of each event's interpolation.
_INTERP_FILTER = np.asarray(
    signal.firwin(2 * 10 * INTERP_UP + 1, 1.0 / INTERP_UP, window=("kaiser", 5.0)), np.float64
)


@dataclass(frozen=True)
class ShockFir:
    """A designed shock filter and its measured response.

    ``taps`` (N,) antisymmetric; ``stopband_db`` the largest gain on [0, stop_hz];
    ``passband_min``/``passband_max`` the gain range on [pass_hz, rate_hz / 2].
    """

    taps: FloatArray
    rate_hz: float
    stop_hz: float
    pass_hz: float
    stopband_db: float
    passband_min: float
    passband_max: float

    @property
    def delay_samples(self) -> float:
        """The group delay, (N - 1) / 2 samples (19.5 for 40 taps)."""
        return (self.taps.size - 1) / 2.0

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready description (for the manifest)."""
        return {
            "type": "linear-phase FIR, antisymmetric even length (type IV), remez",
            "taps": [float(v) for v in self.taps],
            "rate_hz": round(self.rate_hz, 6),
            "stop_hz": self.stop_hz,
            "pass_hz": self.pass_hz,
            "stopband_max_db": round(self.stopband_db, 2),
            "passband_gain": [round(self.passband_min, 5), round(self.passband_max, 5)],
            "delay_samples": self.delay_samples,
        }


def fir_response(taps: FloatArray, rate_hz: float) -> tuple[FloatArray, FloatArray]:
    """(frequency (K,) Hz on [0, rate_hz / 2], gain |H| (K,)) of an FIR, by
    :func:`scipy.signal.freqz` on :data:`RESPONSE_POINTS` points including Nyquist."""
    f, h = signal.freqz(taps, worN=RESPONSE_POINTS, fs=rate_hz, include_nyquist=True)
    return np.asarray(f, np.float64), np.asarray(np.abs(h), np.float64)


def _remez(taps: int, rate_hz: float, stop_hz: float, pass_hz: float) -> FloatArray:
    weight = PASSBAND_RIPPLE / 10 ** (STOPBAND_DB / 20.0)
    return np.asarray(
        signal.remez(
            taps,
            [0.0, stop_hz, pass_hz, rate_hz / 2.0],
            [0.0, 1.0],
            weight=[weight, 1.0],
            fs=rate_hz,
            type="hilbert",
        ),
        np.float64,
    )


def _design_meets(taps: int, rate_hz: float, stop_hz: float, pass_hz: float) -> bool:
    """Whether ``taps`` taps meet the response bounds (a design that does not converge does
    not)."""
    try:
        h = _remez(taps, rate_hz, stop_hz, pass_hz)
    except ValueError:
        return False
    return _meets(*_measure(h, rate_hz, stop_hz, pass_hz))


def _measure(
    taps: FloatArray, rate_hz: float, stop_hz: float, pass_hz: float
) -> tuple[float, float, float]:
    f, gain = fir_response(taps, rate_hz)
    stop = float(gain[f <= stop_hz].max())
    passband = gain[f >= pass_hz]
    return 20.0 * np.log10(max(stop, 1e-300)), float(passband.min()), float(passband.max())


def _meets(stop_db: float, pmin: float, pmax: float) -> bool:
    return (
        stop_db <= STOPBAND_DB and pmin >= 1.0 - PASSBAND_RIPPLE and pmax <= 1.0 + PASSBAND_RIPPLE
    )


def design_shock_fir(
    rate_hz: float,
    taps: int = 40,
    stop_hz: float = 10.0,
    pass_hz: float = 15.0,
    *,
    where: str | Path | None = None,
) -> ShockFir:
    """The shock filter for an IMU sampled at ``rate_hz`` (see the module docstring).

    StageError (one line naming the rate, ``where`` its path) when the taps are not even,
    the bands are out of order, or the design misses :data:`STOPBAND_DB` /
    :data:`PASSBAND_RIPPLE` at this rate.
    """
    nyquist = rate_hz / 2.0
    if taps % 2:
        raise StageError(
            f"label.fir_taps = {taps}: a linear-phase FIR with zero gain at 0 Hz and gain up "
            "to Nyquist must be antisymmetric of even length (type IV); use an even number",
            path=where,
        )
    if not 0.0 < stop_hz < pass_hz:
        raise StageError(
            f"label.fir_stop_hz = {stop_hz} must be below label.fir_pass_hz = {pass_hz}",
            path=where,
        )
    if not (np.isfinite(rate_hz) and nyquist >= pass_hz + MIN_PASSBAND_HZ):
        raise StageError(
            f"IMU rate {rate_hz:.6g} Hz cannot carry the shock band: its Nyquist frequency "
            f"{nyquist:.6g} Hz is not at least {MIN_PASSBAND_HZ:g} Hz above "
            f"label.fir_pass_hz = {pass_hz} Hz (the filter removes 0-{stop_hz} Hz and must "
            "pass a band above it)",
            path=where,
        )
    try:
        h = _remez(taps, rate_hz, stop_hz, pass_hz)
    except ValueError as exc:  # the exchange's "Failure to converge"
        raise StageError(
            f"label.fir_taps = {taps}: the filter's design (Parks-McClellan, "
            f"scipy.signal.remez) does not converge at IMU rate {rate_hz:.6g} Hz "
            f"({' '.join(str(exc).split())}); so "
            f"long a filter is ill-conditioned over the {pass_hz - stop_hz:g} Hz transition "
            "band: use fewer taps (the paper's 40)",
            path=where,
        ) from None
    stop_db, pmin, pmax = _measure(h, rate_hz, stop_hz, pass_hz)
    if not _meets(stop_db, pmin, pmax):
        need = next(
            (
                n
                for n in range(taps + 2, MAX_TAPS + 1, 2)
                if _design_meets(n, rate_hz, stop_hz, pass_hz)
            ),
            None,
        )
        hint = f"label.fir_taps >= {need}" if need else "a wider label.fir_pass_hz"
        raise StageError(
            f"IMU rate {rate_hz:.6g} Hz: {taps} taps reach only {stop_db:.1f} dB on "
            f"0-{stop_hz} Hz (need <= {STOPBAND_DB:.0f}) and gain {pmin:.3f}-{pmax:.3f} on "
            f"{pass_hz}-{nyquist:.6g} Hz (need 1 +- {PASSBAND_RIPPLE}); set {hint}",
            path=where,
        )
    return ShockFir(h, float(rate_hz), float(stop_hz), float(pass_hz), stop_db, pmin, pmax)


@dataclass(frozen=True)
class FilteredChunk:
    """Filter outputs: delay-compensated ``t_ns`` (M,), ``value`` (M,) m/s^2, ``run`` (M,)
    the number of the contiguous IMU run each belongs to (the filter restarts after a gap,
    so interpolation never reaches across one)."""

    t_ns: IntArray
    value: FloatArray
    run: IntArray


def filter_stream(
    chunks: Iterable[tuple[IntArray, FloatArray]], taps: FloatArray, max_gap_ns: int
) -> Iterator[FilteredChunk]:
    """Filter a stream of ``(t_ns (M,), x (M,))`` pieces in bounded memory.

    Overlapping windows: the last ``N - 1`` inputs of a piece are prepended to the next, and
    ``np.convolve(..., "valid")`` gives exactly the outputs whose whole window of N inputs is
    known, so the start-up transient is never emitted. A step between stamps longer than
    ``max_gap_ns`` ends a run: the next run starts the filter afresh. A sample whose stamp
    does not advance past every earlier one is dropped.
    Output ``j`` is stamped with the mean of its window's N input stamps (module docstring).
    """
    n = int(taps.size)
    t_tail = np.zeros(0, np.int64)
    x_tail = np.zeros(0, np.float64)
    run = 0
    for t_new, x_new in chunks:
        if t_new.size == 0:
            continue
        t = np.concatenate([t_tail, np.asarray(t_new, np.int64)])
        x = np.concatenate([x_tail, np.asarray(x_new, np.float64)])
        # A sample whose stamp does not advance (a repeated or backward stamp) is dropped, not
        # taken as a gap: restarting the filter would lose 39 samples for one bad stamp.
        advancing = np.ones(t.size, dtype=bool)
        advancing[1:] = t[1:] > np.maximum.accumulate(t)[:-1]
        if not advancing.all():
            t, x = t[advancing], x[advancing]
        dt = np.diff(t)
        breaks = np.flatnonzero(dt > max_gap_ns) + 1
        edges = [0, *breaks.tolist(), t.size]
        outs: list[FilteredChunk] = []
        for k in range(len(edges) - 1):
            if k > 0:
                run += 1
            lo, hi = edges[k], edges[k + 1]
            if hi - lo < n:
                continue
            ts, xs = t[lo:hi], x[lo:hi]
            y = np.convolve(xs, taps, mode="valid")
            rel = np.concatenate([[0], np.cumsum(ts - ts[0])])
            sums = rel[n:] - rel[:-n]  # sum of each window's stamps, relative to ts[0]
            t_out = ts[0] + (sums + n // 2) // n
            outs.append(FilteredChunk(t_out, y, np.full(y.size, run, np.int64)))
        lo = edges[-2]
        t_tail, x_tail = t[max(lo, t.size - (n - 1)) :], x[max(lo, t.size - (n - 1)) :]
        if outs:
            yield FilteredChunk(
                np.concatenate([o.t_ns for o in outs]),
                np.concatenate([o.value for o in outs]),
                np.concatenate([o.run for o in outs]),
            )


def upsample(value: FloatArray) -> FloatArray:
    """The band-limited interpolation of samples ``value`` (M,): ``(M - 1) * INTERP_UP + 1``
    fine samples, the first on the first sample, each ``1 / INTERP_UP`` of a sample after the
    last (:func:`scipy.signal.resample_poly` with its own filter, designed once)."""
    fine = signal.resample_poly(value, INTERP_UP, 1, window=_INTERP_FILTER)
    return np.asarray(fine[: (value.size - 1) * INTERP_UP + 1], np.float64)


def band_limited_peak(
    t_ns: IntArray, value: FloatArray, t0_ns: int, t1_ns: int
) -> tuple[float, int]:
    """The largest |value| of the band-limited signal through the samples, over the time
    span ``[t0_ns, t1_ns)``, and when it occurs (ns).

    ``t_ns``/``value`` (M,) are one contiguous run of samples covering the span plus up to
    :data:`INTERP_MARGIN` samples either side. Upsampled :data:`INTERP_UP` times by
    :func:`scipy.signal.resample_poly`; the fine samples are placed on the run's mean
    spacing. Never below the largest sample inside the span.
    """
    inside = (t_ns >= t0_ns) & (t_ns < t1_ns)
    if not inside.any():
        raise ValueError("no sample inside the span")
    k = int(np.argmax(np.where(inside, np.abs(value), -1.0)))
    best, best_t = float(abs(value[k])), int(t_ns[k])
    if value.size < 2:
        return best, best_t
    fine = upsample(value)
    step = (t_ns[-1] - t_ns[0]) / (value.size - 1) / INTERP_UP
    t_fine = t_ns[0] + np.round(np.arange(fine.size) * step).astype(np.int64)
    use = (t_fine >= t0_ns) & (t_fine < t1_ns)
    if use.any():
        j = int(np.argmax(np.where(use, np.abs(fine), -1.0)))
        if abs(fine[j]) > best:
            best, best_t = float(abs(fine[j])), int(t_fine[j])
    return best, best_t


@dataclass(frozen=True)
class EventShock:
    """The shock of one event: ``shock_mps2`` (the statistic of the filtered acceleration),
    the time of the peak (``max_abs``; the span's midpoint for ``rms``) and the filtered
    samples inside the span."""

    shock_mps2: float
    peak_t_ns: int
    samples: int


def covered_span(
    t_ns: IntArray, run: IntArray, t0_ns: int, t1_ns: int, max_gap_ns: int
) -> tuple[int, int] | None:
    """The samples ``[lo, hi)`` inside ``[t0_ns, t1_ns)``, or None when they do not cover it
    (see :func:`event_shock`)."""
    lo = int(np.searchsorted(t_ns, t0_ns, side="left"))
    hi = int(np.searchsorted(t_ns, t1_ns, side="left"))
    if hi <= lo:
        return None
    if t_ns[lo] - t0_ns > max_gap_ns or t1_ns - t_ns[hi - 1] > max_gap_ns:
        return None
    if run[hi - 1] != run[lo]:
        return None
    return lo, hi


def event_shock(
    t_ns: IntArray,
    value: FloatArray,
    run: IntArray,
    t0_ns: int,
    t1_ns: int,
    statistic: str,
    max_gap_ns: int,
) -> EventShock | None:
    """The shock over ``[t0_ns, t1_ns)`` from filtered samples (M,) sorted by time, or None
    when they do not cover the span: no sample inside, the first or last more than
    ``max_gap_ns`` from its end, or a run break (an IMU gap) inside it.

    ``statistic``: ``max_abs`` (:func:`band_limited_peak`, with the margin samples of the
    same run) or ``rms`` (root mean square of the samples inside).
    """
    covered = covered_span(t_ns, run, t0_ns, t1_ns, max_gap_ns)
    if covered is None:
        return None
    lo, hi = covered
    r = run[lo]
    if statistic == "rms":
        v = value[lo:hi]
        return EventShock(float(np.sqrt(np.mean(v * v))), (t0_ns + t1_ns) // 2, hi - lo)
    a = max(lo - INTERP_MARGIN, 0)
    b = min(hi + INTERP_MARGIN, t_ns.size)
    same = run[a:b] == r
    idx = np.arange(a, b)[same]
    peak, when = band_limited_peak(t_ns[idx], value[idx], t0_ns, t1_ns)
    return EventShock(peak, when, hi - lo)


__all__ = [
    "INTERP_MARGIN",
    "INTERP_UP",
    "MPS_PER_MPH",
    "PASSBAND_RIPPLE",
    "STOPBAND_DB",
    "EventShock",
    "FilteredChunk",
    "ShockFir",
    "band_limited_peak",
    "covered_span",
    "design_shock_fir",
    "event_shock",
    "filter_stream",
    "fir_response",
    "upsample",
]
