"""``terrain config init``: a starting configuration written from a log itself.

Three pure steps and one that reads the log:

1. :func:`summarize_log` reads what the log says about its sensors: every topic's message
   type, count and rate (through :func:`~toolkit.mcapio.info.scan_log`, as ``terrain info``),
   the ``header.frame_id`` of each sensor topic's first messages, the IMU's mean acceleration
   over them (where gravity points in the IMU's frame), and the static transforms of
   ``/tf_static`` when the log has them.
2. :func:`guess_roles` matches topics to the roles of ``[topics]``: by message type first
   (the types :data:`~toolkit.stages.roles.ROLE_SPECS` accepts), then, when several topics
   share a type, by name (``/imu/data`` over ``/imu/data_raw``; a wheel controller's odometry,
   never ``/odometry/filtered``, which is a fusion's output and not a sensor). Each guess
   keeps why it was made and the alternatives; a role nothing matches says so.
3. :func:`render_config` writes the TOML text: the built-in default's text (every key, every
   comment) with the values the log decides replaced, each replaced value preceded by
   comments saying why, and a head saying which stages the log can feed. The result is
   loaded back with :func:`~toolkit.config.parse_config` before it is returned
   (:func:`init_config`), so what ``config init`` prints always loads.

Nothing here writes TOML through a library: the core depends on none that writes, and
a generated file should read like the hand-written ones (comments where the values are).
"""

from __future__ import annotations

import importlib.resources
import logging
import math
import re
import textwrap
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from toolkit.config import (
    DEFAULT_CONFIG_RESOURCE,
    ROLES,
    PipelineConfig,
    default_config,
    parse_config,
    toml_value,
)
from toolkit.errors import ConfigError, ToolkitError
from toolkit.mcapio.info import LogInfo, scan_log
from toolkit.mcapio.msgdefs import full_type_name
from toolkit.mcapio.reader import LogReader
from toolkit.model.shock import MIN_PASSBAND_HZ, design_shock_fir
from toolkit.mounts import Mount, StaticTransform, chain_to_base
from toolkit.stages.roles import ROLE_SPECS

_log = logging.getLogger(__name__)

#: Sensor roles whose messages carry the frame their mount is looked up by.
FRAMED_ROLES: tuple[str, ...] = ("lasers", "imu", "gps")
#: Largest mount offset the configuration accepts (``[vehicle] *_position_m``), m.
MAX_MOUNT_M = 100.0
#: An IMU tilted less than this (deg) at the start is taken as level (the robot on a slope).
LEVEL_DEG = 20.0

IMU_TYPE = "sensor_msgs/msg/Imu"
TF_TYPE = "tf2_msgs/msg/TFMessage"


# --------------------------------------------------------------------------------------
# 1. What the log says
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TopicSummary:
    """One topic: its full type name (or the schema name as given when it is not a ROS type
    name), count and mean rate (Hz, None under two messages); for sensor topics the frame of
    their first message ("" when not read) and for an IMU its mean acceleration (m/s^2, in
    its own frame) over the first messages."""

    topic: str
    type_name: str
    count: int
    rate_hz: float | None
    frame_id: str = ""
    accel_mean: tuple[float, float, float] | None = None
    problem: str = ""


@dataclass(frozen=True)
class LogSummary:
    """What :func:`summarize_log` read: the log, its duration, its topics, and the static
    transforms of its tf_static topic (``tf_static_topic`` "" when it has none)."""

    path: Path
    duration_s: float
    topics: tuple[TopicSummary, ...]
    tf_static_topic: str = ""
    transforms: tuple[StaticTransform, ...] = ()
    problems: int = 0

    def topic(self, name: str) -> TopicSummary:
        """The summary of one topic (KeyError when the log has no such topic)."""
        return next(t for t in self.topics if t.topic == name)


def _type_name(schema_name: str) -> str:
    try:
        return full_type_name(schema_name)
    except ToolkitError:  # not a ROS type name: kept as is, it matches no role
        return schema_name


