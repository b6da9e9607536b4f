"""The ``race`` profile's rough events (paper, Sect. 5 and 7; issue 11).

By the label stage itself (ingest, pose, label, with its 40-tap filter): about 0.3-0.6 % of
1.4 m events reach 0.02 G/mph, a share that moves by less than a factor of three as the
filter's band edge moves from 9 to 11 Hz, and the positives come from several kinds of
feature and from the background roughness, and event shocks range from about 0.02 G to
0.6 G. By the reference labeller: the event count. The race seed here (1) is not one of those the
simulator was tuned on (601-606, ``benchmarks/sim_seeds.py``).
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from toolkit.config import default_config
from toolkit.sim.profiles import make_profile
from toolkit.sim.simulate import SimResult
from toolkit.stages.ingest import ingest_log
from toolkit.stages.label import SPEC as LABEL
from toolkit.stages.pose import SPEC as POSE
from toolkit.stages.runner import run_stage
from toolkit.tableio import read_table
from toolkit.workspace import Workspace

from .logdata import SimLog, label_log
from .reference_labeller import Events

# The race simulated, ingested, posed and labelled three times: run by .ci/run, left out of
# the README's command.
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def events(race_log: SimLog) -> Events:
    ev = label_log(race_log, make_profile("race").sensors.imu.rate_hz)
    pos = ev.positive
    p1, p50, p99 = np.percentile(ev.shock_g, [1, 50, 99])
    print(
        f"\nrace: {len(ev)} events, {pos.sum()} positive ({pos.mean():.3%}); shock G: "
        f"p1 {p1:.4f}, median {p50:.4f}, p99 {p99:.4f}, max {ev.shock_g.max():.4f}; "
        f"speed {ev.speed_mph.min():.1f}-{ev.speed_mph.max():.1f} mph; top ruggedness "
        f"{np.round(np.sort(ev.ruggedness)[-12:], 4).tolist()}"
    )
    return ev


def test_race_has_enough_events(events: Events, race_log: SimLog) -> None:
    travelled = float(race_log.truth.path_length[-1])
    assert len(events) == pytest.approx(travelled / 1.4, abs=3)
    assert len(events) > 2000


@dataclasses.dataclass(frozen=True)
class StageLabels:
    """The label stage's events on the race log: their count, every event's ``shock_g`` at
    the default filter, and the rough events' truth kinds ("background" where no feature
    lies under a rear tyre) by the filter's stop edge (Hz)."""

    events: int
    shock_g: np.ndarray
    rough_kinds: dict[float, list[str]]


@pytest.fixture(scope="module")
def stage_labels(race_result: SimResult, tmp_path_factory: pytest.TempPathFactory) -> StageLabels:
    """Ingest, pose and label the race log; label it again with the filter's stop edge at 9
    and 11 Hz (pass edge 5 Hz above), the default being 10 Hz."""
    cfg = default_config()
    ws = Workspace(tmp_path_factory.mktemp("race_ws") / "ws")
    log_id = ingest_log(Path(race_result.path), ws, cfg).log_id
    run_stage(POSE, ws, cfg, log_id=log_id)
    kinds: dict[float, list[str]] = {}
    for stop in (9.0, 11.0, cfg.label.fir_stop_hz):
        label = dataclasses.replace(cfg.label, fir_stop_hz=stop, fir_pass_hz=stop + 5.0)
        run_stage(LABEL, ws, dataclasses.replace(cfg, label=label), log_id=log_id, overwrite=True)
        events = read_table(ws.log_dir(log_id) / "events.parquet", "events")
        rough = events.filter(events.column("rough")).column("truth_feature_kind").to_pylist()
        kinds[stop] = [kind or "background" for kind in rough]
    out = StageLabels(events.num_rows, events.column("shock_g").to_numpy(), kinds)
    print(
        f"\nlabel stage on the race log: {out.events} events; rough at stop edge "
        + ", ".join(f"{k:g} Hz {len(v)} {dict(Counter(v))}" for k, v in kinds.items())
    )
    return out


def test_race_positive_fraction(stage_labels: StageLabels) -> None:
    """About 0.3-0.6 % of events reach 0.02 G/mph (the paper: 0.36 % and 0.44 %)."""
    rough = stage_labels.rough_kinds[default_config().label.fir_stop_hz]
    fraction = len(rough) / stage_labels.events
    assert 0.003 <= fraction <= 0.006, f"{fraction:.3%} of {stage_labels.events} events"


def test_race_positive_fraction_holds_as_the_band_edge_moves(stage_labels: StageLabels) -> None:
    """From a 9 Hz to an 11 Hz stop edge the positives change by less than a factor of 3."""
    at_9, at_11 = len(stage_labels.rough_kinds[9.0]), len(stage_labels.rough_kinds[11.0])
    assert at_11 > 0 and at_9 / at_11 < 3.0, (at_9, at_11)


def test_race_positives_come_from_features_and_background(stage_labels: StageLabels) -> None:
    kinds = Counter(stage_labels.rough_kinds[default_config().label.fir_stop_hz])
    assert kinds["background"] > 0, kinds
    assert len(set(kinds) - {"background"}) >= 3, kinds


def test_race_shock_span(stage_labels: StageLabels) -> None:
    """Event shocks (the label stage's) range, as Sect. 7's do, from about 0.02 G
    (negligible) to 0.5-0.6 G (severe). Sect. 7 gives the range's ends, so the smallest and
    the largest event are checked: the quietest event is the IMU's noise through the filter
    (0.018 G here; it fails if that floor rises above 0.03 G), the largest a hard hit."""
    low = float(stage_labels.shock_g.min())
    top = float(stage_labels.shock_g.max())
    print(f"\nshock: min {low:.4f} G, median {np.median(stage_labels.shock_g):.4f}, max {top:.4f}")
    assert low <= 0.03
    assert 0.3 <= top <= 1.0
