"""The log's schema decides (issue 36, point 3): a topic whose schema of a type the toolkit
ships departs from the toolkit's layout is never decoded by that layout.

When the fields its role reads are all in the log's schema, by name and standard type, the
topic is decoded by the log's own schema and the terminal says so once; otherwise ingest
refuses the topic with one line naming the log, the topic and the first differing field, and
``terrain info`` and ``config init`` do not offer it to that role. A standard schema, however
commented or spaced, takes the fast path without a word.

Logs are written with ``mcap_ros2``'s writer, which encodes each message by the schema text it
is given: the bytes follow the log's schema, as a foreign recorder's would."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from mcap.writer import Writer as McapWriter
from mcap_ros2.writer import Writer

from toolkit.cli import main
from toolkit.config import PipelineConfig, parse_config
from toolkit.config_init import init_config
from toolkit.errors import StageError
from toolkit.ingestion import plans as plans_mod
from toolkit.mcapio.cdr_encode import encode_message
from toolkit.mcapio.msgdefs import load_msgdef, parse_schema_text
from toolkit.stages.ingest import ingest_log
from toolkit.workspace import Workspace

NAVSATFIX = "sensor_msgs/msg/NavSatFix"
IMU = "sensor_msgs/msg/Imu"
TF = "tf2_msgs/msg/TFMessage"
T0_NS = 1_700_000_000 * 10**9
LATITUDE_DEG, LONGITUDE_DEG = 36.6, -115.39


def edited(type_name: str, old: str, new: str) -> str:
    """The toolkit's schema text of ``type_name`` (the simulator's) with one edit."""
    text = load_msgdef(type_name)
    assert old in text, old
    return text.replace(old, new, 1)


SWAPPED_FIX = edited(
    NAVSATFIX, "float64 latitude\nfloat64 longitude", "float64 longitude\nfloat64 latitude"
)
#: An IMU that also reports its temperature, before its angular velocity.
IMU_WITH_TEMPERATURE = edited(
    IMU,
    "geometry_msgs/Vector3 angular_velocity\n",
    "float32 temperature\ngeometry_msgs/Vector3 angular_velocity\n",
)
#: An IMU whose acceleration field has another name: nothing to read the imu role from.
IMU_RENAMED = edited(
    IMU, "geometry_msgs/Vector3 linear_acceleration\n", "geometry_msgs/Vector3 accel\n"
)
#: Static transforms whose Transform declares its rotation before its translation.
TF_ROTATION_FIRST = edited(
    TF,
    "Vector3 translation\nQuaternion rotation",
    "Quaternion rotation\nVector3 translation",
)


def noisy(text: str) -> str:
    """A standard schema as another tool might write it: comments, blank lines and spacing
    everywhere, constants without spaces. It lays out exactly the standard bytes."""
    out = ["# recorded by another tool", ""]
    for line in text.splitlines():
        if line and not line.startswith(("#", "=", "MSG:")):
            kind, _, rest = line.partition(" ")
            line = f"{kind}\t  {rest.replace(' = ', '=')}    # what it is  "
        out += [line, ""]
    return "\n".join(out)


def stamp(t_ns: int) -> dict[str, int]:
    return {"sec": t_ns // 10**9, "nanosec": t_ns % 10**9}


def imu_message(t_ns: int, k: int) -> dict[str, Any]:
    return {
        "header": {"stamp": stamp(t_ns), "frame_id": "imu_link"},
        "orientation": {"w": 1.0},
        "angular_velocity": {"z": 0.01 * k},
        # within an IMU's full scale (16 g) for the 2,000 samples of the longest log here
        "linear_acceleration": {"x": 0.05 * k, "z": 9.81},
        "accel": {"x": 0.05 * k, "z": 9.81},
        "temperature": 21.5,
    }


def fix_message(t_ns: int, k: int) -> dict[str, Any]:
    return {
        "header": {"stamp": stamp(t_ns), "frame_id": "gps"},
        "status": {"status": 0},
        "latitude": LATITUDE_DEG + k * 1e-6,
        "longitude": LONGITUDE_DEG,
        "altitude": 900.0,
    }


def tf_message(t_ns: int) -> dict[str, Any]:
    transform = {
        "header": {"stamp": stamp(t_ns), "frame_id": "base_link"},
        "child_frame_id": "imu_link",
        "transform": {
            "translation": {"x": 0.5, "y": -0.25, "z": 1.5},
            "rotation": {"x": 0.0, "y": 0.0, "z": 0.6, "w": 0.8},
        },
    }
    return {"transforms": [transform]}


def write_log(
    path: Path,
    *,
    imu: str | None = None,
    fix: str | None = None,
    tf: str | None = None,
    seconds: int = 2,
    chunk_size: int = 1024 * 1024,
) -> Path:
    """A 100 Hz IMU on /imu/data, a 10 Hz fix on /gps/fix and one /tf_static message, each
    written (and encoded) by the schema text given; a topic without one is left out."""
    with path.open("wb") as f:
        writer = Writer(f, chunk_size=chunk_size)
        imu_schema = writer.register_msgdef(IMU, imu) if imu else None
        fix_schema = writer.register_msgdef(NAVSATFIX, fix) if fix else None
        if tf:
            writer.write_message("/tf_static", writer.register_msgdef(TF, tf), tf_message(T0_NS))
        for k in range(100 * seconds):
            t = T0_NS + k * 10_000_000
            if imu_schema is not None:
                writer.write_message("/imu/data", imu_schema, imu_message(t, k), t, t)
            if fix_schema is not None and k % 10 == 0:
                writer.write_message("/gps/fix", fix_schema, fix_message(t, k // 10), t, t)
        writer.finish()
    return path


CONFIG = """\
[topics]
lasers = []
imu = "/imu/data"
gps = "/gps/fix"
heading = ""
wheels = ""
tf_static = "{tf}"
truth_pose = ""
truth_features = ""
"""


def config(tf: str = "") -> PipelineConfig:
    return parse_config(CONFIG.format(tf=tf))


def table(ws: Workspace, log_id: str, name: str) -> Any:
    return pq.read_table(ws.log_table(log_id, name))


def schema_lines(warnings: Sequence[str]) -> list[str]:
    return [w for w in warnings if "its schema" in w]


def terrain(*args: str) -> subprocess.CompletedProcess[str]:
    """The command line, as a user runs it."""
    return subprocess.run(
        [sys.executable, "-m", "toolkit", *args], capture_output=True, text=True, check=False
    )


# --------------------------------------------------------------------------------------
# Decoded by the log's own schema
# --------------------------------------------------------------------------------------


def test_swapped_latitude_and_longitude_are_read_where_the_schema_puts_them(
    tmp_path: Path,
) -> None:
    """The hostile fix: its schema declares longitude first and its bytes follow. The table
    holds the true latitude and longitude, and the terminal says how the topic was read."""
    log = write_log(tmp_path / "log.mcap", imu=load_msgdef(IMU), fix=SWAPPED_FIX)
    cfg = tmp_path / "config.toml"
    cfg.write_text(CONFIG.format(tf=""))
    ws = tmp_path / "ws"
    proc = terrain("ingest", str(log), "-w", str(ws), "-c", str(cfg))
    assert proc.returncode == 0, proc.stderr
    said = [line for line in proc.stderr.splitlines() if "its schema" in line]
    assert len(said) == 1, proc.stderr
    assert said[0].startswith("terrain: warning: ")
    assert (
        f"{log}: topic /gps/fix: its schema sensor_msgs/msg/NavSatFix declares `longitude` "
        "where the standard layout has `latitude` (field 3): decoded by the log's own schema"
    ) in said[0]
    (log_id,) = Workspace(ws).log_ids()
    log_dir = Workspace(ws).log_dir(log_id)
    gps = pq.read_table(log_dir / "gps.parquet")
    np.testing.assert_allclose(
        gps.column("latitude").to_numpy(), LATITUDE_DEG + np.arange(20) * 1e-6
    )
    np.testing.assert_allclose(gps.column("longitude").to_numpy(), LONGITUDE_DEG)
    manifest = json.loads((log_dir / "manifest.json").read_text())
    assert schema_lines(manifest["stages"]["ingest"]["warnings"]) == [
        said[0].split(f"{log}: ", 1)[1]
    ]


def test_an_imu_with_a_foreign_field_is_decoded_by_its_own_schema(tmp_path: Path) -> None:
    """A temperature field before the angular velocity shifts every later field by 8 bytes:
    read by the log's schema, each value is where it belongs."""
    log = write_log(tmp_path / "log.mcap", imu=IMU_WITH_TEMPERATURE, fix=load_msgdef(NAVSATFIX))
    ws = Workspace(tmp_path / "ws")
    result = ingest_log(log, ws, config())
    assert schema_lines(result.warnings) == [
        "topic /imu/data: its schema sensor_msgs/msg/Imu declares `temperature` where the "
        "standard layout has `angular_velocity` (field 4): decoded by the log's own schema, "
        "which has every field role imu reads"
    ]
    imu = table(ws, result.log_id, "imu")
    k = np.arange(200)
    np.testing.assert_allclose(imu.column("accel_x").to_numpy(), 0.05 * k)
    np.testing.assert_allclose(imu.column("accel_z").to_numpy(), 9.81)
    np.testing.assert_allclose(imu.column("gyro_z").to_numpy(), 0.01 * k)
    assert imu.column("orientation_w").to_pylist() == [1.0] * 200
    assert result.rejects == {}


