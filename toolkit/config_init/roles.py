"""Step 2 of ``config init``: topics matched to the roles of ``[topics]``, by type then name.

Part of :mod:`toolkit.config_init`, whose docstring tells the steps.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from toolkit.config_init.summary import LogSummary, TopicSummary
from toolkit.ingestion.roles import ROLE_SPECS
from toolkit.mcapio.pointcloud2 import packets_note

# --------------------------------------------------------------------------------------
# 2. Topics to roles
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class NameHint:
    """A word in a topic's name (lower case) and what it says about the topic."""

    word: str
    score: int
    why: str


#: Words that make a topic a better (or worse) candidate among several of one type.
PREFER: dict[str, tuple[NameHint, ...]] = {
    "imu": (
        NameHint("raw", -2, "'raw': uncalibrated, usually without orientation"),
        NameHint("data", 1, "'data': the calibrated IMU output"),
    ),
    "gps": (
        NameHint("fix", 1, "'fix': the receiver's fix"),
        NameHint("gps", 1, "'gps'"),
        NameHint("gnss", 1, "'gnss'"),
    ),
    "heading": (NameHint("heading", 1, "'heading'"), NameHint("compass", 1, "'compass'")),
    "wheels": (
        NameHint("wheel", 2, "'wheel': wheel encoders"),
        NameHint("velocity_controller", 2, "a drive controller's wheel odometry"),
        NameHint("diff_drive", 2, "a drive controller's wheel odometry"),
        NameHint("odom", 1, "'odom'"),
    ),
}
#: Words that rule a topic out of a role whatever its type: not a measurement of it.
EXCLUDE: dict[str, tuple[NameHint, ...]] = {
    "gps": (NameHint("filtered", 0, "a fusion's output (navsat_transform), not the receiver"),),
    "wheels": (
        NameHint("filtered", 0, "a fusion's output (robot_localization), not a sensor"),
        NameHint("ekf", 0, "a fusion's output, not a sensor"),
        NameHint("ukf", 0, "a fusion's output, not a sensor"),
        NameHint("fused", 0, "a fusion's output, not a sensor"),
        NameHint("odometry/gps", 0, "the GPS as odometry (navsat_transform), not the wheels"),
        NameHint("cmd", 0, "a velocity command, not a measurement"),
        NameHint("truth", 0, "ground truth (the truth_pose role)"),
    ),
}
#: Words a topic's name must hold for a role (a type too general to mean the role alone).
REQUIRE: dict[str, tuple[str, ...]] = {
    "tf_static": ("tf_static",),
    "truth_pose": ("truth",),
}
#: Types accepted only when the name also says the role (a QuaternionStamped may be anything).
REQUIRE_FOR_TYPE: dict[tuple[str, str], tuple[str, ...]] = {
    ("heading", "geometry_msgs/msg/QuaternionStamped"): ("heading", "compass", "yaw"),
}
#: Preferred types among the accepted ones, best first (a role's others come after).
TYPE_ORDER: dict[str, tuple[str, ...]] = {
    # the mean of the rear wheels is exactly base_link's speed; a twist is a controller's
    "wheels": ("terrain_msgs/msg/WheelSpeeds", "nav_msgs/msg/Odometry"),
}
#: What each role is, for the comments ("no GPS compass found"): the roles' own words.
ROLE_WORDS: dict[str, str] = {role: spec.word for role, spec in ROLE_SPECS.items()}


@dataclass(frozen=True)
class RoleGuess:
    """The topics chosen for a role (none, one, or for lasers and lidars several), why, and
    the other topics of an accepted type with the reason each was not chosen; ``notices``,
    what must be said on the terminal (a topic of the role's type passed over for what the
    log holds, not for its name: no messages)."""

    role: str
    topics: tuple[str, ...]
    why: str
    others: tuple[tuple[str, str], ...] = ()
    notices: tuple[str, ...] = ()


def topic_label(topic: str) -> str:
    """A topic's name as the comments show it (``""`` for the empty name)."""
    return topic if topic else '""'


def describe_topic(t: TopicSummary) -> str:
    """The topic's type, rate (its count under two messages) and frame, for the comments."""
    rate = f" at {t.rate_hz:.1f} Hz" if t.rate_hz is not None else f", {t.count} message(s)"
    frame = f", frame {t.frame_id}" if t.frame_id else ""
    return f"{t.type_name}{rate}{frame}"


def _excluded(role: str, t: TopicSummary) -> str:
    """Why ``t`` cannot play ``role`` although its type is accepted ("" when it can)."""
    if t.layout is not None:
        unreadable = ROLE_SPECS[role].schema_problem(t.layout)
        if unreadable:
            return f"its schema {t.layout.difference}: {unreadable}"
    name = t.topic.lower()
    for hint in EXCLUDE.get(role, ()):
        if hint.word in name:
            return hint.why
    needed = REQUIRE.get(role, ()) + REQUIRE_FOR_TYPE.get((role, t.type_name), ())
    if needed and not any(w in name for w in needed):
        return f"its name has none of {', '.join(repr(w) for w in needed)}"
    return ""


