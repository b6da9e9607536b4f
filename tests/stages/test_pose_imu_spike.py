"""One corrupt IMU sample does not turn the pose: ingest rejects it, says so, and pose runs as
on the clean log (issue "Truth far from home", point 2)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from mcap_ros2.decoder import DecoderFactory

from tests.conftest import SAMPLE_LOG
from toolkit.config import default_config
from toolkit.stages.ingest import ingest_log
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.runner import run_stage
from toolkit.tableio import read_table
from toolkit.workspace import Workspace

IMU_TOPIC = "/imu/data"
SPIKED = 3000  # the 3,000th IMU message, 30 s in, while the vehicle drives


def spiked_copy(src: Path, dst: Path, index: int, gyro_x_radps: float) -> Path:
    """``src`` rewritten message by message, the ``index``-th IMU message's angular
    velocity x replaced (its CDR bytes patched in place: the same layout and length)."""
    decoders = DecoderFactory()
    with src.open("rb") as f, dst.open("wb") as out:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        writer = Writer(out, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="test")
        schema_ids = {
            sid: writer.register_schema(s.name, s.encoding, s.data)
            for sid, s in summary.schemas.items()
        }
        channel_ids = {
            cid: writer.register_channel(
                c.topic, c.message_encoding, schema_ids[c.schema_id], c.metadata
            )
            for cid, c in summary.channels.items()
        }
        n = 0
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            data = message.data
            if channel.topic == IMU_TOPIC:
                if n == index:
                    assert schema is not None
                    decoded = decoders.decoder_for(channel.message_encoding, schema)(data)
                    old = struct.pack("<d", decoded.angular_velocity.x)
                    assert data.count(old) == 1
                    data = data.replace(old, struct.pack("<d", gyro_x_radps))
                n += 1
            writer.add_message(
                channel_ids[channel.id],
                message.log_time,
                data,
                message.publish_time,
                message.sequence,
            )
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        writer.finish()
    return dst


@pytest.mark.parametrize(
    ("gyro_x_radps", "reason"), [(100.0, "imu_beyond_range"), (20.0, "imu_spike")]
)
def test_one_spiked_gyro_sample_is_rejected_and_the_pose_stays_as_clean(
    tmp_path: Path,
    sample_projected: tuple[Path, str],
    gyro_x_radps: float,
    reason: str,
) -> None:
    """Before: 100 rad/s once turned the roll by 59 deg, exit 0. Now the sample is dropped,
    counted and said, and roll and pitch stay within 1 deg of the clean log's pose."""
    log = spiked_copy(SAMPLE_LOG, tmp_path / "spiked.mcap", SPIKED, gyro_x_radps)
    ws = Workspace(tmp_path / "ws")
    result = ingest_log(log, ws, default_config())
    assert result.rejects[IMU_TOPIC] == {reason: 1}
    assert any(IMU_TOPIC in w and "1 IMU samples rejected" in w for w in result.warnings)
    run_stage(POSE, ws, default_config(), log_id=result.log_id)

    clean_root, clean_id = sample_projected
    clean = read_table(Workspace(clean_root).log_dir(clean_id) / "pose.parquet", "pose")
    spiked = read_table(ws.log_dir(result.log_id) / "pose.parquet", "pose")
    assert clean.num_rows == spiked.num_rows
    for angle in ("roll", "pitch"):
        diff = np.abs(clean.column(angle).to_numpy() - spiked.column(angle).to_numpy())
        assert np.degrees(diff.max()) < 1.0, angle