def _accepted_by_any(type_name: str) -> bool:
    return any(type_name in spec.converters for spec in ROLE_SPECS.values())


def summarize_log(path: str | Path) -> LogSummary:
    """Read what :func:`guess_roles` and :func:`render_config` need from a log.

    Reads the summary (or index) for the topics, then only the first batch of every topic a
    role accepts and every message of a ``tf_static`` topic. Raises
    :class:`~toolkit.errors.LogReadError` for a file that is missing or not MCAP.
    """
    path = Path(path)
    info: LogInfo = scan_log(path)
    types = {t.topic: _type_name(t.message_type) for t in info.topics}
    # A topic with no message has no first batch: asking for it would read the whole log.
    counts = {t.topic: t.message_count for t in info.topics}
    wanted = {topic for topic, tp in types.items() if _accepted_by_any(tp) and counts[topic] != 0}
    tf_topic = _tf_static_topic(types)
    tf_count = next((t.message_count for t in info.topics if t.topic == tf_topic), 0)
    first: dict[str, dict[str, np.ndarray]] = {}
    problems: dict[str, str] = {}
    tf_messages: list[dict[str, np.ndarray]] = []
    if wanted:
        _read_first_batches(path, wanted, tf_topic, tf_count, first, problems, tf_messages)
    topics = []
    for t in info.topics:
        cols = first.get(t.topic, {})
        topics.append(
            TopicSummary(
                topic=t.topic,
                type_name=types[t.topic],
                count=t.message_count,
                rate_hz=t.mean_rate_hz,
                frame_id=_first_frame(cols),
                accel_mean=_accel_mean(cols) if types[t.topic] == IMU_TYPE else None,
                problem=problems.get(t.topic, ""),
            )
        )
    return LogSummary(
        path=path,
        duration_s=info.duration_s,
        topics=tuple(topics),
        tf_static_topic=tf_topic,
        transforms=tuple(_transforms(tf_messages)),
        problems=len(info.problems),
    )


def _tf_static_topic(types: Mapping[str, str]) -> str:
    """The static-transform topic: a TFMessage topic named for it (``/tf`` is dynamic)."""
    found = sorted(t for t, tp in types.items() if tp == TF_TYPE and "tf_static" in t.lower())
    return found[0] if found else ""


def _read_first_batches(
    path: Path,
    wanted: set[str],
    tf_topic: str,
    tf_count: int,
    first: dict[str, dict[str, np.ndarray]],
    problems: dict[str, str],
    tf_messages: list[dict[str, np.ndarray]],
) -> None:
    """Decode the first batch of each wanted topic and every tf_static message, stopping as
    soon as that is done (the start of the log, for a log of any length)."""
    from toolkit.stages.ingest import channel_decoder

    seen: set[str] = set()
    tf_seen = 0
    with LogReader(path, topics=wanted) as reader:
        for batch in reader.batches():
            topic = batch.channel.topic
            if topic == tf_topic or topic not in seen:
                try:
                    cols = channel_decoder(topic, batch.channel)(batch.payloads)
                except ToolkitError as exc:  # a sensor whose messages do not decode
                    problems.setdefault(topic, str(exc))
                    cols = {}
                if topic == tf_topic:
                    tf_seen += len(batch.payloads)
                    if cols:
                        tf_messages.append(cols)
                elif cols:
                    first[topic] = cols
                seen.add(topic)
            if seen >= wanted and tf_seen >= tf_count:
                break


def _first_frame(cols: Mapping[str, np.ndarray]) -> str:
    frames = cols.get("header.frame_id")
    if frames is None or len(frames) == 0:
        return ""
    return str(frames[0]).strip().lstrip("/")  # ROS 1 frames may start with "/"


