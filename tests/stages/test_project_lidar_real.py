"""The real Ouster log (tests/data/real-lidar, derived from ouster-sdk's recording) from
`config init` through pose and project to a Foxglove view, as a user would run it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from click.testing import CliRunner

from toolkit.cli import main
from toolkit.config_init import init_config
from toolkit.mcapio.info import scan_log

LOG = Path(__file__).resolve().parents[1] / "data" / "real-lidar" / "ouster-os1-128.mcap"


def test_the_real_ouster_log_runs_from_config_init_to_a_view(tmp_path: Path) -> None:
    text = init_config(LOG)
    assert 'lidars = ["/ouster/points"]' in text and 'wheels = "/derived/odom"' in text
    assert "pose: yes: an IMU, and wheel speeds" in text
    # 0.3 s of driving (0.7 m) leaves no return near the tyres' paths: keep them all.
    assert 'keep = "near_path"' in text
    config = tmp_path / "ouster.toml"
    config.write_text(text.replace('keep = "near_path"', 'keep = "all"'))
    ws = tmp_path / "ws"
    runner = CliRunner()
    result = runner.invoke(
        main,
        ["run", str(LOG), "-w", str(ws), "-c", str(config), "--to", "project", "--workers", "0"],
    )
    assert result.exit_code == 0, result.output
    # The recording's IMU reads 1.07 g over its first 0.3 s: the start is said to be unsteady.
    assert "the IMU's mean specific force over the first second is 1.07" in result.stderr
    (log_dir,) = (d for d in (ws / "logs").iterdir() if not d.name.startswith("."))
    manifest = json.loads((log_dir / "manifest.json").read_text())
    points = pq.read_table(log_dir / "points.parquet")
    ref = np.load(LOG.with_name("ouster-os1-128.reference.npz"))
    valid = int(np.count_nonzero(ref["range_mm"] > 0))
    # Every valid return is a point or a counted reject (the first sweep's start precedes
    # the first pose: the IMU starts 22 ms after the first cloud).
    rejects = {k: v for k, v in manifest["stages"]["project"]["rejects"].items() if v}
    assert points.num_rows + sum(rejects.values()) == valid
    assert set(rejects) == {"no_pose"} and points.num_rows > 0.8 * valid
    rings = set(points.column("ring").to_pylist())
    assert rings == set(ref["beams_kept"].tolist())
    assert set(points.column("laser").to_pylist()) == {f"/ouster/points ring {r}" for r in rings}

    view = tmp_path / "view.mcap"
    result = runner.invoke(main, ["viz", "-w", str(ws), "--log", log_dir.name, "--out", str(view)])
    assert result.exit_code == 0, result.output
    topics = {t.topic: t.message_count for t in scan_log(view).topics}
    assert topics["/points"] >= 1 and topics["/tf"] >= 1


def test_near_path_on_a_drive_too_short_for_it_says_the_cloud_is_empty(tmp_path: Path) -> None:
    config = tmp_path / "ouster.toml"
    config.write_text(init_config(LOG))
    result = CliRunner().invoke(
        main,
        ["run", str(LOG), "-w", str(tmp_path / "ws"), "-c", str(config), "--to", "project",
         "--workers", "0"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "none of the 16688 projected returns lies near the tyres' paths" in result.stderr