def _unusable(t: TopicSummary) -> str:
    """Why ``t`` can play no role whatever its name and type say ("" when it can): the log
    holds nothing of it, or nothing a configuration can name. A topic with no messages would
    make an empty table (and a stage verdict that lies), so it never wins over one with
    messages; a topic named "" would be written as an absent role."""
    if not t.topic:
        return 'its name is empty, and a configuration cannot name it ("" is no topic)'
    if t.count == 0:
        return "it has no messages in the log"
    return ""


def _rank(role: str, t: TopicSummary) -> tuple[bool, int, int, float, str]:
    """Sort key, best first: a rate known (two messages or more) before none, then name
    score, type preference, rate, and the name itself."""
    name = t.topic.lower()
    score = sum(h.score for h in PREFER.get(role, ()) if h.word in name)
    order = TYPE_ORDER.get(role, ())
    type_rank = order.index(t.type_name) if t.type_name in order else len(order)
    return (t.rate_hz is None, -score, type_rank, -(t.rate_hz or 0.0), t.topic)


def _notices(
    role: str, passed: Sequence[tuple[TopicSummary, str]], chosen: Sequence[str]
) -> tuple[str, ...]:
    """The terminal's lines for the topics of ``role``'s type passed over for what the log
    holds, each with what was chosen instead."""
    instead = (
        f"{', '.join(repr(c) for c in chosen)} chosen"
        if chosen
        else f"no {ROLE_WORDS[role]} topic left"
    )
    return tuple(
        f"[topics] {role}: {t.topic!r} ({t.type_name}) not used, {why}; {instead}"
        for t, why in passed
    )


def _name_reasons(role: str, t: TopicSummary) -> list[str]:
    name = t.topic.lower()
    return [h.why for h in PREFER.get(role, ()) if h.word in name]


def guess_role(role: str, topics: Sequence[TopicSummary]) -> RoleGuess:
    """The topics of ``topics`` that play ``role``, with why (see the module docstring)."""
    accepted = ROLE_SPECS[role].converters
    typed = [t for t in topics if t.type_name in accepted]
    others: list[tuple[str, str]] = []
    passed: list[tuple[TopicSummary, str]] = []
    usable = []
    for t in typed:
        why_not = _excluded(role, t)
        if not why_not:
            why_not = _unusable(t)
            if why_not:
                passed.append((t, why_not))
        if why_not:
            others.append((t.topic, f"{describe_topic(t)}: not used, {why_not}"))
        else:
            usable.append(t)
    if not usable:
        types = " or ".join(ROLE_SPECS[role].accepted_types)
        why = f"no {ROLE_WORDS[role]} found: no usable topic of type {types}"
        if role == "lidars":  # a log of packets has a lidar the toolkit cannot read yet
            notes = [packets_note(t.topic, t.type_name) for t in topics]
            why = "; ".join([why, *(n for n in notes if n)])
        return RoleGuess(role, (), why, tuple(others), _notices(role, passed, ()))
    if ROLE_SPECS[role].multi:  # every laser (lidar) scans terrain: all of them
        chosen = sorted(usable, key=lambda t: t.topic)
        types = " or ".join(ROLE_SPECS[role].accepted_types)
        names = tuple(t.topic for t in chosen)
        return RoleGuess(
            role,
            names,
            f"every {types} topic ({len(chosen)})",
            tuple(others),
            _notices(role, passed, names),
        )
    ranked = sorted(usable, key=lambda t: _rank(role, t))
    best = ranked[0]
    if len(ranked) == 1:
        how = f"the only {'usable ' if others else ''}topic of an accepted type"
    else:
        reasons = _name_reasons(role, best)
        how = "chosen among several by " + (
            f"name ({'; '.join(reasons)})" if reasons else "type and rate"
        )
    for t in ranked[1:]:
        reasons = _name_reasons(role, t)
        extra = f" ({'; '.join(reasons)})" if reasons else ""
        others.insert(0, (t.topic, f"{describe_topic(t)}: an alternative{extra}"))
    return RoleGuess(
        role,
        (best.topic,),
        f"{describe_topic(best)}: {how}",
        tuple(others),
        _notices(role, passed, (best.topic,)),
    )


def guess_roles(summary: LogSummary) -> dict[str, RoleGuess]:
    """A guess for every role of ``[topics]``; a topic plays at most one role (the first
    role in :data:`~toolkit.ingestion.roles.ROLE_SPECS` order that chose it)."""
    taken: set[str] = set()
    guesses: dict[str, RoleGuess] = {}
    for role in ROLE_SPECS:
        free = [t for t in summary.topics if t.topic not in taken]
        guess = guess_role(role, free)
        taken.update(guess.topics)
        guesses[role] = guess
    return guesses
