"""Step 3 of ``config init``, the vehicle: sensor frames and mounts from the log's static
transforms and the IMU's gravity, as the :class:`Setting` values of ``[vehicle]``.

Part of :mod:`toolkit.config_init`, whose docstring tells the steps.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np

from toolkit.config import (
    default_config,
    toml_value,
)
from toolkit.config_init.render import Setting, Settings
from toolkit.config_init.roles import ROLE_WORDS, RoleGuess
from toolkit.config_init.summary import LEVEL_DEG, MAX_MOUNT_M, LogSummary
from toolkit.geometry.mounts import Mount, chain_to_base


def mount_of(frame: str, summary: LogSummary, base: str) -> tuple[Mount | None, str]:
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


def base_frame(summary: LogSummary) -> tuple[str, str]:
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


def vehicle_settings(summary: LogSummary, guesses: Mapping[str, RoleGuess]) -> Settings:
    """The ``[vehicle]`` keys the log decides: frames and mounts."""
    default = default_config().vehicle
    base, base_why = base_frame(summary)
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
        mount, why_not = mount_of(frame, summary, base)
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
