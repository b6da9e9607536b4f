"""One sensor seam: a toy role declared as README's "Adding a sensor" says (a converter, a
``RoleSpec`` line, its ``[topics]`` key) is picked up by every reader of roles: the
configuration's loader, ``terrain info``, ``config init`` and ingest, with no other change.

The toy is a barometer publishing ``sensor_msgs/msg/FluidPressure``, a type the toolkit has
no definition of: the log's own schema decodes it."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from mcap_ros2.writer import Writer

from toolkit.cli import main
from toolkit.config import PipelineConfig, load_config, sections
from toolkit.config_init import init_config
from toolkit.ingestion.roles import ROLE_SPECS, RoleSpec
from toolkit.ingestion.rows import Columns, ConvertContext, RoleRows, all_finite, f64, stamp_times
from toolkit.stages.ingest import ingest_log
from toolkit.workspace import Workspace

SEPARATOR = "=" * 80
#: The definitions every stamped message's schema ends with (ros2msg: dependencies after
#: a line of 80 "=").
HEADER = [
    SEPARATOR,
    "MSG: std_msgs/Header",
    "builtin_interfaces/Time stamp",
    "string frame_id",
    SEPARATOR,
    "MSG: builtin_interfaces/Time",
    "int32 sec",
    "uint32 nanosec",
]
FLUID_PRESSURE = "\n".join(
    ["std_msgs/Header header", "float64 fluid_pressure", "float64 variance", *HEADER]
)
IMU = "\n".join(
    [
        "std_msgs/Header header",
        "geometry_msgs/Quaternion orientation",
        "float64[9] orientation_covariance",
        "geometry_msgs/Vector3 angular_velocity",
        "float64[9] angular_velocity_covariance",
        "geometry_msgs/Vector3 linear_acceleration",
        "float64[9] linear_acceleration_covariance",
        *HEADER,
        SEPARATOR,
        "MSG: geometry_msgs/Quaternion",
        "float64 x",
        "float64 y",
        "float64 z",
        "float64 w",
        SEPARATOR,
        "MSG: geometry_msgs/Vector3",
        "float64 x",
        "float64 y",
        "float64 z",
    ]
)
T0_NS = 1_700_000_000 * 10**9


def barometer_from_fluid_pressure(
    cols: Columns, log_time_ns: np.ndarray, ctx: ConvertContext
) -> RoleRows:
    """The toy converter: sensor_msgs/FluidPressure -> t_ns, pressure_pa."""
    t_ns, missing = stamp_times(cols, log_time_ns, ctx)
    pressure = f64(cols, "fluid_pressure")
    return RoleRows(
        pa.table({"t_ns": t_ns, "pressure_pa": pressure}), all_finite(pressure), missing
    )


@pytest.fixture
def toy_role(monkeypatch: pytest.MonkeyPatch) -> type:
    """Declare the barometer: its RoleSpec line and its [topics] field."""
    topics = dataclasses.make_dataclass(
        "TopicsConfig",
        [("barometer", str | None, dataclasses.field(default=None))],
        bases=(sections.TopicsConfig,),
        frozen=True,
    )
    monkeypatch.setattr(sections, "TopicsConfig", topics)
    spec = RoleSpec(
        "barometer",
        "barometer",
        {"sensor_msgs/msg/FluidPressure": barometer_from_fluid_pressure},
        "barometer",
        written="present",
    )
    monkeypatch.setitem(ROLE_SPECS, "barometer", spec)
    return topics


def write_log(path: Path) -> Path:
    """Two seconds of a 10 Hz barometer and a 100 Hz IMU, schemas from the log itself."""
    with path.open("wb") as f:
        writer = Writer(f)
        baro = writer.register_msgdef("sensor_msgs/FluidPressure", FLUID_PRESSURE)
        imu = writer.register_msgdef("sensor_msgs/Imu", IMU)
        for i in range(200):
            t = T0_NS + i * 10_000_000
            stamp = {"sec": t // 10**9, "nanosec": t % 10**9}
            writer.write_message(
                "/imu/data",
                imu,
                {
                    "header": {"stamp": stamp, "frame_id": "imu_link"},
                    "orientation_covariance": [-1.0] + [0.0] * 8,
                    "linear_acceleration": {"x": 0.0, "y": 0.0, "z": 9.81},
                },
                t,
                t,
            )
            if i % 10 == 0:
                msg = {
                    "header": {"stamp": stamp, "frame_id": "baro_link"},
                    "fluid_pressure": 101_325.0 - i,
                    "variance": 4.0,
                }
                writer.write_message("/baro/pressure", baro, msg, t, t)
        writer.finish()
    return path


def test_every_reader_picks_up_a_toy_role(tmp_path: Path, toy_role: type) -> None:
    log = write_log(tmp_path / "baro.mcap")

    # terrain info: the topic can be a barometer.
    result = CliRunner().invoke(main, ["info", str(log)])
    assert result.exit_code == 0, result.output
    (row,) = [ln for ln in result.stdout.splitlines() if ln.startswith("/baro/pressure")]
    assert row.split()[-1] == "barometer"

    # config init: finds it, says so in the role lines, writes its key; the file loads.
    text = init_config(log)
    assert "# roles found: imu, barometer" in text
    assert 'barometer = "/baro/pressure"' in text
    path = tmp_path / "baro.toml"
    path.write_text(text)
    cfg: PipelineConfig = load_config(path)
    assert isinstance(cfg.topics, toy_role)
    assert cfg.topics.by_role()["barometer"] == ("/baro/pressure",)

    # ingest: its table, every message accounted for.
    ingested = ingest_log(log, Workspace(tmp_path / "ws"), cfg)
    log_dir = tmp_path / "ws" / "logs" / ingested.log_id
    table = pq.read_table(log_dir / "barometer.parquet")
    assert table.num_rows == 20
    np.testing.assert_array_equal(
        table.column("pressure_pa").to_numpy(), 101_325.0 - np.arange(0, 200, 10)
    )
    account = json.loads((log_dir / "manifest.json").read_text())["ingest"]["topics"][
        "/baro/pressure"
    ]
    assert (account["role"], account["read"], account["written"]) == ("barometer", 20, 20)

    # Without its declaration the same log has no barometer: the role came from the seam.
    ROLE_SPECS.pop("barometer")
    assert "barometer" not in init_config(log)