def _accel_mean(cols: Mapping[str, np.ndarray]) -> tuple[float, float, float] | None:
    try:
        mean = [float(np.nanmean(np.asarray(cols[f"linear_acceleration.{a}"]))) for a in "xyz"]
    except KeyError:
        return None
    return (mean[0], mean[1], mean[2]) if all(math.isfinite(m) for m in mean) else None


def _transforms(messages: Iterable[Mapping[str, np.ndarray]]) -> list[StaticTransform]:
    """The static transforms of decoded TFMessage batches (unusable ones left out)."""
    from scipy.spatial.transform import Rotation

    out: list[StaticTransform] = []
    for cols in messages:
        for per_msg in cols.get("transforms", []):
            parents = np.asarray(per_msg.get("header.frame_id", []), dtype=str)
            children = np.asarray(per_msg.get("child_frame_id", []), dtype=str)
            t = np.stack(
                [np.asarray(per_msg[f"transform.translation.{a}"], np.float64) for a in "xyz"],
                axis=-1,
            ).reshape(-1, 3)
            q = np.stack(
                [np.asarray(per_msg[f"transform.rotation.{a}"], np.float64) for a in "xyzw"],
                axis=-1,
            ).reshape(-1, 4)
            for k in range(len(children)):
                if not (np.isfinite(t[k]).all() and np.isfinite(q[k]).all()):
                    continue
                if np.linalg.norm(q[k]) < 1e-9:
                    continue
                out.append(
                    StaticTransform(
                        str(parents[k]).lstrip("/"),
                        str(children[k]).lstrip("/"),
                        t[k],
                        Rotation.from_quat(q[k]).as_matrix(),
                    )
                )
    return out


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
#: What each role is, for the comments ("no GPS compass found").
ROLE_WORDS: dict[str, str] = {
    "lasers": "laser",
    "imu": "IMU",
    "gps": "GPS",
    "heading": "GPS compass",
    "wheels": "wheel speed",
    "tf_static": "static transform topic",
    "truth_pose": "true pose (simulated logs only)",
    "truth_features": "true terrain features (simulated logs only)",
}


@dataclass(frozen=True)
class RoleGuess:
    """The topics chosen for a role (none, one, or for lasers several), why, and the other
    topics of an accepted type with the reason each was not chosen."""

    role: str
    topics: tuple[str, ...]
    why: str
    others: tuple[tuple[str, str], ...] = ()


def _describe(t: TopicSummary) -> str:
    rate = f"{t.rate_hz:.1f} Hz" if t.rate_hz is not None else f"{t.count} message(s)"
    frame = f", frame {t.frame_id}" if t.frame_id else ""
    return f"{t.type_name} at {rate}{frame}"


def _excluded(role: str, t: TopicSummary) -> str:
    """Why ``t`` cannot play ``role`` although its type is accepted ("" when it can)."""
    name = t.topic.lower()
    for hint in EXCLUDE.get(role, ()):
        if hint.word in name:
            return hint.why
    needed = REQUIRE.get(role, ()) + REQUIRE_FOR_TYPE.get((role, t.type_name), ())
    if needed and not any(w in name for w in needed):
        return f"its name has none of {', '.join(repr(w) for w in needed)}"
    return ""


def _rank(role: str, t: TopicSummary) -> tuple[int, int, float, str]:
    """Sort key, best first: name score, type preference, rate, then the name itself."""
    name = t.topic.lower()
    score = sum(h.score for h in PREFER.get(role, ()) if h.word in name)
    order = TYPE_ORDER.get(role, ())
    type_rank = order.index(t.type_name) if t.type_name in order else len(order)
    return (-score, type_rank, -(t.rate_hz or 0.0), t.topic)


def _name_reasons(role: str, t: TopicSummary) -> list[str]:
    name = t.topic.lower()
    return [h.why for h in PREFER.get(role, ()) if h.word in name]