def test_static_transforms_are_read_by_their_own_schema(tmp_path: Path) -> None:
    """A type without a fixed layout (an array of transforms) is decoded message by message,
    by the log's text too, not the toolkit's."""
    log = write_log(
        tmp_path / "log.mcap",
        imu=load_msgdef(IMU),
        fix=load_msgdef(NAVSATFIX),
        tf=TF_ROTATION_FIRST,
    )
    ws = Workspace(tmp_path / "ws")
    result = ingest_log(log, ws, config(tf="/tf_static"))
    (said,) = schema_lines(result.warnings)
    assert "declares `transforms.transform.rotation` where the standard layout has" in said
    doc = json.loads((ws.log_dir(result.log_id) / "tf_static.json").read_text())
    (transform,) = doc["transforms"]
    assert transform["translation_m"] == [0.5, -0.25, 1.5]
    assert transform["rotation_xyzw"] == [0.0, 0.0, 0.6, 0.8]


def test_another_channel_of_the_topic_is_read_by_its_own_schema(tmp_path: Path) -> None:
    """Two channels on /gps/fix, both named NavSatFix, one standard, one swapped: each is
    decoded by its own schema (a second channel is planned on its own, not by its name)."""
    log = tmp_path / "log.mcap"
    texts = {"standard": load_msgdef(NAVSATFIX), "swapped": SWAPPED_FIX}
    with log.open("wb") as f:
        writer = McapWriter(f)
        writer.start(profile="ros2")
        channels = {}
        for key, text in texts.items():
            schema = writer.register_schema(NAVSATFIX, "ros2msg", text.encode())
            channels[key] = (
                writer.register_channel("/gps/fix", "cdr", schema),
                parse_schema_text(NAVSATFIX, text),
            )
        for k in range(20):
            t = T0_NS + k * 100_000_000
            channel, spec = channels["standard" if k % 2 else "swapped"]
            payload = encode_message(spec, fix_message(t, k))
            writer.add_message(channel, log_time=t, data=payload, publish_time=t)
        writer.finish()
    ws = Workspace(tmp_path / "ws")
    result = ingest_log(log, ws, config())
    gps = table(ws, result.log_id, "gps")
    np.testing.assert_allclose(
        gps.column("latitude").to_numpy(), LATITUDE_DEG + np.arange(20) * 1e-6
    )
    np.testing.assert_allclose(gps.column("longitude").to_numpy(), LONGITUDE_DEG)
    assert len(schema_lines(result.warnings)) == 1


