"""The online stage on the sample: test-then-train replay, stopped and resumed, started
from a model learned elsewhere."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from tests.stages.test_learn import Pipeline
from toolkit.config import PipelineConfig, default_config
from toolkit.errors import StageError
from toolkit.stages.online import SPEC as ONLINE
from toolkit.stages.runner import run_stage
from toolkit.tableio import read_table
from toolkit.workspace import Workspace


def _copy(pipeline: Pipeline, tmp_path: Path, name: str = "ws") -> Workspace:
    ws = Workspace(tmp_path / name)
    shutil.copytree(pipeline.ws.root, ws.root, symlinks=True)
    return ws


#: The default's refits scaled to the sample's 0.9 km (the default refits every 2 km).
SAMPLE_REFITS = {"refit_every_m": 200.0, "refit_budget_s": 5.0, "refit_iterations": 3}


def _every(metres: float, checkpoint_every: int = 2, **changes: object) -> PipelineConfig:
    """The default configuration with an update every ``metres`` and its refits scaled to
    the sample (:data:`SAMPLE_REFITS`; ``changes`` override them)."""
    cfg = default_config()
    online = dataclasses.replace(
        cfg.online,
        update_every_m=metres,
        checkpoint_every=checkpoint_every,
        **{**SAMPLE_REFITS, **changes},
    )
    return dataclasses.replace(cfg, online=online)


def _outputs(ws: Workspace) -> dict[str, object]:
    """The replay's outputs, compared by ``np.testing.assert_equal`` (NaN equal to NaN)."""
    return {
        "scores": read_table(ws.path("online_scores"), "online_scores").to_pydict(),
        "steps": read_table(ws.path("online_steps"), "online_steps").to_pydict(),
        "summary": json.loads(ws.path("online_summary").read_text()),
        "state": json.loads(ws.path("online_state").read_text()),
    }


def test_every_event_is_scored_by_the_model_of_its_time(pipeline: Pipeline, tmp_path: Path) -> None:
    """Each event met once, by a version no later than the updates before it was seen; no
    event flagged before the model first learned; the offline column is model.json's score
    of the same event in the report; nothing is left of the checkpoint."""
    ws = _copy(pipeline, tmp_path)
    cfg = _every(100.0, min_rough=2)
    result = run_stage(ONLINE, ws, cfg)
    assert result.status == "written"
    scores = read_table(ws.path("online_scores"), "online_scores")
    steps = read_table(ws.path("online_steps"), "online_steps")
    events = read_table(ws.events_table, "tables_events")
    assert scores.num_rows == events.num_rows
    version = scores.column("version").to_numpy()
    assert version.min() >= 0
    s_m = scores.column("s_m").to_numpy()
    end_m = steps.column("end_m").to_numpy()
    # An event beginning before step k's end is scored by a version of at most k.
    assert np.all(version <= np.searchsorted(end_m, s_m, side="right"))
    predicted = scores.column("predicted").to_numpy(zero_copy_only=False)
    assert not predicted[version == 0].any()
    assert steps.column("version").to_numpy().max() >= 1, "the sample holds enough to learn"
    report = read_table(ws.scores_table, "scores")
    by_event = dict(
        zip(
            report.column("event_id").to_pylist(),
            report.column("r_combined").to_pylist(),
            strict=True,
        )
    )
    mine = scores.filter(scores.column("split").to_numpy(zero_copy_only=False) == "test")
    want = np.array([by_event[e] for e in mine.column("event_id").to_pylist()])
    np.testing.assert_allclose(mine.column("r_offline").to_numpy(), want, rtol=1e-12)
    # The final model's standings rank as its scores do, each a share of its buffer.
    r_final = scores.column("r_final").to_numpy()
    s_final = scores.column("standing_final").to_numpy()
    assert np.all(np.diff(s_final[np.argsort(r_final, kind="stable")]) >= 0)
    assert s_final.min() >= 0.0 and s_final.max() <= 1.0
    summary = json.loads(ws.path("online_summary").read_text())
    assert summary["updates"] == steps.num_rows and summary["not_reached"] == 0
    assert summary["test"]["offline"]["auc"] == pytest.approx(
        json.loads(ws.summary_path.read_text())["self_supervised"]["auc"]
    )
    assert not ws.path("online_checkpoint").exists()
    assert run_stage(ONLINE, ws, cfg).status == "up_to_date"


