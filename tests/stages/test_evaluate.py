"""The evaluate stage on the bundled sample log: tables + ``model.json`` -> ``report/``
(sect. 7).

The pipeline run is the one ``test_learn.py`` builds (label, tables, learn, evaluate, once per
session, see :func:`tests.stages.test_learn.build_pipeline`). Every number the report states
is checked against the tables, ``model.json`` or ``scores.parquet`` of the same run, or
recomputed from them with scikit-learn, the field's reference for ROC curves.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from click.testing import CliRunner
from sklearn.metrics import roc_auc_score, roc_curve

from tests.stages.test_learn import (
    Pipeline,
    copy_workspace,
    one_error_line,
    rewrite_events_table,
    split_and_rough,
    with_rough,
)
from toolkit.cli import main
from toolkit.config import default_config
from toolkit.errors import StageError, ToolkitError
from toolkit.manifest import file_sha256
from toolkit.model.roc import MIN_ROUGH_EVENTS
from toolkit.model.roughness import signed_power
from toolkit.stages import evaluate_rows
from toolkit.stages.evaluate import SPEC as EVALUATE
from toolkit.stages.runner import run_stage
from toolkit.tableio import load_table_schema, read_table

#: summary.json's methods with an ROC entry (the contract's, ablations apart).
METHODS = ("self_supervised", "baseline_all_lasers", "baseline_closest_laser", "oracle")
ABLATIONS = ("no_time_term", "no_rate_terms")
FPR_KEYS = ("0.05", "0.1", "0.2")
REPORT_FILES = ("scores.parquet", "summary.json", "index.html")


@pytest.fixture(scope="module")
def summary(pipeline: Pipeline) -> dict[str, Any]:
    return dict(json.loads(pipeline.ws.summary_path.read_text()))


@pytest.fixture(scope="module")
def model(pipeline: Pipeline) -> dict[str, Any]:
    return dict(json.loads(pipeline.ws.model_path.read_text()))


@pytest.fixture(scope="module")
def scores(pipeline: Pipeline) -> pa.Table:
    return read_table(pipeline.ws.scores_table, "scores")


def method_entries(summary: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Every method's ROC entry, the ablations' included, by the name of its scores column."""
    entries = {name: summary[name] for name in METHODS}
    entries.update({name: summary["ablations"][name] for name in ABLATIONS})
    return entries


def column(table: pa.Table, name: str) -> np.ndarray:
    return np.asarray(table.column(name).to_numpy(zero_copy_only=False))


def ranked(scores: pa.Array | pa.ChunkedArray) -> np.ndarray:
    """A method's scores with the events it could not score (null) ranked below every
    scored one, as the report defines."""
    v = np.asarray(scores.to_numpy(zero_copy_only=False), dtype=np.float64)
    missing = np.isnan(v)
    if missing.any():
        v = np.where(missing, np.nanmin(v) - 1.0 if (~missing).any() else 0.0, v)
    return v


def report_mtimes(pipeline: Pipeline) -> dict[str, int]:
    return {n: (pipeline.ws.report_dir / n).stat().st_mtime_ns for n in REPORT_FILES}


# -- summary.json --------------------------------------------------------------------------


def test_summary_has_the_contract_keys_and_the_tables_counts(
    pipeline: Pipeline, summary: dict[str, Any]
) -> None:
    """The contract's minimum keys, each method's entry with an AUC and TPR at the three
    FPRs (the oracle too: the sample is simulated), and the per-split counts equal to what
    ``tables/events.parquet`` holds; no warning but the small-sample one of each split with
    fewer than 30 rough events (both splits have both classes)."""
    for key in (*METHODS, "ablations", "speed_control"):
        assert key in summary, key
    for name, entry in method_entries(summary).items():
        assert isinstance(entry, dict), name
        assert isinstance(entry["auc"], float), name
        assert set(entry["tpr_at_fpr"]) == set(FPR_KEYS), name
    assert set(summary["speed_control"]) >= {"shock_reduction_at_equal_time", "curves"}

    split, rough = split_and_rough(pipeline.ws)
    for name in ("train", "test"):
        mine = split == name
        assert summary[f"{name}_events"] == int(mine.sum())
        assert summary[f"{name}_positives"] == int(rough[mine].sum())
    small = [name for name in ("train", "test") if summary[f"{name}_positives"] < MIN_ROUGH_EVENTS]
    assert len(summary["warnings"]) == len(small)
    for name, line in zip(small, summary["warnings"], strict=True):
        assert line.startswith(f"the {name} split has {summary[f'{name}_positives']} rough")
    assert pipeline.evaluate_warnings == tuple(summary["warnings"])