# --------------------------------------------------------------------------------------
# Refused
# --------------------------------------------------------------------------------------


def test_an_imu_without_the_fields_its_role_reads_is_refused_in_one_line(tmp_path: Path) -> None:
    log = write_log(tmp_path / "log.mcap", imu=IMU_RENAMED, fix=load_msgdef(NAVSATFIX))
    cfg = tmp_path / "config.toml"
    cfg.write_text(CONFIG.format(tf=""))
    ws = tmp_path / "ws"
    proc = terrain("ingest", str(log), "-w", str(ws), "-c", str(cfg))
    assert proc.returncode == 1, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("terrain: error:")]
    assert len(errors) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert (
        f"{log}: topic /imu/data: its schema sensor_msgs/msg/Imu declares `accel` where the "
        "standard layout has `linear_acceleration` (field 6); role imu cannot read it: the "
        "schema has no field `linear_acceleration.x`"
    ) in errors[0]
    assert not list(ws.rglob("*.parquet"))


def test_a_point_cloud_is_read_by_its_standard_layout_only(tmp_path: Path) -> None:
    """A PointCloud2 is read by its own decoder, which knows the standard layout alone."""
    cloud = "sensor_msgs/msg/PointCloud2"
    text = edited(cloud, "uint32 height", "uint16 height")
    log = tmp_path / "log.mcap"
    with log.open("wb") as f:
        writer = Writer(f)
        schema = writer.register_msgdef(cloud, text)
        writer.write_message(
            "/points", schema, {"header": {"stamp": stamp(T0_NS)}, "height": 1}, T0_NS, T0_NS
        )
        writer.finish()
    cfg = parse_config(
        CONFIG.format(tf="").replace("lasers = []", 'lasers = []\nlidars = ["/points"]')
    )
    with pytest.raises(StageError) as err:
        ingest_log(log, Workspace(tmp_path / "ws"), cfg)
    assert str(err.value) == (
        f"{log}: topic /points: its schema sensor_msgs/msg/PointCloud2 declares `height` as "
        "uint16 where the standard layout has uint32 (field 2); role lidars reads "
        "sensor_msgs/msg/PointCloud2 by its standard layout only"
    )