def guess_role(role: str, topics: Sequence[TopicSummary]) -> RoleGuess:
    """The topics of ``topics`` that play ``role``, with why (see the module docstring)."""
    accepted = ROLE_SPECS[role].converters
    typed = [t for t in topics if t.type_name in accepted]
    others: list[tuple[str, str]] = []
    usable = []
    for t in typed:
        why_not = _excluded(role, t)
        if why_not:
            others.append((t.topic, f"{_describe(t)}: not used, {why_not}"))
        else:
            usable.append(t)
    if not usable:
        types = " or ".join(ROLE_SPECS[role].accepted_types)
        return RoleGuess(
            role, (), f"no {ROLE_WORDS[role]} found: no usable topic of type {types}", tuple(others)
        )
    if role == "lasers":  # every laser scans terrain: all of them
        chosen = sorted(usable, key=lambda t: t.topic)
        return RoleGuess(
            role,
            tuple(t.topic for t in chosen),
            f"every sensor_msgs/msg/LaserScan topic ({len(chosen)})",
            tuple(others),
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
        others.insert(0, (t.topic, f"{_describe(t)}: an alternative{extra}"))
    return RoleGuess(role, (best.topic,), f"{_describe(best)}: {how}", tuple(others))


def guess_roles(summary: LogSummary) -> dict[str, RoleGuess]:
    """A guess for every role of ``[topics]``; a topic plays at most one role (the first
    role in :data:`ROLES` order that chose it)."""
    taken: set[str] = set()
    guesses: dict[str, RoleGuess] = {}
    for role in ROLES:
        free = [t for t in summary.topics if t.topic not in taken]
        guess = guess_role(role, free)
        taken.update(guess.topics)
        guesses[role] = guess
    return guesses


# --------------------------------------------------------------------------------------
# 3. The TOML text
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Setting:
    """What to write for one key of the default: ``value`` as TOML text (None keeps the
    default's line) and the comment lines to put above it (without ``#``)."""

    value: str | None
    comments: tuple[str, ...] = ()


Settings = dict[tuple[str, str], Setting]


def _mount_of(frame: str, summary: LogSummary, base: str) -> tuple[Mount | None, str]:
    """The mount of ``frame`` from the log's static transforms, or None and why not."""
    if not summary.tf_static_topic:
        return None, "no /tf_static in the log"
    if not frame:
        return None, "its messages name no frame"
    found = chain_to_base(frame, summary.transforms, base)
    if found is None:
        return None, f"{frame!r} is not below {base!r} in {summary.tf_static_topic}"
    rotation, translation = found
    if not (np.abs(translation) <= MAX_MOUNT_M).all():
        return None, f"{frame!r} is more than {MAX_MOUNT_M:g} m from {base!r}: not believed"
    return Mount(frame, translation, rotation, "tf_static"), ""


def _base_frame(summary: LogSummary) -> tuple[str, str]:
    """base_link if the static transforms name it, else the root of their tree; with why."""
    frames = {tf.parent for tf in summary.transforms} | {tf.child for tf in summary.transforms}
    if not frames or "base_link" in frames:
        return "base_link", ""
    roots = sorted(
        {tf.parent for tf in summary.transforms} - {tf.child for tf in summary.transforms}
    )
    if not roots:  # every frame has a parent: a cycle
        return "base_link", (
            f"CHECK: the transforms of {summary.tf_static_topic} form a cycle and name no "
            "'base_link'; base_link must be on the ground below the rear-axle centre"
        )
    return roots[0], (
        f"CHECK: no 'base_link' in {summary.tf_static_topic}; using the root of its tree, "
        f"{roots[0]!r}. base_link must be on the ground below the rear-axle centre"
    )


def _floats(values: Iterable[float]) -> str:
    return toml_value([round(float(v), 9) + 0.0 for v in values])


def _vehicle_settings(summary: LogSummary, guesses: Mapping[str, RoleGuess]) -> Settings:
    """The ``[vehicle]`` keys the log decides: frames and mounts."""
    default = default_config().vehicle
    base, base_why = _base_frame(summary)
    out: Settings = {
        ("vehicle", "model"): Setting(
            toml_value(f"the robot of {summary.path.name}"), ("CHECK: name your vehicle",)
        ),
        ("vehicle", "wheelbase_m"): Setting(
            None,
            (
                "CHECK: wheelbase_m, track_m and wheel_radius_m are Stanley's (VW Touareg): a",
                "log does not say them. Measure yours: tables puts the tyre tracks at",
                "+-track_m / 2 from base_link.",
            ),
        ),
        ("vehicle", "base_frame"): Setting(toml_value(base), (base_why,) if base_why else ()),
    }
    for role, frame_key, position_key, rpy_key in (
        ("imu", "imu_frame", "imu_position_m", "imu_orientation_rad"),
        ("gps", "gps_frame", "gps_antenna_position_m", ""),
    ):
        topic = next(iter(guesses[role].topics), "")
        frame = summary.topic(topic).frame_id if topic else ""
        fallback = getattr(default, frame_key)
        frame_note = (
            f"the frame_id of {topic}'s messages"
            if frame
            else f"{topic or 'no ' + ROLE_WORDS[role]}: no frame read, the default kept"
        )
        out[("vehicle", frame_key)] = Setting(toml_value(frame or fallback), (frame_note,))
        mount, why_not = _mount_of(frame, summary, base)
        if mount is not None:
            note = f"from {summary.tf_static_topic}: {base} -> {frame}"
            out[("vehicle", position_key)] = Setting(_floats(mount.translation_m), (note,))
            if rpy_key:
                out[("vehicle", rpy_key)] = Setting(_floats(mount.rpy_rad()), (note,))
            continue
        what = "antenna" if role == "gps" else "IMU"
        notes = [
            f"CHECK: {why_not}: mount of the {what} ({frame or fallback}) assumed at {base}, "
            "identity; measure it (a wrong lever arm silently bends the pose)"
        ]
        if role == "gps" and not topic:
            notes = ["no GPS: the antenna's mount is unused"]
        out[("vehicle", position_key)] = Setting(_floats((0.0, 0.0, 0.0)), tuple(notes))
        if rpy_key:
            rpy, gravity_notes = _gravity_mount(summary, topic)
            out[("vehicle", rpy_key)] = Setting(_floats(rpy), tuple(gravity_notes))
    return out


def _gravity_mount(summary: LogSummary, imu_topic: str) -> tuple[tuple[float, ...], list[str]]:
    """The IMU's roll and pitch in base_link from where gravity points at the start (a level
    IMU along base_link reads +g on z), with the comments saying so; yaw stays 0, since
    gravity cannot tell it. A tilt under :data:`LEVEL_DEG` is taken for a slope: level."""
    level: tuple[float, ...] = (0.0, 0.0, 0.0)
    accel = summary.topic(imu_topic).accel_mean if imu_topic else None
    if accel is None or float(np.linalg.norm(accel)) < 1e-6:
        return level, []
    ax, ay, az = accel
    shown = ", ".join(f"{a:.2f}" for a in accel)
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, az / float(np.linalg.norm(accel))))))
    if tilt < LEVEL_DEG:
        return level, [f"the IMU's mean acceleration at the start, ({shown}) m/s^2, is near +z"]
    roll, pitch = math.atan2(ay, az), math.atan2(-ax, math.hypot(ay, az))
    return (roll, pitch, 0.0), [
        f"CHECK: the IMU's mean acceleration at the start is ({shown}) m/s^2, {tilt:.0f} deg "
        "from +z: the IMU is mounted turned. Roll and pitch below put gravity on base_link's "
        "z (right for a robot that started level); the yaw (0) is a guess gravity cannot "
        "tell: measure it.",
    ]


