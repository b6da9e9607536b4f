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
from mcap.reader import make_reader

from toolkit.mcapio.cdr import decode_batch
from toolkit.sim.profiles import make_profile
from toolkit.sim.simulate import simulate

from .logdata import label_log, load_log

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_logs" / "sample.mcap"


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


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
        a, b = decode_batch(name, payloads), decode_batch(name, other_payloads)
        assert a.keys() == b.keys()
        for key in a:
            x, y = np.asarray(a[key]), np.asarray(b[key])
            if x.dtype.kind == "f":
                # A few ulp of what they are computed from: lat/lon come from Earth-centred
                # coordinates (6.4e6 m, 1e-9 m per ulp), so altitude may move by nanometres.
                np.testing.assert_allclose(x, y, rtol=1e-13, atol=1e-8, err_msg=f"{topic} {key}")
            else:
                np.testing.assert_array_equal(x, y, err_msg=f"{topic} {key}")
    assert differing, "the bytes differ but no message does"


def test_sample_is_a_minute_small_and_has_rough_events() -> None:
    """About 60 s, at most 15 MB, and at least 10 events of 0.02 G/mph or more."""
    assert SAMPLE.stat().st_size <= 15 * 1024 * 1024
    log = load_log(SAMPLE)
    ev = label_log(log, make_profile("sample").sensors.imu.rate_hz)
    duration_s = (log.truth.t_ns[-1] - log.truth.t_ns[0]) * 1e-9
    assert 50.0 <= duration_s <= 70.0
    assert int(ev.positive.sum()) >= 10
