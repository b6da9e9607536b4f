"""The ruggedness label (sect. 5.2, sect. 7) and the attribution's summary of it."""

from __future__ import annotations

import numpy as np

from toolkit.model.ruggedness import attribution_summary

G = 9.80665


def test_attribution_applies_to_the_peak_only() -> None:
    """rms has no crest: nothing is attributed or counted; under impact the counts compare
    the two rules' ruggedness at the threshold."""
    shock = np.array([5.0, 1.0, 0.0])
    span = np.array([5.0, 4.5, 0.3])
    own = np.array([True, True, False])
    speed = np.full(3, 22.4)
    args = (shock, span, own, speed, G, 0.02)
    assert attribution_summary("impact", "rms", *args) == {"rule": "impact", "applied": False}
    assert attribution_summary("span_peak", "max_abs", *args) == {
        "rule": "span_peak",
        "applied": False,
    }
    got = attribution_summary("impact", "max_abs", *args, np.array([False, True, True]))
    assert got == {
        "rule": "impact",
        "applied": True,
        "events_reduced": 2,
        "events_without_own_impact": 1,
        "rough_span_peak": 2,
        "rough": 1,
        "rough_lost": 1,
        "rough_lost_featureless": 1,
    }