def _topic_settings(guesses: Mapping[str, RoleGuess], summary: LogSummary) -> Settings:
    """The ``[topics]`` keys: every role's topic(s) with why, and the alternatives."""
    out: Settings = {}
    for role in ROLES:
        guess = guesses[role]
        comments: list[str] = []
        if role == "lasers":
            value = toml_value(list(guess.topics))
            comments.append(guess.why if guess.topics else f"{guess.why}: project cannot run")
            for topic in guess.topics:
                t = summary.topic(topic)
                comments.append(f"  {topic}: {_describe(t)}{_laser_mount_note(t, summary)}")
        else:
            value = toml_value(guess.topics[0] if guess.topics else "")
            comments.append(f"{guess.topics[0]}: {guess.why}" if guess.topics else guess.why)
            if not guess.topics:
                comments.extend(_missing_role_notes(role))
        for topic, why in guess.others:
            comments.append(f"  also {topic}: {why}")
        for topic in guess.topics:
            problem = summary.topic(topic).problem
            if problem:
                comments.append(f"  CHECK: {topic}'s first messages did not decode: {problem}")
        out[("topics", role)] = Setting(value, tuple(comments))
    return out


def _laser_mount_note(t: TopicSummary, summary: LogSummary) -> str:
    base, _ = _base_frame(summary)
    mount, why_not = _mount_of(t.frame_id, summary, base)
    if mount is not None:
        return "; mount in /tf_static"
    return f"; CHECK: {why_not}: project drops its scans without a mount"


