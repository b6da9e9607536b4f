"""Fixed-point storage: exact to half a step, float64 when read, refusals named."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from toolkit import fixed_point
from toolkit.errors import SchemaError
from toolkit.tableio import iter_table_batches, load_table_schema, read_table, write_table


def test_values_come_back_as_the_nearest_float_to_their_millimetre() -> None:
    rng = np.random.default_rng(3)
    v = np.r_[rng.uniform(-900_000, 900_000, 10_000), 0.0005, -0.0015, 1.2344999]
    back = fixed_point.decode(fixed_point.encode(pa.array(v), 3)).to_numpy()
    np.testing.assert_array_equal(back, np.rint(v * 1000.0) / 1000.0)
    assert np.abs(back - v).max() <= 0.5e-3 + 1e-9


def test_a_slice_decodes_its_own_rows() -> None:
    stored = fixed_point.encode(pa.array([1.0, 2.0, 3.0, 4.0]), 3)
    assert fixed_point.decode(stored.slice(1, 2)).to_pylist() == [2.0, 3.0]


@pytest.mark.parametrize("bad", [np.nan, np.inf, 1.0e6])
def test_a_value_the_column_cannot_hold_is_refused(bad: float) -> None:
    with pytest.raises(fixed_point.FixedPointRangeError, match="cannot be stored"):
        fixed_point.encode(pa.array([0.0, bad]), 3)


def _points(n: int, x: np.ndarray) -> pa.Table:
    schema = load_table_schema("points")
    cols = {c.name: c.arrow_type() for c in schema.columns}
    data = {
        "t_ns": np.arange(n, dtype=np.int64),
        "laser": ["/laser/front_1"] * n,
        "beam": np.zeros(n, np.int32),
        "range": np.ones(n, np.float32),
        "x": x,
        "y": -x,
        "z": np.zeros(n),
        "roll_rate": np.full(n, 0.1234567),
        "pitch_rate": np.zeros(n),
        "scan_t_ns": np.zeros(n, np.int64),
        "scan_dt_s": np.zeros(n),
    }
    return pa.table({k: pa.array(v).cast(cols[k]) for k, v in data.items()})


def test_the_point_cloud_is_stored_fixed_point_and_read_as_float64(tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "points.parquet"
    x = np.linspace(-20_000.0, 20_000.0, 1001)
    write_table(path, _points(x.size, x), "points", source_sha256="0" * 64, config_hash="h")
    table = read_table(path, "points")
    assert table.schema.field("x").type == pa.float64()
    np.testing.assert_array_equal(table["x"].to_numpy(), np.rint(x * 1e3) / 1e3)
    assert table["roll_rate"].to_numpy()[0] == 0.123457  # 1e-6 rad/s
    batches = list(iter_table_batches(path, "points", columns=["x", "y"], batch_rows=100))
    assert all(b.schema.field("y").type == pa.float64() for b in batches)
    np.testing.assert_array_equal(
        np.concatenate([b["y"].to_numpy() for b in batches]), -table["x"].to_numpy()
    )


def test_a_point_beyond_the_fixed_point_is_one_error_naming_the_column(tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "points.parquet"
    with pytest.raises(SchemaError, match="column 'x'.*cannot be stored") as err:
        write_table(
            path,
            _points(2, np.array([0.0, 2e6])),
            "points",
            source_sha256="0" * 64,
            config_hash="h",
        )
    assert "points.parquet" in str(err.value)
    assert not path.exists()
