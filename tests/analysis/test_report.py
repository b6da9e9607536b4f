"""The report's ROC figure (its drawn area is the table's AUC) and ``index.html`` (warnings
at the top, each method's share of events scored 0 next to its AUC)."""

from __future__ import annotations

import html
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from matplotlib.cbook import STEP_LOOKUP_MAP

from toolkit.analysis import figures
from toolkit.analysis.method_registry import method, title
from toolkit.analysis.report import (
    ReportInputs,
    index_html,
    roc_lines,
    roc_png,
)
from toolkit.model.roc import RocSummary, summarise

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def tied_summary(seed: int, n: int = 3000) -> RocSummary:
    """A method scoring exactly 0 on about 95 % of ``n`` events (rough ones among them)
    and nothing on 2 %, about 5 % of the events rough: one large tie at the bottom."""
    rng = np.random.default_rng(seed)
    y = rng.random(n) < 0.05
    s = np.where(rng.random(n) < 0.95, 0.0, rng.random(n))
    s[y] = np.where(rng.random(y.sum()) < 0.5, 0.0, rng.random(y.sum()) + 0.3)
    s[rng.random(n) < 0.02] = np.nan
    return summarise(s, y, np.nan_to_num(s), resamples=20, seed=seed)


def drawn_lines(
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    curves: dict[str, Any],
    aucs: dict[str, float | None] | None = None,
) -> dict[str, np.ndarray]:
    """Draw ``curves`` with :func:`roc_png` and return, by legend label, the vertices (K, 2)
    of each line as rendered: a line's data with its draw style applied (a staircase's
    corners included)."""
    drawn: list[Figure] = []
    save = figures.save_png_atomic

    def keep(fig: Figure, path: Path) -> Path:
        drawn.append(fig)
        return save(fig, path)

    monkeypatch.setattr("toolkit.analysis.report.save_png_atomic", keep)
    png = roc_png(tmp_path / "roc.png", curves, aucs or {})
    assert png.is_file() and png.stat().st_size > 0
    (ax,) = drawn[0].axes
    out = {}
    for line in ax.get_lines():
        x, y = np.asarray(line.get_xydata(), np.float64).T
        sx, sy = STEP_LOOKUP_MAP[line.get_drawstyle()](x, y)
        out[str(line.get_label())] = np.column_stack([sx, sy])
    return out