def _missing_role_notes(role: str) -> list[str]:
    return {
        "gps": ["without GPS, pose dead-reckons on the wheel speeds and the gyro in a local frame"],
        "heading": [
            "without a compass, pose takes the heading from the GPS track once the vehicle",
            "has moved pose.track_min_distance_m in a straight line",
        ],
        "wheels": ["without wheel speeds, pose holds the speed with the GPS alone"],
        "tf_static": ["mounts come from [vehicle] below"],
    }.get(role, [])


def _shock_band_note(rate_hz: float | None, cfg: PipelineConfig) -> tuple[bool, str]:
    """Whether the label stage's shock filter can be designed at the IMU's rate, and why."""
    lab = cfg.label
    need = 2.0 * (lab.fir_pass_hz + MIN_PASSBAND_HZ)
    band = (
        f"the FIR removes 0-{lab.fir_stop_hz:g} Hz and passes from {lab.fir_pass_hz:g} Hz "
        f"up to the IMU's Nyquist frequency, which needs at least {need:g} Hz"
    )
    if rate_hz is None:
        return False, "the IMU's rate is unknown (under two messages)"
    if rate_hz < need:
        return False, f"the IMU samples at {rate_hz:.1f} Hz, too slow for the shock band: {band}"
    try:
        design_shock_fir(rate_hz, lab.fir_taps, lab.fir_stop_hz, lab.fir_pass_hz)
    except ToolkitError as exc:  # fast enough, but these taps miss the band at this rate
        return False, f"the IMU samples at {rate_hz:.1f} Hz: {exc}"
    return True, f"the IMU samples at {rate_hz:.1f} Hz, fast enough for the shock band: {band}"


@dataclass(frozen=True)
class StageVerdicts:
    """Which stages the log can feed (pose, project, label), each with why."""

    pose: tuple[bool, str]
    project: tuple[bool, str]
    label: tuple[bool, str]


def stage_verdicts(summary: LogSummary, guesses: Mapping[str, RoleGuess]) -> StageVerdicts:
    """What each stage needs against what the log has (see the README, "Your own robot")."""
    has = {role: bool(g.topics) for role, g in guesses.items()}
    if not has["imu"]:
        pose = (False, "no IMU (sensor_msgs/msg/Imu): pose needs one")
    elif not (has["gps"] or has["wheels"]):
        pose = (False, "no GPS nor wheel speeds: pose needs an IMU and GPS or wheels")
    else:
        feeds = " and ".join(w for r, w in (("gps", "GPS"), ("wheels", "wheel speeds")) if has[r])
        pose = (True, f"an IMU, and {feeds}")
    if has["lasers"]:
        project = (True, f"{len(guesses['lasers'].topics)} laser(s), and a pose")
    else:
        project = (False, "no laser (sensor_msgs/msg/LaserScan): project needs one")
    if has["imu"]:
        imu = summary.topic(guesses["imu"].topics[0])
        ok, why = _shock_band_note(imu.rate_hz, default_config())
        label = (ok and pose[0], why if pose[0] else f"{why}; and label needs a pose")
    else:
        label = (False, "no IMU: label measures shocks on the IMU")
    return StageVerdicts(pose, project, label)


