"""The learn stage on the bundled sample log: ``tables/`` -> ``model.json`` (sect. 6).

One pipeline run (label, tables, learn, evaluate on a copy of the session's projected
sample) is shared by this file and ``test_evaluate.py`` through :func:`pipeline`: it is
built once per session, in a fixed folder under pytest's base temporary directory, whichever
file asks first. Tests that change a workspace work on a copy of it.

The checks derive what they expect from the tables (counts, hashes) or recompute it with
the model's own building blocks (patches, pair table, scores), so a stage that recorded
something other than what it did fails here.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest
from click.testing import CliRunner
from sklearn.metrics import roc_auc_score

from toolkit.cli import main
from toolkit.config import default_config
from toolkit.errors import StageError, WorkspaceError
from toolkit.manifest import Manifest, digest_files, file_sha256
from toolkit.model.patches import build_patches
from toolkit.model.roughness import EXPONENTS, PairTable, RoughnessParams, score_events
from toolkit.stages.evaluate import SPEC as EVALUATE
from toolkit.stages.label import SPEC as LABEL
from toolkit.stages.learn import SPEC as LEARN
from toolkit.stages.runner import run_stage
from toolkit.stages.tables import SPEC as TABLES
from toolkit.tableio import read_table, read_table_metadata, write_table
from toolkit.workspace import Workspace

#: Folder (under pytest's base temporary directory) of the shared pipeline run.
PIPELINE_DIR = "learn_evaluate_pipeline"
#: Keys ``model.json`` must hold: the contract's parameters and how they were trained.
MODEL_KEYS = (
    "alpha",
    "upsilon",
    "omega",
    "zeta",
    "mu",
    "lambda",
    "objective",
    "tp_rate",
    "fp_rate",
    "iterations",
    "objective_by_iteration",
    "training",
)


@dataclasses.dataclass(frozen=True)
class Pipeline:
    """The shared run: its workspace, the sample's log id and what the stages returned."""

    ws: Workspace
    log_id: str
    learn_status: str
    evaluate_status: str
    evaluate_warnings: tuple[str, ...]


def build_pipeline(
    sample_projected: tuple[Path, str], tmp_path_factory: pytest.TempPathFactory
) -> Pipeline:
    """Label, tables, learn and evaluate on a copy of the projected sample, once per
    session: a later call (from this file or ``test_evaluate.py``, even through another
    import of this module) finds the finished run by its ``done.json`` and reuses it."""
    base = tmp_path_factory.getbasetemp() / PIPELINE_DIR
    done = base / "done.json"
    if not done.is_file():
        if base.exists():
            shutil.rmtree(base)  # an earlier build that failed half-way
        root, log_id = sample_projected
        ws = Workspace(base / "ws")
        shutil.copytree(root, ws.root, symlinks=True)
        cfg = default_config()
        run_stage(LABEL, ws, cfg, log_id=log_id)
        run_stage(TABLES, ws, cfg)
        learned = run_stage(LEARN, ws, cfg)
        evaluated = run_stage(EVALUATE, ws, cfg)
        done.write_text(
            json.dumps(
                {
                    "log_id": log_id,
                    "learn_status": learned.status,
                    "evaluate_status": evaluated.status,
                    "evaluate_warnings": list(evaluated.warnings),
                }
            )
        )
    info = json.loads(done.read_text())
    return Pipeline(
        Workspace(base / "ws"),
        info["log_id"],
        info["learn_status"],
        info["evaluate_status"],
        tuple(info["evaluate_warnings"]),
    )


def copy_workspace(ws: Workspace, dst: Path) -> Workspace:
    """A copy of ``ws`` at ``dst`` a test may change."""
    shutil.copytree(ws.root, dst, symlinks=True)
    return Workspace(dst)


def write_events_unrecorded(ws: Workspace, events: pa.Table) -> None:
    """Replace ``tables/events.parquet`` by ``events``, its metadata kept but no finished
    ``terrain tables`` recording it: a table rewritten by hand."""
    meta = read_table_metadata(ws.events_table)
    write_table(
        ws.events_table,
        events,
        "tables_events",
        source_sha256=meta["source_sha256"].split(","),
        config_hash=meta["config_hash"],
    )