def test_every_method_roc_entry_agrees_with_its_scores(
    summary: dict[str, Any], scores: pa.Table
) -> None:
    """For each method: the AUC is in [0, 1] and equals scikit-learn's on the test rows of
    its ``scores.parquet`` column (unscored events ranked lowest); TPR at FPR is in [0, 1]
    and never decreases as the FPR allowed grows; each bootstrap interval has lo <= hi
    (it need not contain the point estimate); the entry counts the test split."""
    test = column(scores, "split") == "test"
    rough = column(scores, "rough").astype(bool)
    for name, entry in method_entries(summary).items():
        col = "r_combined" if name == "self_supervised" else name
        assert 0.0 <= entry["auc"] <= 1.0, name
        want = roc_auc_score(rough[test], ranked(scores.column(col))[test])
        assert entry["auc"] == pytest.approx(want, abs=1e-6), name
        tpr = [entry["tpr_at_fpr"][k] for k in FPR_KEYS]
        assert all(0.0 <= t <= 1.0 for t in tpr), (name, tpr)
        assert all(b >= a for a, b in zip(tpr, tpr[1:], strict=False)), (name, tpr)
        lo, hi = entry["auc_ci95"]
        assert 0.0 <= lo <= hi <= 1.0, (name, lo, hi)
        for k in FPR_KEYS:
            lo, hi = entry["tpr_at_fpr_ci95"][k]
            assert 0.0 <= lo <= hi <= 1.0, (name, k, lo, hi)
        assert entry["events"] == int(test.sum()), name
        assert entry["positives"] == int(rough[test].sum()), name


def test_tpr_at_fpr_is_the_best_operating_point_of_the_roc_curve(
    summary: dict[str, Any], scores: pa.Table
) -> None:
    """The self-supervised model's TPR at each FPR is the largest true-positive rate among
    the points of scikit-learn's ROC curve (every threshold kept) whose false-positive rate
    is at most that FPR, no interpolation (a vehicle runs one threshold)."""
    test = column(scores, "split") == "test"
    rough = column(scores, "rough").astype(bool)[test]
    fpr, tpr, _ = roc_curve(rough, column(scores, "r_combined")[test], drop_intermediate=False)
    for key in FPR_KEYS:
        want = float(tpr[fpr <= float(key) + 1e-12].max())
        assert summary["self_supervised"]["tpr_at_fpr"][key] == pytest.approx(want, abs=1e-6)


def test_ablations_fix_their_terms_at_zero_and_the_model_entry_is_model_json(
    summary: dict[str, Any], model: dict[str, Any]
) -> None:
    """``no_time_term`` learns with alpha_3 = 0, ``no_rate_terms`` with alpha_7 = alpha_9 = 0
    (eq. 4's time and rate terms removed); the self-supervised entry's parameters are
    ``model.json``'s, not learned again."""
    assert summary["ablations"]["no_time_term"]["params"]["alpha"][2] == 0.0
    rates = summary["ablations"]["no_rate_terms"]["params"]["alpha"]
    assert rates[6] == 0.0 and rates[8] == 0.0
    for key in ("alpha", "upsilon", "omega", "zeta", "mu"):
        assert summary["self_supervised"]["params"][key] == model[key], key
        assert summary["model"][key] == model[key], key


def test_speed_control_names_its_curves_file(pipeline: Pipeline, summary: dict[str, Any]) -> None:
    """The speed-control entry points at ``speed_tradeoff.csv`` beside it, a CSV with the
    reactive and proactive curves; the reduction is a fraction (or null when the curves'
    times do not overlap)."""
    sc = summary["speed_control"]
    assert sc["curves"] == "speed_tradeoff.csv"
    text = (pipeline.ws.report_dir / sc["curves"]).read_text()
    methods = {line.split(",")[0] for line in text.splitlines()[1:]}
    assert {"reactive", "proactive"} <= methods
    red = sc["shock_reduction_at_equal_time"]
    assert red is None or (isinstance(red, float) and red <= 1.0)


# -- scores.parquet ------------------------------------------------------------------------


