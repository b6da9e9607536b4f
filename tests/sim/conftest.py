"""Session fixtures: each log the simulator tests need is simulated once.

Simulation is the slow part (about 10 s for the sample log, 15-20 s for the calibration log
and 40 s for the race log on one core), so every log is written once per session into a
temporary directory and decoded once; the tests share the decoded columns.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from toolkit.sim.simulate import SimResult, simulate

from .logdata import SimLog, load_log

SAMPLE_SEED = 1
CALIBRATION_SEED = 1
RACE_SEED = 1
# The race profile's default route (8000 m, about 5700 events of 1.4 m): the rough-event
# fraction of a shorter log swings too much with the few severe features it happens to hold.
RACE_DISTANCE_M = 8000.0


@pytest.fixture(scope="session")
def sim_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("sim")


@pytest.fixture(scope="session")
def sample_result(sim_dir: Path) -> SimResult:
    return simulate(sim_dir / "sample.mcap", profile="sample", seed=SAMPLE_SEED)


@pytest.fixture(scope="session")
def sample_log(sample_result: SimResult) -> SimLog:
    return load_log(sample_result.path)


@pytest.fixture(scope="session")
def calibration_result(sim_dir: Path) -> SimResult:
    return simulate(sim_dir / "calibration.mcap", profile="calibration", seed=CALIBRATION_SEED)


@pytest.fixture(scope="session")
def calibration_log(calibration_result: SimResult) -> SimLog:
    return load_log(calibration_result.path)


@pytest.fixture(scope="session")
def race_result(sim_dir: Path) -> SimResult:
    # Without its lasers: the race log's tests read its IMU, GPS, truth and labels, never its
    # scans, and a log without lasers is the same drive with the same noise on every other
    # sensor (test_determinism); casting 8 km of rays was most of this fixture's 2 minutes.
    return simulate(
        sim_dir / "race.mcap",
        profile="race",
        distance_m=RACE_DISTANCE_M,
        seed=RACE_SEED,
        lasers=False,
    )


@pytest.fixture(scope="session")
def race_log(race_result: SimResult) -> SimLog:
    return load_log(race_result.path)
