"""Same seed, same log; another seed, another world and another log."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from tests.sim.logdata import load_log
from toolkit.errors import SimulationError
from toolkit.sim.profiles import make_profile
from toolkit.sim.simulate import simulate
from toolkit.sim.world import make_world

DISTANCE_M = 150.0
SEED_A = 3
SEED_B = 4


def messages(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    """A log's messages by topic: (log time, bytes) in the order written."""
    out: dict[str, list[tuple[int, bytes]]] = {}
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            out.setdefault(channel.topic, []).append((message.log_time, message.data))
    return out


@pytest.fixture(scope="module")
def short_logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("determinism")
    runs = {"a1": (SEED_A, None), "a2": (SEED_A, None), "b": (SEED_B, None), "a0": (SEED_A, 0)}
    return {
        name: simulate(
            d / f"{name}.mcap", profile="sample", distance_m=DISTANCE_M, seed=seed, workers=workers
        ).path
        for name, (seed, workers) in runs.items()
    }


def test_same_seed_gives_byte_identical_log(short_logs: dict[str, Path]) -> None:
    a1 = short_logs["a1"].read_bytes()
    a2 = short_logs["a2"].read_bytes()
    assert len(a1) > 100_000
    assert a1 == a2


def test_log_does_not_depend_on_laser_workers(short_logs: dict[str, Path]) -> None:
    """Casting the lasers in the main process (workers=0) or in worker processes (the
    default on a multi-core machine) writes the same bytes."""
    assert short_logs["a0"].read_bytes() == short_logs["a1"].read_bytes()


def test_a_log_without_lasers_is_the_same_log_less_its_scans(
    short_logs: dict[str, Path], tmp_path: Path
) -> None:
    """``--no-lasers`` (for tuning the vehicle fast) drives the same drive with the same
    noise on every other sensor: the lasers draw only from a generator of their own."""
    bare = simulate(
        tmp_path / "bare.mcap", profile="sample", distance_m=DISTANCE_M, seed=SEED_A, lasers=False
    ).path

    full, without = messages(short_logs["a1"]), messages(bare)
    lasers = {t for t in full if t.startswith("/laser/")}
    assert lasers and not lasers & set(without)
    # The static transforms and the simulator's metadata name the lasers either way.
    assert set(full) - lasers == set(without)
    for topic, rows in without.items():
        assert rows == full[topic], topic


def test_laser_spans_scan_only_there_and_change_no_other_sensor(
    short_logs: dict[str, Path], tmp_path: Path
) -> None:
    """``laser_spans_m`` (a long drive judged at a few places) scans inside its spans only,
    by the metres driven, and every other sensor is the drive scanned all the way."""
    spans = ((10.0, 25.0), (40.0, 52.0))  # of the 59 m this log drives
    part = simulate(
        tmp_path / "part.mcap",
        profile="sample",
        distance_m=DISTANCE_M,
        seed=SEED_A,
        laser_spans_m=spans,
    ).path

    full, scanned = messages(short_logs["a1"]), messages(part)
    for topic, rows in full.items():
        if not topic.startswith("/laser/"):
            assert scanned[topic] == rows, topic
    # Metres driven at each time, from the true positions; a scan is logged within a block
    # (0.1 s, under 1 m) of a span.
    truth = load_log(part).truth
    t_ns, xy = truth.t_ns, truth.position[:, :2]
    driven = np.r_[0.0, np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]
    for topic in (t for t in scanned if t.startswith("/laser/")):
        at_m = np.interp(np.asarray([t for t, _ in scanned[topic]]), t_ns, driven)
        inside = np.zeros(at_m.size, bool)
        for a, b in spans:
            inside |= (at_m >= a - 2.0) & (at_m <= b + 2.0)
        assert inside.all(), topic
        for a, b in spans:  # and they scan throughout each span
            assert ((at_m > a + 2.0) & (at_m < a + 5.0)).any(), (topic, a)
            assert ((at_m > b - 5.0) & (at_m < b - 2.0)).any(), (topic, b)
    with pytest.raises(SimulationError, match="laser spans"):
        simulate(tmp_path / "bad.mcap", profile="sample", laser_spans_m=((5.0, 1.0),))


def test_other_seed_gives_other_log(short_logs: dict[str, Path]) -> None:
    assert short_logs["a1"].read_bytes() != short_logs["b"].read_bytes()


def test_same_seed_same_world_other_seed_other_world() -> None:
    params = make_profile("sample", DISTANCE_M).world
    a1, a2, b = make_world(params, SEED_A), make_world(params, SEED_A), make_world(params, SEED_B)

    s = np.linspace(20.0, DISTANCE_M - 20.0, 400)
    d = np.linspace(-3.0, 3.0, 400)
    ha1, ha2, hb = (w.terrain.height(s, d) for w in (a1, a2, b))

    # Same seed: the same route, features and heights, bit for bit.
    np.testing.assert_array_equal(a1.route.x_m, a2.route.x_m)
    np.testing.assert_array_equal(a1.route.y_m, a2.route.y_m)
    np.testing.assert_array_equal(a1.route.z0_m, a2.route.z0_m)
    assert a1.features == a2.features
    np.testing.assert_array_equal(ha1, ha2)

    # Another seed: another route, other features, other terrain.
    n = min(a1.route.s_m.size, b.route.s_m.size)
    gap = np.hypot(a1.route.x_m[:n] - b.route.x_m[:n], a1.route.y_m[:n] - b.route.y_m[:n])
    assert gap.max() > 10.0
    assert np.max(np.abs(a1.route.z0_m[:n] - b.route.z0_m[:n])) > 0.1
    assert a1.features != b.features
    assert {f.s_start_m for f in a1.features}.isdisjoint({f.s_start_m for f in b.features})
    # Heights relative to the route's own elevation, so only the roughness is compared.
    rel_a = ha1 - np.interp(s, a1.route.s_m, a1.route.z0_m)
    rel_b = hb - np.interp(s, b.route.s_m, b.route.z0_m)
    assert np.mean(np.abs(rel_a - rel_b) > 1e-3) > 0.9