def split_and_rough(ws: Workspace) -> tuple[np.ndarray, np.ndarray]:
    """The ``split`` (object) and ``rough`` (bool) columns of ``tables/events.parquet``."""
    events = read_table(ws.events_table, "tables_events")
    split = np.asarray(events.column("split").to_pylist(), dtype=object)
    rough = events.column("rough").to_numpy(zero_copy_only=False).astype(bool)
    return split, rough


def rewrite_events_table(ws: Workspace, events: pa.Table) -> None:
    """Replace ``tables/events.parquet`` by ``events`` and record the tables as what the
    last finished ``terrain tables`` wrote (sizes and sha256 of both files, as a real run
    that produced these tables would have), so the consumers' input check passes."""
    write_events_unrecorded(ws, events)
    manifest = Manifest(ws.manifest_path)
    record = manifest.stage("tables")
    assert record is not None, "the workspace has no finished tables stage"
    manifest.record_stage(
        "tables",
        dataclasses.replace(
            record, output_files=digest_files(ws.tables_dir, list(record.output_files))
        ),
    )


def with_rough(events: pa.Table, rough: np.ndarray) -> pa.Table:
    """``events`` with its ``rough`` column replaced."""
    i = events.schema.get_field_index("rough")
    return events.set_column(i, "rough", pa.array(rough.astype(bool), pa.bool_()))