def _head(
    summary: LogSummary, guesses: Mapping[str, RoleGuess], verdicts: StageVerdicts
) -> list[str]:
    """The comments at the top of the file: where it came from and what the log can feed."""
    found = ", ".join(r for r in ROLES if guesses[r].topics) or "none"
    missing = ", ".join(r for r in ROLES if not guesses[r].topics) or "none"
    lines = [
        f"{summary.path.name}: a starting configuration written by `terrain config init`",
        f"from the log itself ({summary.duration_s:.1f} s, {len(summary.topics)} topics).",
        "Topics were matched to roles by message type, then by name; every guess is",
        "commented where it is made. Read each line marked CHECK, edit, then:",
        f"  terrain ingest {summary.path.name} -w ws -c THIS_FILE && terrain pose -w ws",
        "Keys the log cannot tell keep the built-in default's values (Stanley, 2005).",
        "",
        f"roles found: {found}",
        f"roles missing: {missing}",
        "",
        "What this log can feed:",
    ]
    for stage, (ok, why) in (
        ("pose", verdicts.pose),
        ("project", verdicts.project),
        ("label", verdicts.label),
    ):
        lines.append(f"  {stage}: {'yes' if ok else 'NO'}: {why}")
    if not (verdicts.project[0] and verdicts.label[0]):
        lines.append("  tables, learn, evaluate: NO: they need both project and label")
    if summary.problems:
        lines.append(
            f"`terrain info` finds {summary.problems} problem(s) in this log: read them first"
        )
    return lines


def _pose_settings(guesses: Mapping[str, RoleGuess]) -> Settings:
    has_gps = bool(guesses["gps"].topics)
    if not has_gps and guesses["wheels"].topics:
        return {
            ("pose", "dead_reckoning"): Setting(
                toml_value("odometry"),
                (
                    "no GPS: dead-reckon on the wheel speeds and the gyro's heading (the",
                    "accelerometer of a slow robot must not steer the heading)",
                ),
            )
        }
    return {
        ("pose", "dead_reckoning"): Setting(
            None,
            (
                'CHECK: used only while there is no GPS fix. "odometry" for a slow robot with',
                'a MEMS IMU (pipelines/husky.toml), "inertial" for a fast one with a good IMU',
            ),
        )
    }


def _label_settings(verdicts: StageVerdicts, guesses: Mapping[str, RoleGuess]) -> Settings:
    if not guesses["imu"].topics:
        return {}
    mark = "" if verdicts.label[0] else "CHECK: "
    return {("label", "fir_taps"): Setting(None, (f"{mark}{verdicts.label[1]}",))}


def log_settings(summary: LogSummary, guesses: Mapping[str, RoleGuess]) -> Settings:
    """Every key the log decides or comments on, by (section, key)."""
    verdicts = stage_verdicts(summary, guesses)
    name = re.sub(r"[^A-Za-z0-9_.-]+", "-", summary.path.stem).strip("-") or "my-robot"
    settings: Settings = {("", "name"): Setting(toml_value(name))}
    settings.update(_topic_settings(guesses, summary))
    settings.update(_vehicle_settings(summary, guesses))
    settings.update(_pose_settings(guesses))
    settings.update(_label_settings(verdicts, guesses))
    return settings