# --------------------------------------------------------------------------------------
# The standard layout, however written: fast, and nothing said
# --------------------------------------------------------------------------------------


def test_a_commented_standard_schema_takes_the_fast_path_silently(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Comments, blank lines, tabs and constants change no byte: no line on the terminal,
    and every batch goes to the fast decoder by the type's name. The schema is compared
    once per channel, not per chunk or message."""
    log = write_log(
        tmp_path / "log.mcap",
        imu=noisy(load_msgdef(IMU)),
        fix=noisy(load_msgdef(NAVSATFIX)),
        seconds=20,
        chunk_size=16 * 1024,
    )
    compared: list[str] = []
    bound_to: list[object] = []
    real_layout, real_decode = plans_mod.channel_layout, plans_mod.decode_batch

    def counting_layout(channel: Any) -> Any:
        compared.append(channel.topic)
        return real_layout(channel)

    def spying_decode(type_name: Any, payloads: Any, **kw: Any) -> Any:
        bound_to.append(type_name)
        return real_decode(type_name, payloads, **kw)

    monkeypatch.setattr(plans_mod, "channel_layout", counting_layout)
    monkeypatch.setattr(plans_mod, "decode_batch", spying_decode)
    ws = Workspace(tmp_path / "ws")
    result = ingest_log(log, ws, config())
    assert schema_lines(result.warnings) == []
    assert sorted(compared) == ["/gps/fix", "/imu/data"]
    assert len(bound_to) > 10  # many chunks, one decode call each per topic
    assert set(bound_to) == {IMU, NAVSATFIX}  # by name: the toolkit's fast layout
    assert result.row_counts["imu"] == 2000 and result.row_counts["gps"] == 200
    gps = table(ws, result.log_id, "gps")
    np.testing.assert_allclose(
        gps.column("latitude").to_numpy()[:3], LATITUDE_DEG + np.arange(3) * 1e-6
    )


# --------------------------------------------------------------------------------------
# info and config init
# --------------------------------------------------------------------------------------


def info_rows(log: Path) -> Mapping[str, str]:
    result = CliRunner().invoke(main, ["info", str(log)])
    assert result.exit_code == 0, result.output
    rows = {}
    for line in result.stdout.splitlines():
        if line.startswith("/"):
            rows[line.split()[0]] = line.split()[-1]
    return rows


def test_info_and_config_init_offer_a_topic_only_to_roles_its_schema_serves(
    tmp_path: Path,
) -> None:
    """The renamed IMU can be nothing; the swapped fix can still be the GPS, with a note;
    both are said among info's findings (not as damage)."""
    log = write_log(tmp_path / "log.mcap", imu=IMU_RENAMED, fix=SWAPPED_FIX)
    assert info_rows(log) == {"/imu/data": "-", "/gps/fix": "gps"}
    doc = json.loads(CliRunner().invoke(main, ["info", str(log), "--json"]).stdout)
    kinds = [p["kind"] for p in doc["problems"]]
    assert kinds.count("nonstandard_schema") == 2
    roles = {t["topic"]: t["roles"] for t in doc["topics"]}
    assert roles == {"/imu/data": [], "/gps/fix": ["gps"]}

    text = init_config(log)
    assert 'imu = ""' in text
    assert 'gps = "/gps/fix"' in text
    comments = " ".join(line.strip().lstrip("#").strip() for line in text.splitlines())
    assert "also /imu/data: sensor_msgs/msg/Imu at 100.0 Hz, frame imu_link: not used" in comments
    assert "role imu cannot read it: the schema has no field `linear_acceleration.x`" in comments
    assert "NOTE: /gps/fix's schema declares `longitude` where the standard" in comments
    assert "problem(s) in this log" not in comments