def one_error_line(stderr: str) -> str:
    """The single ``terrain: error:`` line of a failed command (no traceback)."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1, stderr
    assert lines[0].startswith("terrain: error: "), stderr
    assert "Traceback" not in stderr
    return lines[0]


@pytest.fixture(scope="module")
def model(pipeline: Pipeline) -> dict[str, Any]:
    return dict(json.loads(pipeline.ws.model_path.read_text()))


# -- the data the rest stands on ---------------------------------------------------------


def test_both_splits_hold_rough_and_smooth_events(pipeline: Pipeline) -> None:
    """Precondition of every other test here: learning needs both classes in the training
    split, the ROC both in the test split. If the sample or the labeller changes so that a
    split loses a class, this says so instead of the other tests failing obscurely."""
    split, rough = split_and_rough(pipeline.ws)
    for name in ("train", "test"):
        mine = split == name
        assert 0 < int(rough[mine].sum()) < int(mine.sum()), (name, mine.sum(), rough[mine].sum())
    assert set(split.tolist()) == {"train", "test"}
    assert pipeline.learn_status == "written"
    assert pipeline.evaluate_status == "written"


# -- model.json ----------------------------------------------------------------------------


def test_model_json_holds_the_parameters_and_how_they_were_trained(
    pipeline: Pipeline,
    model: dict[str, Any],
) -> None:
    """The contract's keys; 10 alphas with the exponents (alpha_2, 4, 6, 8, 10) positive,
    as eq. (4) needs for ``|0|^a``; omega a positive integer (W's length); the training
    counts equal what ``tables/events.parquet`` says of its train split; the objective is
    eq. (6) of the recorded rates; what the search climbs never decreases from its start
    (it only accepts improvements); the tables' sha256 are the
    files'; the manifest's learn record describes the same run."""
    ws = pipeline.ws
    cfg = default_config()
    for key in MODEL_KEYS:
        assert key in model, key
    alpha = model["alpha"]
    assert len(alpha) == 10 and all(isinstance(a, float) for a in alpha)
    assert all(alpha[i] > 0.0 for i in EXPONENTS if i < len(alpha)), alpha
    assert isinstance(model["omega"], int) and not isinstance(model["omega"], bool)
    assert model["omega"] >= 1
    assert model["upsilon"] > 0.0 and model["zeta"] > 0.0
    assert np.isfinite(model["mu"])

    split, rough = split_and_rough(ws)
    train = split == "train"
    training = model["training"]
    assert training["events"] == int(train.sum())
    assert training["positives"] == int(rough[train].sum())
    assert training["max_points_per_wheel"] == cfg.model.max_points_per_wheel
    # Points: each training tyre's points in the table, capped at max_points_per_wheel.
    events = read_table(ws.events_table, "tables_events")
    train_keys = {
        (log, ev)
        for log, ev, s in zip(
            events.column("log_id").to_pylist(),
            events.column("event_id").to_pylist(),
            split.tolist(),
            strict=True,
        )
        if s == "train"
    }
    points = read_table(
        ws.event_points_table, "event_points", columns=["log_id", "event_id", "wheel"]
    )
    per_tyre = points.group_by(["log_id", "event_id", "wheel"]).aggregate([([], "count_all")])
    capped = sum(
        min(n, cfg.model.max_points_per_wheel)
        for log, ev, n in zip(
            per_tyre.column("log_id").to_pylist(),
            per_tyre.column("event_id").to_pylist(),
            per_tyre.column("count_all").to_pylist(),
            strict=True,
        )
        if (log, ev) in train_keys
    )
    assert training["points"] == capped

    assert model["lambda"] == cfg.learn.lambda_fp
    assert model["objective"] == pytest.approx(
        model["tp_rate"] - model["lambda"] * model["fp_rate"], abs=1e-12
    )
    history = model["objective_by_iteration"]
    assert len(history) == model["iterations"] == cfg.learn.iterations
    assert history[-1] == model["objective"]
    # What the steps climb (the training AUC by default) never falls, from the start on.
    assert model["accepted_by"] == cfg.learn.accept
    climbed = model["accepted_measure_by_iteration"]
    assert len(climbed) == model["iterations"]
    assert all(b >= a for a, b in zip(climbed, climbed[1:], strict=False)), climbed
    assert climbed[0] >= model["start"][cfg.learn.accept]

    assert training["tables_sha256"] == {
        "tables/events.parquet": file_sha256(ws.events_table),
        "tables/event_points.parquet": file_sha256(ws.event_points_table),
    }
    record = ws.manifest().stage("learn")
    assert record is not None
    assert record.output_files["model.json"].sha256 == file_sha256(ws.model_path)
    # The record keys them by layout name, as the runner checks every stage's needs.
    assert dict(record.inputs) == {
        "events_table": file_sha256(ws.events_table),
        "event_points_table": file_sha256(ws.event_points_table),
    }
    assert record.row_counts["train_events"] == training["events"]
    assert record.row_counts["train_positives"] == training["positives"]


def test_the_parameters_reproduce_the_recorded_rates_on_the_training_split(
    pipeline: Pipeline,
    model: dict[str, Any],
) -> None:
    """Scoring the training events again, from the tables, with the model's building blocks
    (patches sampled as ``model.json`` says, pair table, eqs. 2-5) and the parameters read
    back from ``model.json``, and
    calling an event rough when ``R_combined > mu``, gives the true- and false-positive
    rates the file records: the file holds the parameters that earned its objective, and
    its mu sits where the learner put it. The recorded training AUC is the ranking's."""
    ws = pipeline.ws
    events = read_table(ws.events_table, "tables_events")
    train = events.filter(pc.equal(events.column("split"), "train"))
    rough = train.column("rough").to_numpy(zero_copy_only=False).astype(bool)
    points = read_table(ws.event_points_table, "event_points")
    t = model["training"]
    patches = build_patches(
        train,
        points,
        t["max_points_per_wheel"],
        sample=t["point_sample"],
        laser_order=t["laser_order"],
        source=ws.event_points_table,
    )
    assert int(patches.count.sum()) == model["training"]["points"]
    params = RoughnessParams(
        tuple(model["alpha"]), model["upsilon"], model["omega"], model["zeta"], model["mu"]
    )
    scores = score_events(PairTable(patches), params)
    predicted = scores.r_combined > model["mu"]
    np.testing.assert_array_equal(predicted, scores.predicted)
    assert float(predicted[rough].mean()) == pytest.approx(model["tp_rate"], abs=1e-12)
    assert float(predicted[~rough].mean()) == pytest.approx(model["fp_rate"], abs=1e-12)
    # mu separates the scores: no training event sits on the threshold.
    assert not np.any(scores.r_combined == model["mu"])
    assert model["train_auc"] == pytest.approx(roc_auc_score(rough, scores.r_combined), abs=1e-9)


# -- reruns --------------------------------------------------------------------------------


def test_learning_again_gives_the_same_bytes_and_a_current_model_is_left_alone(
    pipeline: Pipeline, tmp_path: Path
) -> None:
    """Coordinate ascent is deterministic: ``--overwrite`` on the same tables and
    configuration writes a byte-identical ``model.json``. Then, without ``--overwrite``,
    both the function and ``terrain learn`` report the model up to date and leave the file
    (and the manifest's record of it) untouched."""
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    before = ws.model_path.read_bytes()
    again = run_stage(LEARN, ws, default_config(), overwrite=True)
    assert again.status == "written"
    assert ws.model_path.read_bytes() == before
    assert again.model == json.loads(before)

    mtime = ws.model_path.stat().st_mtime_ns
    record = ws.manifest().stage("learn")
    third = run_stage(LEARN, ws, default_config())
    assert third.status == "up_to_date"
    assert third.model == json.loads(before)
    assert ws.model_path.stat().st_mtime_ns == mtime
    assert ws.manifest().stage("learn") == record

    result = CliRunner().invoke(main, ["learn", "-w", str(ws.root)])
    assert result.exit_code == 0, result.stderr
    assert "up to date" in result.stdout
    assert ws.model_path.stat().st_mtime_ns == mtime
    assert ws.model_path.read_bytes() == before


# -- refusals ------------------------------------------------------------------------------


def test_without_tables_learn_refuses_in_one_line_naming_the_file(
    sample_projected: tuple[Path, str], tmp_path: Path
) -> None:
    """A projected workspace that never ran ``terrain tables``: the stage refuses, naming
    the missing table and the verb to run, and writes no model; the command exits 1 with
    one line."""
    root, _ = sample_projected
    ws = copy_workspace(Workspace(root), tmp_path / "ws")
    with pytest.raises(StageError, match="run `terrain tables` first") as err:
        run_stage(LEARN, ws, default_config())
    assert err.value.path == ws.events_table
    assert not ws.model_path.exists()

    result = CliRunner().invoke(main, ["learn", "-w", str(ws.root)])
    assert result.exit_code == 1
    line = one_error_line(result.stderr)
    assert str(ws.events_table) in line and "terrain tables" in line
    assert not ws.model_path.exists()


@pytest.mark.parametrize("missing", ["rough", "smooth"])
def test_a_training_split_of_one_class_is_refused_and_the_model_kept(
    pipeline: Pipeline, tmp_path: Path, missing: str
) -> None:
    """Crafted tables (written through ``tableio.write_table`` and recorded as a finished
    tables run, so the input check passes) whose training split has no rough (or no smooth)
    event: eq. (6)'s rates are undefined, so learning refuses, naming the events table and
    the class it lacks, by function and by command (exit 1, one line). The new tables are
    not the old model's, so the stage does not call it up to date; the model of the earlier
    tables stays as it was (nothing half-written)."""
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    before = ws.model_path.read_bytes()
    events = read_table(ws.events_table, "tables_events")
    split, rough = split_and_rough(ws)
    crafted = rough.copy()
    crafted[split == "train"] = missing == "smooth"
    rewrite_events_table(ws, with_rough(events, crafted))
    # The test split is as it was: only the training split lost a class.
    np.testing.assert_array_equal(split_and_rough(ws)[1][split == "test"], rough[split == "test"])

    with pytest.raises(StageError, match=f"training split has .* no {missing} one") as err:
        run_stage(LEARN, ws, default_config())
    assert err.value.path == ws.events_table
    assert ws.model_path.read_bytes() == before

    result = CliRunner().invoke(main, ["learn", "-w", str(ws.root)])
    assert result.exit_code == 1
    line = one_error_line(result.stderr)
    assert str(ws.events_table) in line and f"no {missing} one" in line
    assert ws.model_path.read_bytes() == before
    # Nothing written aside is left (``.model.json.<host>-<pid>-<random>.tmp``).
    assert [p.name for p in ws.root.iterdir() if "model.json" in p.name] == ["model.json"]


def test_tables_changed_after_the_tables_stage_are_refused(
    pipeline: Pipeline, tmp_path: Path
) -> None:
    """An events table rewritten by hand (not recorded by a finished ``terrain tables``)
    is not learned from: one error naming the file and telling to run tables again."""
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    before = ws.model_path.read_bytes()
    write_events_unrecorded(ws, read_table(ws.events_table, "tables_events").slice(1))
    with pytest.raises(WorkspaceError, match="run `terrain tables` again") as err:
        run_stage(LEARN, ws, default_config(), overwrite=True)
    assert err.value.path == ws.events_table
    assert ws.model_path.read_bytes() == before


def test_learn_has_help() -> None:
    result = CliRunner().invoke(main, ["learn", "--help"])
    assert result.exit_code == 0
    assert "--workspace" in result.output and "--overwrite" in result.output


def test_an_event_listed_twice_is_blamed_on_the_events_table(
    pipeline: Pipeline, tmp_path: Path
) -> None:
    """A duplicated row of ``tables/events.parquet`` is said of that file (learn and
    evaluate read it through ``split_events``), not of the points matched to it."""
    from toolkit.stages.training_data import split_events

    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    events = read_table(ws.events_table, "tables_events")
    rewrite_events_table(ws, pa.concat_tables([events, events.slice(3, 1)]))
    with pytest.raises(StageError, match="lists event .* 2 times") as err:
        run_stage(LEARN, ws, default_config(), overwrite=True)
    assert err.value.path == ws.events_table
    with pytest.raises(StageError, match="lists event .* 2 times"):
        split_events(ws, "test")


def test_tables_of_another_configuration_are_refused_by_learn_and_evaluate(
    pipeline: Pipeline, tmp_path: Path
) -> None:
    """``run -c B --from tables`` whose learn fails leaves B's tables under A's config.toml:
    learn and evaluate under A refuse them in one line (export already did) instead of
    reporting on B's split as A's."""
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    other = default_config()
    other = dataclasses.replace(other, tables=dataclasses.replace(other.tables, train_fraction=0.4))
    for stage in (LEARN, EVALUATE):
        with pytest.raises(
            WorkspaceError, match="tables outputs are stale .made with another configuration"
        ) as err:
            run_stage(stage, ws, other, overwrite=True)
        assert err.value.path == ws.tables_dir
    run_stage(LEARN, ws, default_config())  # the configuration they were made with: up to date


def test_learn_evaluate_and_export_refuse_what_other_code_made_upstream(
    pipeline: Pipeline, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The runner holds a workspace stage's needs to their makers' code as it does a log
    stage's: tables made by another version of the tables stage are refused by learn,
    evaluate and export alike, one line naming the maker and why; a model made by another
    learn is refused by evaluate."""
    from toolkit.publish.export import run_export
    from toolkit.stages import registry

    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    real = registry.code_version_of
    for maker, readers in (("tables", (LEARN, EVALUATE)), ("learn", (EVALUATE,))):
        monkeypatch.setattr(
            registry, "code_version_of", lambda n, m=maker: "e" * 64 if n == m else real(n)
        )
        for stage in readers:
            with pytest.raises(
                WorkspaceError, match=f"{maker} outputs are stale .made by other code"
            ):
                run_stage(stage, ws, default_config(), overwrite=True)
    monkeypatch.setattr(
        registry, "code_version_of", lambda n: "e" * 64 if n == "tables" else real(n)
    )
    with pytest.raises(WorkspaceError, match="tables outputs are stale .made by other code"):
        run_export(ws, tmp_path / "export", default_config())
    monkeypatch.setattr(registry, "code_version_of", real)
    assert run_stage(EVALUATE, ws, default_config()).status == "up_to_date"


def test_evaluate_refuses_a_model_learned_from_other_tables(
    pipeline: Pipeline, tmp_path: Path
) -> None:
    """The tables made again (new labels) after learn: evaluate would score a model on
    events it may have trained on. The runner's upstream check refuses it, naming the
    tables' file and the stage to run again."""
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    events = read_table(ws.events_table, "tables_events")
    rough = events.column("rough").to_numpy(zero_copy_only=False)
    rewrite_events_table(ws, with_rough(events, ~rough))
    with pytest.raises(WorkspaceError, match="learn outputs beside it are stale") as err:
        run_stage(EVALUATE, ws, default_config(), overwrite=True)
    assert err.value.path == ws.events_table


def test_an_initial_guess_that_overflows_is_a_config_error(
    pipeline: Pipeline, tmp_path: Path
) -> None:
    """Valid values each (omega 10,000, upsilon 100) whose scores overflow together: one line
    naming the configuration's keys, not an internal error; the model stays as it was."""
    from toolkit.errors import ConfigError

    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    before = ws.model_path.read_bytes()
    cfg = default_config()
    huge = dataclasses.replace(
        cfg, learn=dataclasses.replace(cfg.learn, initial_upsilon=100.0, initial_omega=10_000)
    )
    with pytest.raises(ConfigError, match="learn.initial_alpha / initial_upsilon") as err:
        run_stage(LEARN, ws, huge, overwrite=True)
    assert "\n" not in str(err.value) and err.value.path == ws.config_path
    assert ws.model_path.read_bytes() == before
