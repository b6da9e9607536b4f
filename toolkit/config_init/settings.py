"""Step 3 of ``config init``, the other keys: topics, pose and label settings, and the
head saying which stages the log can feed.

Part of :mod:`toolkit.config_init`, whose docstring tells the steps.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

from toolkit.config import PipelineConfig, default_config, toml_value
from toolkit.config_init.mounts import base_frame, mount_of, vehicle_settings
from toolkit.config_init.render import Setting, Settings
from toolkit.config_init.roles import RoleGuess, describe_topic, topic_label
from toolkit.config_init.summary import LogSummary, TopicSummary
from toolkit.errors import ToolkitError
from toolkit.ingestion.roles import ROLE_SPECS
from toolkit.mcapio.pointcloud2 import preset_for_fields
from toolkit.model.shock import MIN_PASSBAND_HZ, design_shock_fir


def _topic_settings(guesses: Mapping[str, RoleGuess], summary: LogSummary) -> Settings:
    """The ``[topics]`` keys: every role's topic(s) with why, and the alternatives."""
    out: Settings = {}
    for role, spec in ROLE_SPECS.items():
        guess = guesses[role]
        comments: list[str] = []
        if spec.multi:
            value = toml_value(list(guess.topics))
            comments.append(guess.why if guess.topics else f"{guess.why}")
            for topic in guess.topics:
                t = summary.topic(topic)
                comments.append(f"  {topic}: {describe_topic(t)}{_laser_mount_note(t, summary)}")
        else:
            value = toml_value(guess.topics[0] if guess.topics else "")
            comments.append(f"{guess.topics[0]}: {guess.why}" if guess.topics else guess.why)
            if not guess.topics:
                comments.extend(_missing_role_notes(role))
        for topic, why in guess.others:
            comments.append(f"  also {topic_label(topic)}: {why}")
        for topic in guess.topics:
            chosen = summary.topic(topic)
            if chosen.problem:
                comments.append(
                    f"  CHECK: {topic}'s first messages did not decode: {chosen.problem}"
                )
            if chosen.layout is not None and chosen.layout.difference is not None:
                comments.append(
                    f"  NOTE: {topic}'s schema {chosen.layout.difference}: ingest decodes it "
                    "by the log's own schema"
                )
        out[("topics", role)] = Setting(value, tuple(comments))
    return out


def _laser_mount_note(t: TopicSummary, summary: LogSummary) -> str:
    base, _ = base_frame(summary)
    mount, why_not = mount_of(t.frame_id, summary, base)
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
    scanners = [
        f"{len(guesses[role].topics)} {word}(s)"
        for role, word in (("lasers", "laser"), ("lidars", "3-D lidar"))
        if has[role]
    ]
    if scanners:
        project = (True, f"{' and '.join(scanners)}, and a pose")
    else:
        project = (
            False,
            "no laser (sensor_msgs/msg/LaserScan) nor 3-D lidar (sensor_msgs/msg/PointCloud2): "
            "project needs one",
        )
    if has["imu"]:
        imu = summary.topic(guesses["imu"].topics[0])
        ok, why = _shock_band_note(imu.rate_hz, default_config())
        label = (ok and pose[0], why if pose[0] else f"{why}; and label needs a pose")
    else:
        label = (False, "no IMU: label measures shocks on the IMU")
    return StageVerdicts(pose, project, label)


def file_head(
    summary: LogSummary, guesses: Mapping[str, RoleGuess], verdicts: StageVerdicts
) -> list[str]:
    """The comments at the top of the file: where it came from and what the log can feed."""
    found = ", ".join(r for r in ROLE_SPECS if guesses[r].topics) or "none"
    missing = ", ".join(r for r in ROLE_SPECS if not guesses[r].topics) or "none"
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
    lines.extend(f"CHECK: {warning}" for warning in summary.tf_warnings)
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


def _lidar_settings(guesses: Mapping[str, RoleGuess], summary: LogSummary) -> Settings:
    """``[lidar] time``: the driver preset the lidars' field names say, with why; and the
    cloud kept near the tyres' paths (``[project] keep``)."""
    topics = guesses["lidars"].topics
    if not topics:
        return {}
    found = {t: preset_for_fields(summary.topic(t).point_fields) for t in topics}
    presets = sorted(set(found.values()))
    comments = [
        f"{t}: fields {', '.join(summary.topic(t).point_fields) or 'unread'} -> {p}"
        for t, p in found.items()
    ]
    preset = presets[0]
    if len(presets) > 1:
        comments.append(
            f"CHECK: the lidars' layouts differ ({', '.join(presets)}): 'auto' reads each"
        )
        preset = "auto"
    if presets == ["none"]:
        comments.append(
            "CHECK: no per-point time field: every return at its cloud's stamp (motion "
            'correction off); name the field with time = "custom" if the driver has one'
        )
    keep = Setting(
        toml_value("near_path"),
        (
            "a spinning 3-D lidar sees all around, most returns far from the tyres: the cloud",
            'keeps those the tables use ("all" keeps every one, at ~9 bytes a return)',
        ),
    )
    return {
        ("lidar", "time"): Setting(toml_value(preset), tuple(comments)),
        ("project", "keep"): keep,
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
    settings.update(_lidar_settings(guesses, summary))
    settings.update(vehicle_settings(summary, guesses))
    settings.update(_pose_settings(guesses))
    settings.update(_label_settings(verdicts, guesses))
    return settings


#: Width of a generated comment line, "# " included (the default's lines are within 100).
