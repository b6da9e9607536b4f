"""The ruggedness label of the paper's Sect. 5.2 and Sect. 7.

Sect. 5.2: "the faster we drive over rugged terrain, the stronger the perceived
z-acceleration"; over a static obstacle the shock grows about linearly with speed (Fig. 5),
so the *ruggedness coefficient* is the quotient

    ruggedness = shock_g / speed_mph                                   [G/mph]

of an event's shock (:mod:`toolkit.model.shock`, in G: m/s^2 over ``label.gravity_mps2``)
and its mean speed (:func:`event_speed_mps`: the event's length over its duration, the time
mean of the path speed; 1 mph = 0.44704 m/s exactly). Sect. 7 detects "shocks of .02 Gs per
mph or more": an event is ``rough`` when its ruggedness reaches
``label.rough_threshold_g_per_mph`` (:func:`is_rough`).

Events slower than ``label.min_speed_mps`` are left out before anything is divided by their
speed (:func:`fast_enough`): a stop lies inside one long slow event, so it makes none.

:func:`attribution_summary` counts what the ``impact`` attribution of the shock
(:mod:`toolkit.model.shock_attribution`) changed of these labels.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from toolkit.arrays import BoolArray, FloatArray, IntArray
from toolkit.model.shock import MPS_PER_MPH


def event_speed_mps(bounds_ns: IntArray, length_m: float) -> FloatArray:
    """Each event's mean speed (E,) m/s from its boundaries' times (E + 1,) ns: its length
    over its duration. Every event has a positive duration (s rises through each boundary);
    a zero one (two boundaries inside one nanosecond) is treated as infinitely slow (0.0)
    rather than divided by."""
    duration_s = np.diff(bounds_ns) * 1e-9
    return np.asarray(
        np.where(duration_s > 0, length_m / np.where(duration_s > 0, duration_s, 1.0), 0.0),
        np.float64,
    )


def fast_enough(speed_mps: FloatArray, min_speed_mps: float) -> BoolArray:
    """The events (E,) driven at ``min_speed_mps`` or faster (any speed above 0 when it is
    0): the only ones whose shock is divided by their speed."""
    if min_speed_mps > 0:
        return np.asarray(speed_mps >= min_speed_mps)
    return np.asarray(speed_mps > 0)


def ruggedness(shock_g: FloatArray, speed_mph: FloatArray) -> FloatArray:
    """Sect. 5.2's ruggedness coefficient ``shock_g / speed_mph`` (E,), G/mph."""
    return np.asarray(shock_g / speed_mph, np.float64)


def is_rough(ruggedness_g_per_mph: FloatArray, threshold_g_per_mph: float) -> BoolArray:
    """Sect. 7's label (E,): ruggedness at or above the threshold (0.02 G/mph)."""
    return np.asarray(ruggedness_g_per_mph >= threshold_g_per_mph)


@dataclass(frozen=True)
class EventLabels:
    """The labels of the covered events (E,): mean speed (mph), shock (G), ruggedness
    (G/mph) and whether it is rough."""

    speed_mph: FloatArray
    shock_g: FloatArray
    ruggedness: FloatArray
    rough: BoolArray


def label_events(
    shock_mps2: FloatArray, speed_mps: FloatArray, gravity_mps2: float, threshold_g_per_mph: float
) -> EventLabels:
    """The labels of events (E,) from their shock (m/s^2) and mean speed (m/s)."""
    speed_mph = speed_mps / MPS_PER_MPH
    shock_g = shock_mps2 / gravity_mps2
    coefficient = ruggedness(shock_g, speed_mph)
    return EventLabels(speed_mph, shock_g, coefficient, is_rough(coefficient, threshold_g_per_mph))


def attribution_summary(
    rule: str,
    statistic: str,
    shock_mps2: FloatArray,
    span_peak_mps2: FloatArray,
    own_impact: NDArray[np.bool_],
    speed_mph: FloatArray,
    gravity_mps2: float,
    threshold_g_per_mph: float,
    featureless: NDArray[np.bool_] | None = None,
) -> dict[str, Any]:
    """What the attribution changed over the labelled events (E,), for the manifest.

    ``rule`` the configured ``label.attribution``; ``applied`` False (and nothing counted)
    under ``span_peak`` or the ``rms`` statistic. Under ``impact``: ``events_reduced`` (the
    shock below the span peak), ``events_without_own_impact`` (no crest of their own left),
    ``rough_span_peak`` (the positives ``span_peak`` gives: its ruggedness computed as the
    stage computes it, so the same count bit for bit), ``rough`` and ``rough_lost`` (the
    attribution only lowers shocks: no event becomes rough) and, with the truth
    (``featureless``: no true feature under a tyre), ``rough_lost_featureless``."""
    applied = rule == "impact" and statistic == "max_abs"
    out: dict[str, Any] = {"rule": rule, "applied": applied}
    if not applied:
        return out
    rough = is_rough(ruggedness(shock_mps2 / gravity_mps2, speed_mph), threshold_g_per_mph)
    rough_before = is_rough(
        ruggedness(span_peak_mps2 / gravity_mps2, speed_mph), threshold_g_per_mph
    )
    lost = rough_before & ~rough
    out.update(
        events_reduced=int((shock_mps2 < span_peak_mps2).sum()),
        events_without_own_impact=int((~own_impact).sum()),
        rough_span_peak=int(rough_before.sum()),
        rough=int(rough.sum()),
        rough_lost=int(lost.sum()),
    )
    if featureless is not None:
        out["rough_lost_featureless"] = int((lost & featureless).sum())
    return out


__all__ = [
    "EventLabels",
    "attribution_summary",
    "event_speed_mps",
    "fast_enough",
    "is_rough",
    "label_events",
    "ruggedness",
]