class _StopError(Exception):
    """What the test's progress callback raises: the replay stopped from outside."""


@pytest.mark.parametrize(
    "changes",
    [{}, {"refit_every_m": 0.0, "coordinates_per_update": 4}],
    ids=["refits pending across checkpoints", "updates alone"],
)
def test_a_stopped_replay_resumes_to_what_an_unbroken_one_writes(
    pipeline: Pipeline, tmp_path: Path, changes: dict[str, float]
) -> None:
    cfg = _every(100.0, checkpoint_every=2, min_rough=2, **changes)
    whole = _copy(pipeline, tmp_path, "whole")
    run_stage(ONLINE, whole, cfg)
    broken = _copy(pipeline, tmp_path, "broken")
    manifest_before = broken.manifest_path.read_bytes()
    calls = 0

    def stop_after_five(_: str) -> None:
        nonlocal calls
        calls += 1
        if calls == 5:
            raise _StopError

    with pytest.raises(_StopError):
        run_stage(ONLINE, broken, cfg, step=stop_after_five)
    assert broken.path("online_checkpoint").is_file(), "two pieces of two updates were saved"
    # Stopped, it left nothing but work in progress (hidden) and the manifest as it was.
    folder = broken.path("online_scores").parent
    assert [p.name for p in folder.iterdir() if not p.name.startswith(".")] == []
    assert broken.manifest_path.read_bytes() == manifest_before
    resumed = run_stage(ONLINE, broken, cfg)
    assert any("resumed a stopped replay" in w for w in resumed.warnings)
    np.testing.assert_equal(_outputs(broken), _outputs(whole))
    assert not broken.path("online_checkpoint").exists()
    # Recorded as the unbroken run is, but for its timings (the resumption is not a warning).
    records = [
        {k: v for k, v in json.loads(w.manifest_path.read_text())["stages"]["online"].items()
         if k not in ("timings_s", "finished_utc")}
        for w in (broken, whole)
    ]  # fmt: skip
    assert records[0] == records[1]


def test_a_checkpoint_of_other_inputs_is_not_resumed(pipeline: Pipeline, tmp_path: Path) -> None:
    """A checkpoint left by another configuration (another key) is replayed over."""
    ws = _copy(pipeline, tmp_path)
    stops = iter(range(10))

    def stop(_: str) -> None:
        if next(stops) == 3:
            raise _StopError

    with pytest.raises(_StopError):
        run_stage(ONLINE, ws, _every(100.0, min_rough=2), step=stop)
    assert ws.path("online_checkpoint").is_file()
    other = run_stage(ONLINE, ws, _every(100.0, min_rough=3))
    assert not any("resumed" in w for w in other.warnings)
    fresh = _copy(pipeline, tmp_path, "fresh")
    run_stage(ONLINE, fresh, _every(100.0, min_rough=3))
    np.testing.assert_equal(_outputs(ws), _outputs(fresh))


def test_it_starts_from_a_model_learned_elsewhere(pipeline: Pipeline, tmp_path: Path) -> None:
    """With start_model, every event before the first update is scored by that model (here
    the workspace's own, copied), and its verdicts are that model's."""
    ws = _copy(pipeline, tmp_path)
    shutil.copy(ws.model_path, ws.root / "elsewhere.json")
    cfg = _every(100.0, min_rough=2, start_model="elsewhere.json")
    run_stage(ONLINE, ws, cfg)
    scores = read_table(ws.path("online_scores"), "online_scores")
    np.testing.assert_array_equal(scores.column("r_start"), scores.column("r_offline"))
    first = scores.column("version").to_numpy() == 0
    assert first.any()
    np.testing.assert_array_equal(
        scores.column("r_online").to_numpy()[first], scores.column("r_offline").to_numpy()[first]
    )
    summary = json.loads(ws.path("online_summary").read_text())
    assert summary["start"]["from"] == "elsewhere.json"