#: Width of a generated comment line, "# " included (the default's lines are within 100).
COMMENT_WIDTH = 96


def comment_lines(texts: Iterable[str]) -> list[str]:
    """TOML comment lines of ``texts``, each wrapped to :data:`COMMENT_WIDTH` (a text's
    leading spaces indent its continuation lines too); an empty text is a bare ``#``."""
    out: list[str] = []
    for text in texts:
        indent = " " * (len(text) - len(text.lstrip(" ")))
        wrapped = textwrap.wrap(
            text,
            width=COMMENT_WIDTH - 2,
            subsequent_indent=indent + "  ",
            break_long_words=False,
            break_on_hyphens=False,
        )
        out.extend(f"# {w}".rstrip() for w in wrapped or [""])
    return out


_SECTION = re.compile(r"^\[([A-Za-z0-9_.]+)\]")
_KEY = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\s*=")
_CONTINUATION = re.compile(r"^\s+#")


def apply_settings(default_text: str, head: Sequence[str], settings: Settings) -> str:
    """The default's text with ``head`` replacing its opening comments and each key of
    ``settings`` preceded by its comments and, where it gives a value, rewritten (the
    default's comments on a rewritten key, which describe Stanley, are dropped).

    Raises ValueError for a setting whose key the default does not have (a programming
    error: the default lists every key)."""
    lines = default_text.splitlines()
    start = next(i for i, line in enumerate(lines) if _KEY.match(line))
    out = [*comment_lines(head), ""]
    section = ""
    used: set[tuple[str, str]] = set()
    skipping = False
    for line in lines[start:]:
        if skipping and _CONTINUATION.match(line):
            continue
        skipping = False
        header = _SECTION.match(line)
        if header:
            section = header.group(1)
        key = _KEY.match(line)
        setting = settings.get((section, key.group(1))) if key else None
        if key is None or setting is None:
            out.append(line)
            continue
        used.add((section, key.group(1)))
        out.extend(comment_lines(setting.comments))
        if setting.value is None:
            out.append(line)
        else:
            out.append(f"{key.group(1)} = {setting.value}")
            skipping = True
    unknown = set(settings) - used
    if unknown:
        raise ValueError(f"settings for keys the default does not have: {sorted(unknown)}")
    return "\n".join(out).rstrip("\n") + "\n"


def _default_text() -> str:
    resource = importlib.resources.files("toolkit").joinpath(DEFAULT_CONFIG_RESOURCE)
    return resource.read_text(encoding="utf-8")


def render_config(summary: LogSummary, guesses: Mapping[str, RoleGuess]) -> str:
    """The configuration's TOML text for a log (see the module docstring)."""
    head = _head(summary, guesses, stage_verdicts(summary, guesses))
    return apply_settings(_default_text(), head, log_settings(summary, guesses))


def init_config(path: str | Path) -> str:
    """``terrain config init``: the starting configuration of a log, as TOML text that
    :func:`~toolkit.config.parse_config` has just loaded without error."""
    summary = summarize_log(path)
    if summary.problems:  # said on the terminal too, not only in the file's comments
        _log.warning(
            "%s: %d problem(s) in this log (damaged or truncated); the configuration is "
            "guessed from what could be read: see `terrain info %s`",
            summary.path,
            summary.problems,
            summary.path,
        )
    text = render_config(summary, guess_roles(summary))
    try:
        parse_config(text, source=f"<configuration written for {summary.path}>")
    except ConfigError as exc:  # a bug here, said as one line rather than a bad file
        raise ConfigError(
            f"the configuration written for this log does not load: {exc}", path
        ) from exc
    return text


__all__ = [
    "LogSummary",
    "RoleGuess",
    "Setting",
    "StageVerdicts",
    "TopicSummary",
    "apply_settings",
    "comment_lines",
    "guess_role",
    "guess_roles",
    "init_config",
    "log_settings",
    "render_config",
    "stage_verdicts",
    "summarize_log",
]