def test_scores_hold_one_row_per_event_with_the_model_equations(
    pipeline: Pipeline, model: dict[str, Any], scores: pa.Table
) -> None:
    """One row per event of ``tables/events.parquet`` (same keys, split, label and
    ruggedness); every column of ``schemas/tables/scores.json``; ``predicted`` is
    ``r_combined > mu``; ``r_combined`` is eq. (5) with the signed power of
    ``r_left`` and ``r_right`` and the model's zeta; the oracle column is filled (the sample
    is simulated)."""
    ws = pipeline.ws
    schema = load_table_schema("scores")
    assert set(schema.column_names) <= set(scores.column_names)
    for spec in schema.columns:
        if not spec.nullable:
            assert scores.column(spec.name).null_count == 0, spec.name
    events = read_table(ws.events_table, "tables_events")
    assert scores.num_rows == events.num_rows

    def by_key(table: pa.Table, col: str) -> dict[tuple[str, int], Any]:
        return dict(
            zip(
                zip(
                    table.column("log_id").to_pylist(),
                    table.column("event_id").to_pylist(),
                    strict=True,
                ),
                table.column(col).to_pylist(),
                strict=True,
            )
        )

    for col in ("split", "rough", "ruggedness"):
        mine, theirs = by_key(scores, col), by_key(events, col)
        assert len(mine) == scores.num_rows  # no event twice
        assert mine == theirs, col

    r_left, r_right = column(scores, "r_left"), column(scores, "r_right")
    r_comb = column(scores, "r_combined")
    assert np.isfinite(r_comb).all()
    np.testing.assert_allclose(
        r_comb,
        signed_power(r_left, model["zeta"]) + signed_power(r_right, model["zeta"]),
        rtol=1e-12,
        atol=1e-12,
    )
    np.testing.assert_array_equal(column(scores, "predicted").astype(bool), r_comb > model["mu"])
    assert scores.column("oracle").null_count == 0
    for name in ("baseline_all_lasers", *ABLATIONS):
        assert scores.column(name).null_count == 0, name


# -- index.html ----------------------------------------------------------------------------


def test_index_html_shows_every_figure_and_only_files_that_exist(
    pipeline: Pipeline, summary: dict[str, Any]
) -> None:
    """Every file the page links (``src``/``href``) exists in ``report/``; every figure and
    the curves' CSV written there is linked, each log's Fig. 4 among them; the page states
    the run's counts and the self-supervised AUC."""
    report = pipeline.ws.report_dir
    page = (report / "index.html").read_text()
    linked = set(re.findall(r"(?:src|href)\s*=\s*['\"]([^'\"]+)['\"]", page))
    assert linked
    for name in linked:
        assert (report / name).is_file(), name
    written = {p.name for p in report.iterdir() if p.suffix in (".png", ".csv")}
    assert {"roc.png", "speed_tradeoff.png", "speed_tradeoff.csv"} <= written
    assert written <= linked
    fig4 = pipeline.ws.log_dir(pipeline.log_id) / "fig4_z_difference_vs_dt.png"
    if fig4.is_file():
        assert f"{pipeline.log_id}_{fig4.name}" in linked
    assert f"<td>{summary['test_events']}</td>" in page
    assert f"{summary['self_supervised']['auc']:.3f}" in page


# -- reruns and refusals ---------------------------------------------------------------------


def test_evaluating_again_is_up_to_date_and_rewrites_nothing(pipeline: Pipeline) -> None:
    """Same tables, model and configuration: the stage says up to date and touches none of
    its outputs; its record names the model it evaluated."""
    before = report_mtimes(pipeline)
    again = run_stage(EVALUATE, pipeline.ws, default_config())
    assert again.status == "up_to_date"
    assert report_mtimes(pipeline) == before
    record = pipeline.ws.manifest().stage("evaluate")
    assert record is not None
    assert record.inputs["model"] == file_sha256(pipeline.ws.model_path)


def test_a_changed_model_is_refused_not_silently_used(pipeline: Pipeline, tmp_path: Path) -> None:
    """``model.json`` rewritten by hand (another mu) is not the file ``terrain learn``
    wrote: evaluate refuses, with or without ``--overwrite``, naming the file and telling to
    run ``terrain learn``; the report stays the earlier one; the command exits 1 with one
    line."""
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    doc = json.loads(ws.model_path.read_text())
    doc["mu"] = doc["mu"] + 1.0
    ws.model_path.write_text(json.dumps(doc))
    report = {n: file_sha256(ws.report_dir / n) for n in REPORT_FILES}
    for overwrite in (False, True):
        with pytest.raises(ToolkitError, match="run `terrain learn`") as err:
            run_stage(EVALUATE, ws, default_config(), overwrite=overwrite)
        assert err.value.path == ws.model_path
    assert {n: file_sha256(ws.report_dir / n) for n in REPORT_FILES} == report

    result = CliRunner().invoke(main, ["evaluate", "-w", str(ws.root)])
    assert result.exit_code == 1
    line = one_error_line(result.stderr)
    assert "terrain learn" in line and str(ws.model_path) in line
    assert {n: file_sha256(ws.report_dir / n) for n in REPORT_FILES} == report