def test_a_missing_start_model_is_refused_naming_it(pipeline: Pipeline, tmp_path: Path) -> None:
    ws = _copy(pipeline, tmp_path)
    with pytest.raises(StageError, match="start_model") as err:
        run_stage(ONLINE, ws, _every(100.0, start_model="nowhere.json"))
    assert "nowhere.json" in str(err.value)
    assert not ws.path("online_scores").exists()


def test_what_a_user_must_know_is_said() -> None:
    """A resumed replay, a drive that never learned or learned late, stretches without
    events and labels out of order: each a warning line of its own."""
    from toolkit.model.online import OnlineConfig
    from toolkit.stages.online import _warnings

    worse = {"online": {"auc": 0.887}, "start": {"auc": 0.895}}
    summary = {
        "first_update_m": {"0": None, "1": 4000.0, "2": 500.0},
        "gaps": [{"drive": 1, "from_m": 100.0, "to_m": 2600.0}],
        "out_of_order_labels": 3,
        "test": worse,
    }
    got = _warnings(summary, "2026-11-29 10:00:00", OnlineConfig(update_every_m=500.0))
    assert len(got) == 6
    assert "resumed a stopped replay" in got[0]
    assert "drive 0: the model never learned" in got[1]
    assert "drive 1: the model first changed at 4.0 km" in got[2]
    assert "1 stretch(es) without events (2.5 km" in got[3]
    assert "did not help here" in got[4] and "0.887" in got[4] and "(0.895, -0.008)" in got[4]
    assert "3 label(s) known before" in got[5]
    better = {"online": {"auc": 0.895}, "start": {"auc": 0.750}}
    quiet = {"first_update_m": {"0": 500.0}, "gaps": [], "out_of_order_labels": 0, "test": better}
    assert _warnings(quiet, None, OnlineConfig(update_every_m=500.0)) == []
    # With only refits learning (every 2 km), a first change at 2.6 km is as expected; on a
    # drive too short for one, the refits are named among the reasons, and no drive having
    # learned, the start's AUC equalled is not said again.
    refits = OnlineConfig(update_every_m=150.0, coordinates_per_update=0, refit_every_m=2000.0)
    late = {"first_update_m": {"0": 2600.0, "1": None}, "gaps": [], "out_of_order_labels": 0}
    (never,) = _warnings({**late, "test": better}, None, refits)
    assert "drive 1: the model never learned" in never and "none was ready" in never
    short = {"first_update_m": {"0": None}, "gaps": [], "out_of_order_labels": 0, "test": worse}
    (only,) = _warnings(short, None, refits)
    assert "never learned" in only


def test_a_refit_slower_than_its_budget_is_said() -> None:
    from toolkit.model.online import OnlineConfig
    from toolkit.stages.online import _slow_refit

    refits = OnlineConfig(refit_every_m=2000.0, refit_budget_s=30.0)
    (said,) = _slow_refit(31.5, refits)
    assert "a refit took 31.5 s" in said and "budget of 30 s" in said
    assert _slow_refit(29.0, refits) == ()
    assert _slow_refit(99.0, OnlineConfig()) == ()  # no refits


def test_the_terminal_states_the_refits_beside_the_loop() -> None:
    from toolkit.stages.online import OnlineResult

    summary = {"drives": 1, "events": 10, "rough": 2, "updates": 3, "test": {}}
    timings = {"update_p50": 0.0, "update_p95": 0.001, "real_time_factor": 27.0}
    with_refits = OnlineResult(
        "written",
        {**summary, "within_0_02_from_m": None},
        1.0,
        timings={**timings, "refits": 2.0, "refit_max": 6.84},
    )
    assert "2 refit(s) beside the loop, the longest 6.8 s" in with_refits.text()
    without = OnlineResult(
        "written", {**summary, "within_0_02_from_m": None}, 1.0, timings={**timings, "refits": 0.0}
    )
    assert "refit" not in without.text()
