"""The ``impact`` attribution of the shock filter's output (issue 26): the filter's own impulse
envelope, and the shock of an event that holds an impact's crest, its twin or its flank."""

from __future__ import annotations

import numpy as np
import pytest

from toolkit.model.shock import (
    INTERP_UP,
    design_shock_fir,
    event_shock,
    filter_stream,
    upsample,
)
from toolkit.model.shock_attribution import event_impact_shock, impact_envelope

PERIOD_NS = 10_000_000  # 100 Hz


def fine_crests(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions in samples, heights) of the crests of the band-limited |y|."""
    m = np.abs(upsample(y))
    c = np.flatnonzero((m[1:-1] > m[:-2]) & (m[1:-1] >= m[2:])) + 1
    return c / INTERP_UP, m[c]


def test_impact_envelope_explains_the_filters_own_response() -> None:
    """E(d) is 1 up to the quadrature twin (rate / (2 pass_hz) = 3.3 samples), then falls
    with the taps' ringing (0.2 at 4 samples, 0.06 at 8) to 0 past (N - 1) / 2 + 1 samples;
    every crest of the filter's response to an impulse but the largest lies under the largest
    times E at its distance, while a second impulse 0.3 as large 8 samples away does not."""
    fir = design_shock_fir(100.0)
    env = impact_envelope(fir)
    assert env.quadrature_samples == pytest.approx(100.0 / 30.0)
    assert env.reach_samples == 20.5
    d = np.linspace(0.0, 25.0, 401)
    e = env.at(d)
    assert np.all(np.diff(e) <= 0) and np.all(e[d <= 3.33] == 1.0) and np.all(e[d > 20.5] == 0)
    assert env.at(np.array([4.0]))[0] == pytest.approx(0.20, abs=0.01)
    assert env.at(np.array([8.0]))[0] == pytest.approx(0.06, abs=0.005)
    x = np.zeros(200)
    x[100] = 1.0
    pos, height = fine_crests(np.convolve(x, fir.taps, mode="valid"))
    top = int(np.argmax(height))
    near = np.abs(pos - pos[top]) <= env.reach_samples
    others = near & (np.arange(pos.size) != top)
    bound = height[top] * env.at(pos[others] - pos[top])
    assert others.sum() > 10 and np.all(height[others] <= bound * (1 + 1e-9))
    assert np.all(height[~near] < 0.01 * height[top])  # the interpolation's ringing past them
    x[108] = 0.3  # a second impact of its own
    pos, height = fine_crests(np.convolve(x, fir.taps, mode="valid"))
    top = int(np.argmax(height))
    second = int(np.argmax(np.where(np.abs(pos - pos[top]) > 4, height, 0.0)))
    assert height[second] > height[top] * env.at(np.array([pos[second] - pos[top]]))[0]


def test_impact_shock_of_a_crest_a_twin_and_a_flank() -> None:
    """One impact: a 25 Hz ring starting at 1.0 s, its largest crest 19 ms later and its
    quadrature twin 16 ms before that. A span holding the largest crest gets the span peak bit
    for bit. A span ending 7 ms before it holds the twin (span_peak: 0.77 of the peak) and the
    lead-in's crests, all explained by the largest: no impact of its own, the largest
    |filtered| left unexplained instead (a lead-in's flank, 0.12 of the peak). A span one
    sample wide just after the crest holds no crest, and the crest explains all of it: 0.0,
    not None. Spans the samples do not cover are None, as under span_peak."""
    fir = design_shock_fir(100.0)
    env = impact_envelope(fir)
    t = np.arange(300, dtype=np.int64) * PERIOD_NS
    u = (t - 1_000_000_000) * 1e-9
    x = 9.8 + np.where(u >= 0, 9.8 * np.exp(-u / 0.03) * np.sin(2 * np.pi * 25 * u), 0.0)
    (out,) = filter_stream([(t, x)], fir.taps, 15_000_000)
    gap = 15_000_000
    whole = event_shock(out.t_ns, out.value, out.run, 800_000_000, 1_300_000_000, "max_abs", gap)
    assert whole is not None
    crest_ns = whole.peak_t_ns
    holding = event_impact_shock(
        out.t_ns, out.value, out.run, crest_ns - 70_000_000, crest_ns + 70_000_000, env, gap
    )
    assert holding is not None and holding.own_impact
    assert holding.shock_mps2 == holding.span_peak_mps2 == whole.shock_mps2
    assert holding.peak_t_ns == crest_ns
    flank = event_impact_shock(
        out.t_ns, out.value, out.run, crest_ns - 147_000_000, crest_ns - 7_000_000, env, gap
    )
    assert flank is not None and not flank.own_impact
    assert flank.span_peak_mps2 > 0.7 * whole.shock_mps2  # span_peak: the twin
    assert 0.0 < flank.shock_mps2 < 0.2 * whole.shock_mps2
    assert crest_ns - 147_000_000 <= flank.peak_t_ns < crest_ns - 7_000_000
    narrow = event_impact_shock(
        out.t_ns, out.value, out.run, crest_ns + 2_000_000, crest_ns + 12_000_000, env, gap
    )
    assert narrow is not None and not narrow.own_impact
    assert narrow.span_peak_mps2 > 0.1 * whole.shock_mps2
    assert narrow.shock_mps2 == 0.0
    assert event_impact_shock(out.t_ns, out.value, out.run, -(10**9), 10**8, env, gap) is None
