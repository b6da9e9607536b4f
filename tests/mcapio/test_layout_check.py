"""A log's own schema against the toolkit's layout of a type (toolkit/mcapio/layout_check.py):
the first field that differs on the wire is named, and nothing but the wire counts (comments,
spacing, constants, bounds)."""

from __future__ import annotations

from pathlib import Path

import pytest

from toolkit.mcapio.layout_check import (
    channel_layout,
    field_mismatch,
    layout_difference,
    standard_spec,
)
from toolkit.mcapio.msgdefs import known_types, load_msgdef, parse_msgdef, parse_schema_text
from toolkit.mcapio.reader import LogReader
from toolkit.mcapio.records import Channel

REPO = Path(__file__).resolve().parents[2]
#: Logs written by the toolkit's simulator, by rosbag2 through rosbags, and by lidar drivers.
LOGS = [
    REPO / "sample_logs" / "sample.mcap",
    REPO / "tests" / "data" / "real-logs" / "husky-gps-imu-odom.mcap",
    *sorted((REPO / "tests" / "data" / "real-lidar").glob("*.mcap")),
]
NAVSATFIX = "sensor_msgs/msg/NavSatFix"
IMU = "sensor_msgs/msg/Imu"


def difference(type_name: str, text: str) -> str | None:
    """The first difference of ``text`` (a log's schema of ``type_name``) from the standard."""
    return layout_difference(parse_msgdef(type_name), parse_schema_text(type_name, text))


def compact(type_name: str) -> str:
    """The toolkit's schema text of ``type_name`` without its comments and blank lines."""
    lines = load_msgdef(type_name).splitlines()
    return "\n".join(ln for ln in lines if ln.strip() and not ln.startswith("#")) + "\n"


def replaced(type_name: str, old: str, new: str) -> str:
    """The compact schema text of ``type_name`` with one edit (which must apply)."""
    text = compact(type_name)
    assert old in text, old
    return text.replace(old, new, 1)


def noisy(text: str) -> str:
    """The same definitions with comments everywhere, blank lines, odd spacing and trailing
    blanks: what another writer might put in a log for a standard type."""
    out = ["# written by another tool", ""]
    for line in text.splitlines():
        if line.startswith(("=", "MSG:")) or not line.strip() or line.startswith("#"):
            out.append(line)
            continue
        type_name, _, rest = line.partition(" ")
        out.append(f"{type_name}    {rest.strip()}   # a comment, and another # here  ")
        out.append("")
    return "\n".join(out) + "\n\n"


@pytest.mark.parametrize("type_name", known_types())
def test_the_toolkit_s_own_texts_and_noisy_copies_are_standard(type_name: str) -> None:
    """The text the simulator writes (load_msgdef) and a copy with comments, blank lines and
    odd spacing lay out the same bytes: no difference."""
    text = load_msgdef(type_name)
    assert difference(type_name, text) is None
    assert difference(type_name, noisy(text)) is None
    assert difference(type_name, compact(type_name)) is None


def test_constants_bounds_and_defaults_do_not_count() -> None:
    """rosbag2 writes constants first without spaces; bounds and defaults change no byte."""
    constant = "uint8 COVARIANCE_TYPE_KNOWN = 3\n"
    first = "uint8 COVARIANCE_TYPE_KNOWN=3\n" + replaced(NAVSATFIX, constant, "")
    assert difference(NAVSATFIX, first) is None
    bounded = replaced(NAVSATFIX, "string frame_id", "string<=32 frame_id")
    assert difference(NAVSATFIX, bounded) is None
    defaulted = replaced(NAVSATFIX, "float64 altitude", "float64 altitude 0.0")
    assert difference(NAVSATFIX, defaulted) is None


def test_every_channel_of_the_project_s_logs_is_standard() -> None:
    """The simulator's sample log, a real robot's log and the real lidars' logs: every
    channel of a type the toolkit ships agrees with its layout (no false alarm)."""
    checked = 0
    for path in LOGS:
        with LogReader(path) as reader:
            for channel in reader.channels().values():
                layout = channel_layout(channel)
                if layout.standard is not None:
                    assert layout.is_standard, (path.name, channel.topic, layout.difference)
                    checked += 1
    assert checked >= 20


def test_swapped_latitude_and_longitude_are_named() -> None:
    swapped = replaced(
        NAVSATFIX, "float64 latitude\nfloat64 longitude", "float64 longitude\nfloat64 latitude"
    )
    assert difference(NAVSATFIX, swapped) == (
        "declares `longitude` where the standard layout has `latitude` (field 3)"
    )