def test_the_drawn_roc_encloses_the_tables_auc_under_heavy_ties(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """With 95 % of the scores tied at 0, the area under each line as drawn equals the AUC
    the summary states (and the page's table shows), to 1e-9: a tie between rough and
    smooth events is drawn as one diagonal segment, as scikit-learn draws it, not as a
    step along the FPR axis and then up."""
    summaries = {"self_supervised": tied_summary(0), "no_learning": tied_summary(1)}
    aucs = {k: v.auc for k, v in summaries.items()}
    lines = drawn_lines(monkeypatch, tmp_path, {k: v.curve for k, v in summaries.items()}, aucs)
    for name, summary in summaries.items():
        v = lines[f"{title(name)} (AUC {summary.auc:.3f})"]
        assert summary.zero_share > 0.9
        assert float(np.trapezoid(v[:, 1], v[:, 0])) == pytest.approx(summary.auc, abs=1e-9)
    assert "chance" in lines


def test_the_roc_figure_merges_identical_curves_and_keeps_each_methods_look(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Two methods with the same curve are one line naming both (the second no longer
    hides under the first); every label carries its AUC; a method keeps its colour
    whatever rows the run has; the headline is drawn last, thickest, in black."""
    a, b = tied_summary(0), tied_summary(1)
    curves = {
        "self_supervised": a.curve,
        "baseline_closest_laser": b.curve,
        "model_closest_laser": a.curve,  # the same points as the headline
        "no_learning": b.curve,  # the same points as the race's test
    }
    aucs = {"self_supervised": a.auc, "baseline_closest_laser": b.auc}
    lines = roc_lines(curves, aucs | {"model_closest_laser": a.auc, "no_learning": b.auc})
    assert [d.names for d in lines] == [
        ("baseline_closest_laser", "no_learning"),
        ("self_supervised", "model_closest_laser"),
    ]
    head = lines[-1]
    assert head.color == "black" and head.linewidth > lines[0].linewidth
    assert head.label == (
        f"{title('self_supervised')} = {title('model_closest_laser')} (AUC {a.auc:.3f})"
    )
    alone = roc_lines({"no_learning": a.curve}, {"no_learning": a.auc})
    assert alone[0].color == method("no_learning").color != lines[0].color
    drawn = drawn_lines(monkeypatch, tmp_path, curves, aucs)
    assert len(drawn) == 3  # two merged lines and chance


def page(summary: dict[str, Any]) -> str:
    return index_html(ReportInputs(summary=summary, model={}, roc_figures=[], speed_files=[]))


def row_of(text: str, method: str) -> str:
    """The ROC table's row of ``method`` (its key in the method registry)."""
    name = html.escape(title(method))
    (row,) = re.findall(rf"<tr><td>{re.escape(name)}</td>.*?</tr>", text)
    return str(row)


def test_index_html_shows_the_zero_share_next_to_the_auc() -> None:
    """A method's row: name, AUC with its interval, its start's AUC ("-" without one), then
    the shares scored 0 and unscored (all events / rough ones, in %), then TPR at each FPR,
    Spearman and the points it scored. A method not evaluated spans every column; a summary
    written before the shares existed shows n/a."""
    entry: dict[str, Any] = tied_summary(0).to_json()
    old = {k: v for k, v in entry.items() if "share" not in k}
    text = page(
        {
            "self_supervised": entry,
            "oracle": None,
            "model_closest_laser": None,
            "not_run": {"model_closest_laser": "off ([evaluate] model_on_closest_laser)"},
            "ablations": {"no_learning": old},
            "test_events": 3000,
        }
    )
    cells = re.findall(r"<td[^>]*>(.*?)</td>", row_of(text, "self_supervised"))
    assert cells[1].startswith(f"{entry['auc']:.3f} [")
    assert cells[2] == "-"  # no start_auc in this entry
    assert (
        cells[3] == f"{100 * entry['zero_share']:.1f} % / {100 * entry['zero_share_rough']:.1f} %"
    )
    assert cells[4] == (
        f"{100 * entry['unscored_share']:.1f} % / {100 * entry['unscored_share_rough']:.1f} %"
    )
    assert len(cells) == 1 + 4 + len(entry["tpr_at_fpr"]) + 2
    assert cells[-1] == "n/a"  # this entry does not say which points it scored
    assert re.findall(r"<th>(.*?)</th>", text)[3:9] == [
        "method",
        "AUC",
        "its start (learning)",
        "score 0: all / rough",
        "unscored: all / rough",
        "TPR at FPR 0.05",
    ]
    assert "colspan='9'>not evaluated" in row_of(text, "oracle")
    # A row left out on purpose says why.
    assert "not run: off ([evaluate] model_on_closest_laser)" in row_of(text, "model_closest_laser")
    assert "<td>n/a / n/a</td><td>n/a / n/a</td>" in row_of(text, "no_learning")


def test_every_learned_row_shows_its_start_and_says_when_learning_did_not_help() -> None:
    """A row with a start shows the start's test AUC and the difference; the conclusion
    names each learned row (besides the headline) not above its start, and says so when
    every one is."""
    entry: dict[str, Any] = tied_summary(0).to_json()
    auc = float(entry["auc"])
    rows = {
        "self_supervised": {**entry, "start_auc": auc - 0.02},
        "oracle": {**entry, "start_auc": auc + 0.01},
        "ablations": {"no_time_term": {**entry, "start_auc": auc - 0.05}},
        "test_events": 3000,
    }
    text = page(rows)
    cells = re.findall(r"<td[^>]*>(.*?)</td>", row_of(text, "oracle"))
    assert cells[2] == f"{auc + 0.01:.3f} (-0.010)"
    assert re.findall(r"<td[^>]*>(.*?)</td>", row_of(text, "no_time_term"))[2] == (
        f"{auc - 0.05:.3f} (+0.050)"
    )
    said = re.findall(r"<p class='conclusion'>(.*?)</p>", text)[0]
    assert "did not help 1 of the other 2 learned rows" in said
    assert html.escape(title("oracle")) in said and title("no_time_term") not in said
    rows["oracle"] = {**entry, "start_auc": auc - 0.001}
    said = re.findall(r"<p class='conclusion'>(.*?)</p>", page(rows))[0]
    assert "Every other learned row (2) ends above its own start." in said


def test_index_html_puts_the_warnings_first() -> None:
    """The run's warnings, escaped, in a box right under the title, before any number;
    no box when there is none."""
    warnings = ["the test split has 6 rough events (fewer than 30): <noise>", "no oracle"]
    text = page({"warnings": warnings, "test_events": 10})
    box = text.index("<h2>Warnings</h2>")
    assert text.index("<h1>") < box < text.index("<h2>Events</h2>")
    assert "&lt;noise&gt;</li>" in text and "<li>no oracle</li>" in text
    assert text.count("<h2>Warnings</h2>") == 1
    assert "Warnings" not in page({"warnings": [], "test_events": 10})


def test_the_page_concludes_in_words_with_intervals_and_says_when_learning_did_not_help() -> None:
    """Under the table, a conclusion: the model against the race's test on the closest
    laser, with both intervals and whether they overlap; and the model against its own
    unlearned start, "did not help" when it is not above it (the sample: 0.869 < 0.895)."""
    rates = {"tpr_at_fpr": {"0.1": 0.5}, "tpr_at_fpr_ci95": {"0.1": [0.3, 0.7]}}
    summary: dict[str, Any] = {
        "test_events": 435,
        "test_positives": 6,
        "self_supervised": {"auc": 0.869, "auc_ci95": [0.781, 0.946], **rates},
        "baseline_closest_laser": {"auc": 0.809, "auc_ci95": [0.70, 0.90], **rates},
        "ablations": {"no_learning": {"auc": 0.895, "auc_ci95": [0.80, 0.96], **rates}},
    }
    text = " ".join(page(summary).split())
    assert (
        "The learned model's test AUC is 0.869 (95 % interval 0.781-0.946), above the race's "
        "obstacle test on the closest laser, 0.809 (95 % interval 0.700-0.900), but the "
        "intervals overlap: this test split cannot tell the two apart (6 rough events among "
        "435)." in text
    )
    assert "<b>Learning did not help here</b>" in text and "(-0.026)" in text
    summary["baseline_closest_laser"]["auc_ci95"] = [0.60, 0.75]
    summary["ablations"]["no_learning"]["auc"] = 0.850
    text = " ".join(page(summary).split())
    assert "and the intervals do not overlap" in text
    assert "Learning helped: the model is 0.019 above its own unlearned start" in text
    assert "did not help" not in text


def test_the_speed_control_result_is_stated_at_a_time_budget_with_its_count() -> None:
    """Not only the best point of the sweep: the reduction within 1.25x and 1.5x the drive
    time, the largest with its time, and the shocks it rests on (few: said)."""
    from toolkit.analysis.report import speed_headline

    sp = {
        "no_change": {"shocks_over_floor": 11},
        "reductions_along_reactive_front": [
            {"time_norm": 1.2, "reduction": 0.31},
            {"time_norm": 1.4, "reduction": 0.42},
            {"time_norm": 1.9, "reduction": 0.80},
        ],
    }
    text = speed_headline(sp)
    assert "within 1.25x the drive time, 31 %; within 1.5x the drive time, 42 %" in text
    assert "the largest, 80 %, at 1.90x the drive time" in text
    assert "11 shock(s)" in text and "too few" in text
    sp["no_change"]["shocks_over_floor"] = 120
    assert "too few" not in speed_headline(sp)
    assert "n/a" in speed_headline({})
    assert "faint point is one setting" in page({"speed_control": sp})


def test_the_page_says_first_where_its_numbers_come_from() -> None:
    """Simulated or recorded (which logs), the configuration, the toolkit's version: at the
    top; and why Fig. 5 is missing when no log is a calibration drive."""
    summary: dict[str, Any] = {
        "toolkit_version": "9.9",
        "provenance": {
            "logs": [
                {"log_id": "sample-1", "source": "/data/sample.mcap", "kind": "simulated"},
            ],
            "configuration": {"name": "stanley2005"},
        },
    }
    text = index_html(
        ReportInputs(
            summary=summary,
            model={},
            roc_figures=[],
            speed_files=[],
            log_figures=[("Fig. 4 analogue: sample-1", "sample-1_fig4.png")],
        )
    )
    head = text.split("<h2>")[0]
    assert "From <b>simulated data</b>: 1 log(s) of the toolkit's simulator" in head
    assert "<code>sample-1</code> (sample.mcap)" in head and "stanley2005" in head
    assert "terrain 9.9" in head
    assert "no log here is one" in text  # Fig. 5 needs a calibration drive
    summary["provenance"]["logs"][0]["kind"] = "recorded"
    assert "1 recorded log(s)" in page(summary) and "simulated" not in page(summary)
