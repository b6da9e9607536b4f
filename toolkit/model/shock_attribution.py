"""Which event an impact belongs to: the ``impact`` attribution of the shock filter's output
(paper Sect. 5.2; the filter is :mod:`toolkit.model.shock`).

**Attribution** (``label.attribution``, issue 26). ``span_peak`` is the rule above: an event's
shock is the band-limited peak over every filtered sample in its span. But the filtered signal
of one impact is not confined to its event: the quadrature splits it into twin crests a
quarter period either side of it, its flanks and the ringing of the filter's taps reach a
neighbouring event, and the largest |filtered| of that neighbour is then the *flank* of this
impact at the boundary: on three simulated 7.9 km race logs (seeds 601-603, 16,944 events)
7 of the 56 positives were such a neighbour's impact, 3 of them over featureless ground.
``impact`` (the default, :func:`event_impact_shock`) attributes each impact to the one event
that holds it:

* an *impact* is a crest (a local maximum) of the band-limited |filtered| signal (the same
  sinc interpolation as the peak), placed at its delay-compensated time; it belongs to the
  event whose ``[t_start, t_end)`` holds that time, and to no other;
* a crest is *explained* by a strictly larger crest of another event at a distance ``d`` when
  it is no larger than that crest times :class:`ImpactEnvelope` ``E(d)``: ``E = 1`` within
  ``rate / (2 pass_hz)`` samples (the quadrature twin: a symmetric pulse at frequency f
  leaves as an antisymmetric one whose two crests of equal height lie ``1 / (2 f)`` apart,
  at most ``1 / (2 pass_hz)`` for anything the filter passes at full gain: two crests that
  close are one impact to this filter, whose band starts there), and beyond it the
  normalised envelope of the filter's own band-limited impulse response, measured from its
  crest (what the taps leave of an impulse at that distance; 0 past (N - 1) / 2 + 1
  samples). Had the input been one impulse, every other crest of its response would be
  explained, while a second impact of its own (0.3 as large, 8 samples away) is not, nor is
  the vehicle's own ringing: only the filter's doing is taken away;
* an event's shock is its largest own crest that no other event's crest explains (exactly the
  ``span_peak`` value when that crest is the span's peak: the largest impact around never
  changes, nor do the peaks of Fig. 5); an event with no such crest gets the largest |filtered|
  sample of its span that no other event's crest explains, sample by sample (a flank of one of
  its explained crests may be that), or 0.0 when all of it is explained: it is covered, so it
  is labelled, never rejected (a neighbour's smear is all it felt). Never above the
  ``span_peak`` value.

The rule only applies to ``max_abs``: ``rms`` has no crest to attribute.

Times are int64 ns; accelerations m/s^2; distances in samples of the IMU.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import FloatArray, IntArray
from toolkit.model.shock import (
    INTERP_MARGIN,
    INTERP_UP,
    ShockFir,
    covered_span,
    event_shock,
    upsample,
)


@dataclass(frozen=True)
class ImpactEnvelope:
    """``E(d)``: the largest crest, as a fraction of a crest of the filtered signal, that the
    shock filter's own response to it can leave ``d`` samples away (module docstring,
    "Attribution"). ``quadrature_samples``: ``E = 1`` up to this distance (the quadrature
    twin); ``tail`` (K,): ``E`` beyond it, on distances ``k / INTERP_UP`` samples, k = 0..K-1,
    non-increasing, 0 past the last."""

    quadrature_samples: float
    tail: FloatArray

    @property
    def reach_samples(self) -> float:
        """The distance (samples) beyond which ``E = 0``: nothing is explained from further."""
        return max((self.tail.size - 1) / INTERP_UP, self.quadrature_samples)

    def at(self, d_samples: FloatArray) -> FloatArray:
        """``E`` at the distances ``d_samples`` (any shape, samples), read at the fine step at
        or below each (the envelope is non-increasing: an upper bound)."""
        d = np.abs(np.asarray(d_samples, np.float64))
        k = np.floor(d * INTERP_UP)
        tail = np.where(
            k < self.tail.size,
            self.tail[np.minimum(k, self.tail.size - 1).astype(np.int64)],
            0.0,
        )
        return np.asarray(np.where(d <= self.quadrature_samples, 1.0, tail), np.float64)


def impact_envelope(fir: ShockFir) -> ImpactEnvelope:
    """The :class:`ImpactEnvelope` of a designed filter, from its taps alone.

    Tail: the taps' band-limited interpolation (the peak's own, :data:`INTERP_UP` times, with
    :data:`INTERP_MARGIN` zeros either side) in magnitude, ``m``; its crest at ``c``; ``E(d)`` =
    ``max{m(t) : |t - c| >= d} / m(c)`` for ``d`` up to ``(N - 1) / 2 + 1`` samples, 0 beyond:
    an impulse's response spans (N - 1) / 2 samples either side of the impulse, and its crest
    lies within a sample of it (what the interpolation rings on past the taps is < 1 %). At
    100 Hz with 40 taps: 1 to the twin crest 1.2 samples away, 0.20 at 4 samples, 0.060 at
    8, 0.012 at 19.5, 0 past 20.5. Quadrature: ``rate_hz / (2 pass_hz)`` samples (3.3 at
    100 Hz and a 15 Hz pass edge)."""
    n = fir.taps.size
    padded = np.concatenate([np.zeros(INTERP_MARGIN), fir.taps, np.zeros(INTERP_MARGIN)])
    mag = np.abs(upsample(padded))
    c = int(np.argmax(mag))
    size = int(np.ceil(((n - 1) / 2.0 + 1.0) * INTERP_UP)) + 1
    by_distance = np.zeros(size)
    left = mag[: c + 1][::-1][:size]  # distances 0, 1, ... fine steps before the crest
    right = mag[c:][:size]  # and after it
    by_distance[: left.size] = left
    by_distance[: right.size] = np.maximum(by_distance[: right.size], right)
    tail = np.maximum.accumulate(by_distance[::-1])[::-1] / mag[c]
    return ImpactEnvelope(fir.rate_hz / (2.0 * fir.pass_hz), np.asarray(tail, np.float64))


@dataclass(frozen=True)
class AttributedShock:
    """The shock of one event under the ``impact`` rule (:func:`event_impact_shock`):
    ``shock_mps2`` and its time ``peak_t_ns``, the filtered samples inside the span,
    ``span_peak_mps2`` the ``span_peak`` rule's value (:func:`event_shock`, bit for bit; the
    shock never exceeds it) and ``own_impact``: False when no crest of the event's own was left
    (the shock is then the residual its neighbours' impacts do not explain, or 0.0)."""

    shock_mps2: float
    peak_t_ns: int
    samples: int
    span_peak_mps2: float
    own_impact: bool


def event_impact_shock(
    t_ns: IntArray,
    value: FloatArray,
    run: IntArray,
    t0_ns: int,
    t1_ns: int,
    envelope: ImpactEnvelope,
    max_gap_ns: int,
) -> AttributedShock | None:
    """The ``impact`` rule's shock over ``[t0_ns, t1_ns)`` (module docstring, "Attribution"),
    or None when the samples do not cover the span (as :func:`event_shock`).

    ``t_ns``/``value``/``run`` (M,) are filtered samples sorted by time; the crests that can
    explain the event's own lie within ``envelope.reach_samples`` of the span, so the samples
    should reach that far plus :data:`INTERP_MARGIN` either side (fewer near an IMU run's
    ends). Crests are found on the band-limited interpolation of the same run's samples over
    that window, all at once (no loop over samples): strictly above the fine sample before,
    at least the one after. Explained: a crest no larger than ``a E(d)`` for a strictly larger
    crest ``a`` outside the span, ``d`` its distance in the window's mean sample spacing; a
    matrix of the event's crests (or, without one left, its fine samples) against the
    others', a few dozen each.
    """
    covered = covered_span(t_ns, run, t0_ns, t1_ns, max_gap_ns)
    span = event_shock(t_ns, value, run, t0_ns, t1_ns, "max_abs", max_gap_ns)
    if covered is None or span is None:
        return None
    lo, hi = covered
    reach = int(np.ceil(envelope.reach_samples)) + 1 + INTERP_MARGIN
    a, b = max(lo - reach, 0), min(hi + reach, t_ns.size)
    idx = np.arange(a, b)[run[a:b] == run[lo]]
    tw, vw = t_ns[idx], value[idx]
    if vw.size < 3:  # no crest to tell: the span's peak is all there is
        return AttributedShock(span.shock_mps2, span.peak_t_ns, span.samples, span.shock_mps2, True)
    mag = np.abs(upsample(vw))
    spacing_ns = (tw[-1] - tw[0]) / (vw.size - 1)
    t_fine = tw[0] + np.round(np.arange(mag.size) * (spacing_ns / INTERP_UP)).astype(np.int64)
    crest = np.flatnonzero((mag[1:-1] > mag[:-2]) & (mag[1:-1] >= mag[2:])) + 1
    own = (t_fine[crest] >= t0_ns) & (t_fine[crest] < t1_ns)
    foreign_a, foreign_t = mag[crest[~own]], t_fine[crest[~own]]

    def crest_shock(j: int, own_impact: bool) -> AttributedShock:
        """The shock of fine sample ``j``, never above the span's peak."""
        return AttributedShock(
            min(float(mag[j]), span.shock_mps2),
            int(t_fine[j]),
            span.samples,
            span.shock_mps2,
            own_impact,
        )

    def unexplained(i: IntArray) -> NDArray[np.bool_]:
        """Which of the fine samples ``i`` no strictly larger crest of another event explains."""
        if foreign_a.size == 0 or i.size == 0:
            return np.ones(i.size, dtype=bool)
        d = np.abs(t_fine[i][:, None] - foreign_t[None, :]) / spacing_ns
        larger = foreign_a[None, :] > mag[i][:, None]
        bound = np.where(larger, foreign_a[None, :] * envelope.at(d), 0.0)
        return np.asarray(mag[i] > bound.max(axis=1))

    in_span = np.flatnonzero((t_fine >= t0_ns) & (t_fine < t1_ns))
    kept = crest[own][unexplained(crest[own])]
    if kept.size:
        if in_span.size and in_span[np.argmax(mag[in_span])] in kept:
            # The span's peak is an impact of its own: the span_peak value, bit for bit.
            return AttributedShock(
                span.shock_mps2, span.peak_t_ns, span.samples, span.shock_mps2, True
            )
        return crest_shock(int(kept[np.argmax(mag[kept])]), True)
    rest = in_span[unexplained(in_span)]
    if rest.size:
        return crest_shock(int(rest[np.argmax(mag[rest])]), False)
    return AttributedShock(0.0, (t0_ns + t1_ns) // 2, span.samples, span.shock_mps2, False)


__all__ = ["AttributedShock", "ImpactEnvelope", "event_impact_shock", "impact_envelope"]