@pytest.mark.parametrize(
    ("old", "new", "said"),
    [
        (
            "geometry_msgs/Vector3 linear_acceleration",
            "geometry_msgs/Vector3 accel",
            "declares `accel` where the standard layout has `linear_acceleration` (field 6)",
        ),
        (
            "geometry_msgs/Vector3 angular_velocity",
            "float32 temperature\ngeometry_msgs/Vector3 angular_velocity",
            "declares `temperature` where the standard layout has `angular_velocity` (field 4)",
        ),
        (
            "float64[9] orientation_covariance",
            "float64[4] orientation_covariance",
            "declares `orientation_covariance` as float64[4] where the standard layout has "
            "float64[9] (field 3)",
        ),
        (
            "float64[9] linear_acceleration_covariance",
            "float64[9] linear_acceleration_covariance\nuint32 seq",
            "declares an extra field `seq` (field 8)",
        ),
        (
            "\nfloat64[9] linear_acceleration_covariance",
            "",
            "lacks `linear_acceleration_covariance` (field 7 of the standard layout)",
        ),
        (
            "MSG: std_msgs/Header\n",
            "MSG: std_msgs/Header\nuint32 seq\n",
            "declares `header.seq` where the standard layout has `header.stamp` "
            "(field 1 of std_msgs/msg/Header)",
        ),
        (
            "MSG: geometry_msgs/Vector3\nfloat64 x",
            "MSG: geometry_msgs/Vector3\nfloat32 x",
            "declares `angular_velocity.x` as float32 where the standard layout has float64 "
            "(field 1 of geometry_msgs/msg/Vector3)",
        ),
        (
            "geometry_msgs/Quaternion orientation",
            "geometry_msgs/Vector3 orientation",
            "declares `orientation` as geometry_msgs/msg/Vector3 where the standard layout "
            "has geometry_msgs/msg/Quaternion (field 2)",
        ),
    ],
)
def test_the_first_difference_of_an_imu_is_named(old: str, new: str, said: str) -> None:
    """Renamed, inserted, resized, added, removed and retyped fields, in the message and in
    its nested ones, each named by its dotted path and position."""
    assert difference(IMU, replaced(IMU, old, new)) == said


def test_field_mismatch_asks_only_for_the_fields_read() -> None:
    standard = parse_msgdef(IMU)
    extra = parse_schema_text(
        IMU,
        replaced(
            IMU,
            "geometry_msgs/Vector3 angular_velocity",
            "float32 temperature\ngeometry_msgs/Vector3 angular_velocity",
        ),
    )
    reads = ("header.stamp.sec", "linear_acceleration.z", "orientation_covariance")
    assert field_mismatch(standard, extra, reads) is None  # reordered, extra: still readable
    renamed = parse_schema_text(
        IMU,
        replaced(IMU, "geometry_msgs/Vector3 linear_acceleration", "geometry_msgs/Vector3 accel"),
    )
    assert field_mismatch(standard, renamed, reads) == "has no field `linear_acceleration.z`"
    assert field_mismatch(standard, renamed, ("orientation_covariance",)) is None
    short = parse_schema_text(
        IMU, replaced(IMU, "float64[9] orientation_covariance", "float64[] orientation_covariance")
    )
    assert field_mismatch(standard, short, reads) == (
        "declares `orientation_covariance` as float64[] where the standard layout has float64[9]"
    )
    with pytest.raises(ValueError, match="no field"):  # a converter's typo is a bug
        field_mismatch(standard, extra, ("linear_acceleration.q",))


def test_through_an_array_of_messages() -> None:
    """TFMessage: a path runs through its array of transforms into their nested fields."""
    name = "tf2_msgs/msg/TFMessage"
    standard = parse_msgdef(name)
    moved = parse_schema_text(
        name, replaced(name, "MSG: geometry_msgs/Vector3\n", "MSG: geometry_msgs/Vector3\nint8 w\n")
    )
    assert layout_difference(standard, moved) == (
        "declares `transforms.transform.translation.w` where the standard layout has "
        "`transforms.transform.translation.x` (field 1 of geometry_msgs/msg/Vector3)"
    )
    assert field_mismatch(standard, moved, ("transforms.transform.translation.x",)) is None
    assert field_mismatch(standard, moved, ("transforms.transform.translation",)) == (
        "declares `transforms.transform.translation.w` where the standard layout has "
        "`transforms.transform.translation.x` (field 1 of geometry_msgs/msg/Vector3)"
    )


def test_channel_layout_of_known_unknown_and_textless_channels() -> None:
    def channel(name: str, data: bytes, encoding: str = "ros2msg") -> Channel:
        return Channel(1, "/t", "cdr", name, encoding, data, schema_id=1)

    standard = channel_layout(channel("sensor_msgs/NavSatFix", load_msgdef(NAVSATFIX).encode()))
    assert standard.is_standard and standard.type_name == NAVSATFIX
    unknown = channel_layout(channel("sensor_msgs/FluidPressure", b"float64 fluid_pressure\n"))
    assert unknown.standard is None and unknown.log is not None and not unknown.is_standard
    textless = channel_layout(channel(NAVSATFIX, b""))
    assert textless.log is None and textless.is_standard  # only its name to go by
    assert standard_spec("not a type name") is None