def test_a_model_learned_from_earlier_tables_is_refused(
    pipeline: Pipeline, model: dict[str, Any], tmp_path: Path
) -> None:
    """The tables are made again after learning (crafted here: one smooth training event
    relabelled rough, recorded as a finished tables run, as ``terrain tables`` after a
    relabelling would). The model in ``model.json`` was learned on the earlier tables (its
    ``training.tables_sha256`` says so): evaluating it against the new labels would report
    a model that never saw them, with the new tables' counts beside the old training's
    rates. Evaluate must refuse, telling to run ``terrain learn``, as every other stage
    refuses inputs made from an earlier version of what it reads."""
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    events = read_table(ws.events_table, "tables_events")
    split, rough = split_and_rough(ws)
    flipped = rough.copy()
    flipped[np.flatnonzero((split == "train") & ~rough)[0]] = True
    rewrite_events_table(ws, with_rough(events, flipped))
    assert model["training"]["tables_sha256"]["tables/events.parquet"] != file_sha256(
        ws.events_table
    )
    with pytest.raises(ToolkitError, match="terrain learn"):
        run_stage(EVALUATE, ws, default_config())


def test_evaluate_has_help() -> None:
    result = CliRunner().invoke(main, ["evaluate", "--help"])
    assert result.exit_code == 0
    assert "--workspace" in result.output and "--overwrite" in result.output


def test_without_a_model_evaluate_refuses_in_one_line(pipeline: Pipeline, tmp_path: Path) -> None:
    """Tables but no ``model.json``: the stage refuses naming the missing model and the verb
    to run; the command exits 1 with one line; no report is rewritten."""
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    ws.model_path.unlink()
    report = {n: file_sha256(ws.report_dir / n) for n in REPORT_FILES}
    with pytest.raises(StageError, match="run `terrain learn` first") as err:
        run_stage(EVALUATE, ws, default_config(), overwrite=True)
    assert err.value.path == ws.model_path

    result = CliRunner().invoke(main, ["evaluate", "-w", str(ws.root)])
    assert result.exit_code == 1
    line = one_error_line(result.stderr)
    assert str(ws.model_path) in line and "terrain learn" in line
    assert {n: file_sha256(ws.report_dir / n) for n in REPORT_FILES} == report


def test_the_model_on_the_closest_laser_alone_is_trained_only_when_asked(
    pipeline: Pipeline, summary: dict[str, Any]
) -> None:
    """Off by default: the row is either the same computation as the model's (and says
    so) or not run, with the reason on the page; never a silent gap."""
    row = summary["model_closest_laser"]
    page = (pipeline.ws.report_dir / "index.html").read_text()
    if row is None:
        assert summary["not_run"]["model_closest_laser"].endswith("model_on_closest_laser)")
        assert "not run: off ([evaluate] model_on_closest_laser)" in page
    else:
        assert row["points"]["same_as"] == "self_supervised"
        assert "model_closest_laser" not in summary["not_run"]


def test_the_closest_laser_is_the_one_seen_last_before_the_training_events(
    pipeline: Pipeline, summary: dict[str, Any]
) -> None:
    """Ranked on every point of the training events (the mean time from scan to event), not
    on the model's sampled patches, whose few other lasers' points come from odd patches."""
    import polars as pl

    ws = pipeline.ws
    events = pl.read_parquet(ws.events_table).filter(pl.col("split") == "train")
    points = pl.read_parquet(ws.event_points_table, columns=["log_id", "event_id", "laser", "t_ns"])
    lead = (
        points.join(events.select("log_id", "event_id", "t_start_ns"), on=["log_id", "event_id"])
        .with_columns(lead_s=(pl.col("t_start_ns") - pl.col("t_ns")) * 1e-9)
        .group_by(pl.col("laser").cast(pl.String))
        .agg(pl.col("lead_s").mean())
        .sort(["lead_s", "laser"])
    )
    assert lead.height > 1  # the sample's five lasers, so the choice means something
    assert summary["closest_laser"] == lead["laser"][0]
    assert summary["baseline_closest_laser"]["points"]["only_laser"] == lead["laser"][0]


