"""The bundled sample log is what its README's command writes, bit for bit."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

from toolkit.sim.profiles import make_profile
from toolkit.sim.simulate import simulate

from .logdata import label_log, load_log

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "sample_logs" / "sample.mcap"


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_readme_command_regenerates_the_sample_bit_for_bit(tmp_path: Path) -> None:
    readme = (REPO / "sample_logs" / "README.md").read_text()
    match = re.search(r"terrain sim sample_logs/sample\.mcap --profile (\w+) --seed (\d+)", readme)
    assert match is not None, "sample_logs/README.md lost its regeneration command"
    profile, seed = match.group(1), int(match.group(2))
    out = tmp_path / "sample.mcap"
    simulate(out, profile=profile, seed=seed)
    assert _sha256(out) == _sha256(SAMPLE)


def test_sample_is_a_minute_small_and_has_rough_events() -> None:
    """About 60 s, at most 15 MB, and at least 10 events of 0.02 G/mph or more."""
    assert SAMPLE.stat().st_size <= 15 * 1024 * 1024
    log = load_log(SAMPLE)
    ev = label_log(log, make_profile("sample").sensors.imu.rate_hz)
    duration_s = (log.truth.t_ns[-1] - log.truth.t_ns[0]) * 1e-9
    assert 50.0 <= duration_s <= 70.0
    assert int(ev.positive.sum()) >= 10
