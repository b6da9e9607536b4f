"""The ``race`` profile's rough events, labelled by the reference labeller (paper, Sect. 5
and 7): about 0.3-0.6 % of 1.4 m events reach 0.02 G/mph, and event shocks span about
0.02 G to 0.6 G."""

from __future__ import annotations

import numpy as np
import pytest

from toolkit.sim.profiles import make_profile

from .logdata import SimLog, label_log
from .reference_labeller import Events


@pytest.fixture(scope="module")
def events(race_log: SimLog) -> Events:
    ev = label_log(race_log, make_profile("race").sensors.imu.rate_hz)
    pos = ev.positive
    p1, p50, p99 = np.percentile(ev.shock_g, [1, 50, 99])
    print(
        f"\nrace: {len(ev)} events, {pos.sum()} positive ({pos.mean():.3%}); shock G: "
        f"p1 {p1:.4f}, median {p50:.4f}, p99 {p99:.4f}, max {ev.shock_g.max():.4f}; "
        f"speed {ev.speed_mph.min():.1f}-{ev.speed_mph.max():.1f} mph; top ruggedness "
        f"{np.round(np.sort(ev.ruggedness)[-12:], 4).tolist()}"
    )
    return ev


def test_race_has_enough_events(events: Events, race_log: SimLog) -> None:
    travelled = float(race_log.truth.path_length[-1])
    assert len(events) == pytest.approx(travelled / 1.4, abs=3)
    assert len(events) > 2000


def test_race_positive_fraction(events: Events) -> None:
    """About 0.3-0.6 % of events reach 0.02 G/mph (the paper: 0.36 % and 0.44 %)."""
    fraction = float(events.positive.mean())
    assert 0.003 <= fraction <= 0.006, (
        f"{events.positive.sum()} of {len(events)} events positive ({fraction:.3%})"
    )


def test_race_shock_span(events: Events) -> None:
    """Event shocks span about 0.02 G (negligible) to 0.6 G (severe)."""
    p1 = float(np.percentile(events.shock_g, 1))
    top = float(events.shock_g.max())
    assert p1 <= 0.03
    assert 0.3 <= top <= 1.0