@pytest.mark.slow  # end to end: run by .ci/run, left out of the README's command
def test_a_report_killed_mid_write_is_the_old_one(
    pipeline: Pipeline, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Evaluate dying after the new scores are written but before the page: WS/report is
    still the earlier report, every file as it was, nothing of the new one beside it; the
    next evaluate replaces it whole."""
    from toolkit.stages import evaluate as evaluate_stage

    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    before = {p.name: file_sha256(p) for p in ws.report_dir.iterdir()}

    def killed(*args: Any, **kwargs: Any) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(evaluate_stage, "write_index_html", killed)
    with pytest.raises(KeyboardInterrupt):
        run_stage(EVALUATE, ws, default_config(), overwrite=True)
    assert {p.name: file_sha256(p) for p in ws.report_dir.iterdir()} == before
    monkeypatch.undo()
    (ws.report_dir / "old_figure.png").write_bytes(b"a figure no run draws any more")
    run_stage(EVALUATE, ws, default_config(), overwrite=True)
    # Made from nothing: the stale figure is gone, every file of a run is there.
    assert sorted(p.name for p in ws.report_dir.iterdir()) == sorted(before)
    gens = [p for p in ws.root.iterdir() if p.name.startswith(".report.") and p.suffix == ".gen"]
    assert gens == [ws.report_dir.resolve()]  # the current report alone, nothing left over


def test_a_failed_learn_inside_run_says_evaluate_was_not_run(
    pipeline: Pipeline, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``terrain run`` whose learn fails: its line, then a line saying online and evaluate
    were not run because of it (as a per-log stage no log reached says so), exit 1 with the
    cause."""
    import dataclasses

    from toolkit.stages import learn

    ws = copy_workspace(pipeline.ws, tmp_path / "ws")

    def fail(call: Any) -> Any:
        raise StageError("no pair of events to learn from", path=ws.root)

    monkeypatch.setattr(learn, "SPEC", dataclasses.replace(learn.SPEC, compute=fail))
    from tests.conftest import SAMPLE_LOG

    args = ["run", str(SAMPLE_LOG), "-w", str(ws.root), "--from", "learn", "--overwrite"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 1, result.output
    lines = result.stdout.splitlines()
    assert any(line.startswith("learn") and "1 failed" in line for line in lines), lines
    assert "online, evaluate not run: learn failed (its error is below)" in lines
    assert "no pair of events to learn from" in result.stderr


def test_run_says_each_stage_once_as_it_ends_after_its_warnings(
    pipeline: Pipeline, tmp_path: Path
) -> None:
    """``terrain run ... 2>&1 | tee``: each stage's line once (on stdout, as the stage
    ends), its warnings before it, then the totals; with --json, stdout is the JSON alone."""
    from tests.conftest import SAMPLE_LOG

    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    args = ["run", str(SAMPLE_LOG), "-w", str(ws.root), "--from", "tables", "--to", "learn"]
    result = CliRunner().invoke(main, [*args, "--overwrite"])
    assert result.exit_code == 0, result.output
    merged = result.output.splitlines()  # stdout and stderr as a terminal shows them

    def said(stage: str) -> list[int]:  # the stage's line, with a prefix or without
        return [k for k, line in enumerate(merged) if re.search(rf"\b{stage} +[\d.]+ s ", line)]

    tables, learn = said("tables"), said("learn")
    assert len(tables) == 1 and len(learn) == 1, merged
    warned = [k for k, line in enumerate(merged) if "events dropped" in line]
    assert warned and max(warned) < tables[0] < learn[0]
    out = result.stdout.splitlines()
    assert [line.split()[0] for line in out] == ["tables", "learn", "run:"]
    doc = CliRunner().invoke(main, [*args, "--json"])
    assert doc.exit_code == 0 and json.loads(doc.stdout)["stages"]


def _report_bytes(root: Path) -> dict[str, bytes]:
    report = root / "report"
    return {p.name: p.read_bytes() for p in sorted(report.iterdir()) if p.is_file()}


@pytest.mark.slow  # one more evaluation of the sample (~15 s); run by .ci/run
def test_rows_trained_on_two_cores_make_the_same_report_as_on_one(
    pipeline: Pipeline, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The shared pipeline's report was made with the default two workers; made again one
    row at a time, it is the same, file for file."""
    assert evaluate_rows.ROW_WORKERS == 2
    ws = copy_workspace(pipeline.ws, tmp_path / "ws")
    monkeypatch.setattr(evaluate_rows, "ROW_WORKERS", 1)
    run_stage(EVALUATE, ws, default_config(), overwrite=True)
    alone, both = _report_bytes(ws.root), _report_bytes(pipeline.ws.root)
    assert {"summary.json", "scores.parquet", "index.html", "roc.png"} <= set(both)
    assert alone == both
