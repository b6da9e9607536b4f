"""A topic's conversion context: the configured clock correction and its full type name."""

from __future__ import annotations

import dataclasses

from toolkit.config import default_config
from toolkit.ingestion.rows import ConvertContext


def test_context_takes_the_configured_correction() -> None:
    cfg = default_config()
    time = dataclasses.replace(
        cfg.time,
        latency_ns=dataclasses.replace(cfg.time.latency_ns, imu=3_000_000),
        clock_offset_ns=dataclasses.replace(cfg.time.clock_offset_ns, imu=1_000_000),
    )
    ctx = ConvertContext.for_topic("/imu", "imu", "sensor_msgs/Imu", time)
    assert ctx.correction_ns == 1_000_000 - 3_000_000
    assert ctx.type_name == "sensor_msgs/msg/Imu"
