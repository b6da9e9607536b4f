"""The bundled sample log is what its README's command writes.

Bit for bit on the project machine. Elsewhere the last bits of a few floating-point values
may differ: numpy's transcendental functions (the GPS fix's geodetic conversion uses
``arctan2``, ``sin``, ``cos``) are not correctly rounded and change between numpy builds and
CPUs. So when the bytes differ, the logs must still hold the same records in the same order
with the same times and sizes, every integer, string and boolean field equal, and every
float within a few units in the last place of what it is computed from.
``tests/sim/test_determinism.py`` checks bit-for-bit determinism on one machine."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from toolkit.mcapio.cdr import decode_batch
from toolkit.sim.profiles import make_profile
from toolkit.sim.simulate import simulate

from .logdata import label_log, load_log

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_logs" / "sample.mcap"


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.slow  # simulates the whole sample (23 s): run by .ci/run
def test_readme_command_regenerates_the_sample_bit_for_bit(tmp_path: Path) -> None:
    readme = (REPO / "sample_logs" / "README.md").read_text()
    match = re.search(
        r"terrain sim sample_logs/sample\.mcap --profile (\w+) --seed (\d+) --overwrite", readme
    )
    assert match is not None, "sample_logs/README.md lost its regeneration command"
    profile, seed = match.group(1), int(match.group(2))
    out = tmp_path / "sample.mcap"
    simulate(out, profile=profile, seed=seed)
    if _sha256(out) != _sha256(SAMPLE):
        _assert_same_up_to_float_rounding(out, SAMPLE)


def _messages(path: Path) -> dict[str, tuple[str, list[tuple[int, int]], list[bytes]]]:
    """topic -> (schema name, [(log_time, publish_time)], payloads) in file order."""
    out: dict[str, tuple[str, list[tuple[int, int]], list[bytes]]] = {}
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            name = schema.name if schema is not None else ""
            entry = out.setdefault(channel.topic, (name, [], []))
            entry[1].append((message.log_time, message.publish_time))
            entry[2].append(message.data)
    return out


# How far a regenerated value may be from the bundled one, by the dtype the message stores.
# float64: an ulp of difference in a transcendental function (1e-16 relative) is carried along,
# damped, by the simulator's integration over the whole drive. Measured with numpy's AVX-512
# and AVX2 paths switched off (NPY_DISABLE_CPU_FEATURES, as on a CPU without them): at most
# 2.3e-10 m/s^2 on the IMU, 1.5e-11 on the truth's rates, 1.9e-9 m on the GPS altitude (it
# comes from Earth-centred coordinates, 6.4e6 m, where an ulp is 1e-9 m). 1e-8 absolute plus
# 1e-9 relative is above all of it and a thousand times below the simulator's smallest sensor
# noise. float32 (laser ranges, intensities): computed in float64 and rounded to float32 once,
# so two float32 ulps (a rounding that lands on the other side).
FLOAT_TOLERANCE = {
    np.dtype(np.float64): {"rtol": 1e-9, "atol": 1e-8},
    np.dtype(np.float32): {"rtol": float(2 * np.finfo(np.float32).eps), "atol": 1e-6},
}


def assert_decoded_close(mine: object, theirs: object, where: str) -> None:
    """Assert two decoded values equal, field by field, floats within FLOAT_TOLERANCE.

    ``decode_batch`` gives numpy arrays, and for sequences of messages (a TFMessage's
    transforms, a RoughFeatureArray's features) object arrays of dicts of arrays: each level is
    compared by what it is, and a failure names the path to the field that differs.
    """
    if isinstance(mine, dict):
        assert isinstance(theirs, dict), where
        assert mine.keys() == theirs.keys(), f"{where}: fields {sorted(mine)} vs {sorted(theirs)}"
        for key in mine:
            assert_decoded_close(mine[key], theirs[key], f"{where}.{key}")
        return
    x, y = np.asarray(mine), np.asarray(theirs)
    assert x.shape == y.shape, f"{where}: shape {x.shape} vs {y.shape}"
    assert x.dtype == y.dtype, f"{where}: dtype {x.dtype} vs {y.dtype}"
    if x.dtype.kind == "O":
        for i, (a, b) in enumerate(zip(x.ravel(), y.ravel(), strict=True)):
            assert_decoded_close(a, b, f"{where}[{i}]")
    elif x.dtype.kind == "f":
        tolerance = FLOAT_TOLERANCE[x.dtype]
        np.testing.assert_allclose(x, y, **tolerance, equal_nan=True, err_msg=where)
    else:
        np.testing.assert_array_equal(x, y, err_msg=where)


def _assert_same_up_to_float_rounding(ours: Path, bundled: Path) -> None:
    mine, theirs = _messages(ours), _messages(bundled)
    assert mine.keys() == theirs.keys()
    differing = []
    for topic, (name, times, payloads) in mine.items():
        other_name, other_times, other_payloads = theirs[topic]
        assert (name, times) == (other_name, other_times), topic
        assert [len(p) for p in payloads] == [len(p) for p in other_payloads], topic
        if payloads == other_payloads:
            continue
        differing.append(topic)
        assert_decoded_close(
            decode_batch(name, payloads), decode_batch(name, other_payloads), topic
        )
    assert differing, "the bytes differ but no message does"


def test_decoded_values_compare_through_nested_messages() -> None:
    """The fallback comparison reaches into sequences of messages and names what differs."""
    feature = {"kind": np.array(["rock"]), "height_m": np.array([0.1])}
    nested = {"features": np.array([feature], dtype=object), "t": np.array([1], np.int32)}
    near = {"height_m": np.array([0.1 + 1e-15]), "kind": np.array(["rock"])}
    assert_decoded_close(nested, {**nested, "features": np.array([near], dtype=object)}, "x")
    far = {"height_m": np.array([0.1001]), "kind": np.array(["rock"])}
    with pytest.raises(AssertionError, match=r"x\.features\[0\]\.height_m"):
        assert_decoded_close(nested, {**nested, "features": np.array([far], dtype=object)}, "x")
    ranges = np.array([10.0], np.float32)
    assert_decoded_close(ranges, np.nextafter(ranges, np.float32(11.0)), "r")
    with pytest.raises(AssertionError):
        assert_decoded_close(ranges, ranges + np.float32(0.001), "r")


def test_sample_is_a_minute_small_and_has_rough_events() -> None:
    """About 60 s, at most 15 MB, and at least 10 events of 0.02 G/mph or more."""
    assert SAMPLE.stat().st_size <= 15 * 1024 * 1024
    log = load_log(SAMPLE)
    ev = label_log(log, make_profile("sample").sensors.imu.rate_hz)
    duration_s = (log.truth.t_ns[-1] - log.truth.t_ns[0]) * 1e-9
    assert 50.0 <= duration_s <= 70.0
    assert int(ev.positive.sum()) >= 10
