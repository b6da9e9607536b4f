"""IMU samples no sensor produces are found: beyond the full scale, and gyro spikes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from toolkit.config import ImuConfig
from toolkit.ingestion import imucheck
from toolkit.ingestion.imucheck import beyond_range, gyro_spikes, stream_imu_check

CFG = ImuConfig()
RATE_HZ = 100.0


def _stream(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A clean 100 Hz stream: a body rocking at up to 40 rad/s^2 (well inside the 100
    allowed), with gyro noise, and gravity on the accelerometer."""
    rng = np.random.default_rng(seed)
    t_ns = np.round(np.arange(n) * 1e9 / RATE_HZ).astype(np.int64)
    t = t_ns * 1e-9
    omega = 2 * np.pi * 1.5  # 1.5 Hz rocking of amplitude 4 rad/s: peak 38 rad/s^2
    gyro = np.column_stack([4 * np.sin(omega * t), 0.5 * np.cos(omega * t), 0.1 * t / t[-1]])
    gyro += rng.normal(0.0, 0.01, gyro.shape)
    accel = np.tile([0.0, 0.0, 9.81], (n, 1)) + rng.normal(0.0, 0.5, (n, 3))
    return t_ns, gyro, accel


def test_a_clean_fast_stream_has_nothing_flagged() -> None:
    t_ns, gyro, accel = _stream(3000)
    assert not beyond_range(gyro, accel, CFG).any()
    assert not gyro_spikes(t_ns, gyro, CFG.max_angular_accel_radps2, slice(None)).any()


@pytest.mark.parametrize("value", [4.0, -8.0, 30.0])
def test_one_spike_within_range_is_flagged_alone(value: float) -> None:
    t_ns, gyro, _ = _stream(500)
    gyro[250, 0] += value
    flagged = gyro_spikes(t_ns, gyro, CFG.max_angular_accel_radps2, slice(None))
    assert np.flatnonzero(flagged).tolist() == [250]


def test_two_spikes_in_a_row_are_both_flagged_and_at_the_ends_too() -> None:
    t_ns, gyro, _ = _stream(500)
    gyro[[100, 101], 1] = 20.0
    gyro[0, 2] = -10.0
    gyro[-1, 2] = 10.0
    flagged = gyro_spikes(t_ns, gyro, CFG.max_angular_accel_radps2, slice(None))
    assert np.flatnonzero(flagged).tolist() == [0, 100, 101, 499]


def test_across_a_gap_the_allowance_grows_with_the_time() -> None:
    """After a 1 s outage the rate may have changed by up to 100 rad/s: a new level there is
    the body's motion during the gap, not a spike."""
    t_ns, gyro, _ = _stream(400)
    t_ns[200:] += 1_000_000_000
    gyro[200:, 0] += 5.0
    assert not gyro_spikes(t_ns, gyro, CFG.max_angular_accel_radps2, slice(None)).any()


def test_beyond_the_full_scale_on_any_axis() -> None:
    t_ns, gyro, accel = _stream(100)
    gyro[10, 2] = 35.0  # over 2000 deg/s
    accel[20, 0] = -160.0  # over 16 g
    accel[30, 1] = 150.0  # within
    assert np.flatnonzero(beyond_range(gyro, accel, CFG)).tolist() == [10, 20]
    wide = ImuConfig(gyro_range_radps=70.0, accel_range_mps2=400.0)
    assert not beyond_range(gyro, accel, wide).any()


def _write(path: Path, t_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray, rg: int) -> Path:
    cols = {"t_ns": t_ns}
    cols.update({name: gyro[:, i] for i, name in enumerate(imucheck.GYRO)})
    cols.update({name: accel[:, i] for i, name in enumerate(imucheck.ACCEL)})
    pq.write_table(pa.table(cols), path, row_group_size=rg)
    return path


@pytest.mark.parametrize("piece_rows", [1, 3, 7, 64])
def test_streamed_in_pieces_as_judged_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, piece_rows: int
) -> None:
    t_ns, gyro, accel = _stream(300, seed=3)
    for i, v in [(0, 9.0), (6, -9.0), (7, 9.0), (150, 5.0), (298, 12.0), (299, -7.0)]:
        gyro[i, i % 3] += v
    accel[40, 2] = 500.0
    gyro[41, 0] = 100.0
    path = _write(tmp_path / "imu.parquet", t_ns, gyro, accel, piece_rows)
    monkeypatch.setattr(imucheck, "ROW_GROUP_ROWS", piece_rows)
    verdict = stream_imu_check(path, CFG)
    assert verdict is not None
    assert np.flatnonzero(verdict.beyond_range).tolist() == [40, 41]
    # Whole: the beyond-range samples are no one's neighbours, as when streamed.
    masked = np.where(verdict.beyond_range[:, None], np.nan, gyro)
    whole = gyro_spikes(t_ns, masked, CFG.max_angular_accel_radps2, slice(None))
    assert np.array_equal(verdict.spike, whole & ~verdict.beyond_range)
    assert np.flatnonzero(verdict.spike).tolist() == [0, 6, 7, 150, 298, 299]


def test_a_clean_table_gives_no_verdict(tmp_path: Path) -> None:
    path = _write(tmp_path / "imu.parquet", *_stream(1000), rg=100)
    assert stream_imu_check(path, CFG) is None
