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
from toolkit.analysis.report import METHOD_NAMES, ReportInputs, index_html, roc_png
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
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, curves: dict[str, Any]
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
    png = roc_png(tmp_path / "roc.png", curves)
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
    lines = drawn_lines(monkeypatch, tmp_path, {k: v.curve for k, v in summaries.items()})
    for name, summary in summaries.items():
        v = lines[METHOD_NAMES[name]]
        assert summary.zero_share > 0.9
        assert float(np.trapezoid(v[:, 1], v[:, 0])) == pytest.approx(summary.auc, abs=1e-9)
    assert "chance" in lines


def page(summary: dict[str, Any]) -> str:
    return index_html(ReportInputs(summary=summary, model={}, roc_figures=[], speed_files=[]))


def row_of(text: str, method: str) -> str:
    """The ROC table's row of ``method`` (its key in METHOD_NAMES)."""
    name = html.escape(METHOD_NAMES[method])
    (row,) = re.findall(rf"<tr><td>{re.escape(name)}</td>.*?</tr>", text)
    return str(row)


def test_index_html_shows_the_zero_share_next_to_the_auc() -> None:
    """A method's row: name, AUC with its interval, then the shares scored 0 and unscored
    (all events / rough ones, in %), then TPR at each FPR, Spearman and the points it
    scored. A method not
    evaluated spans every column; a summary written before the shares existed shows
    n/a."""
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
    assert (
        cells[2] == f"{100 * entry['zero_share']:.1f} % / {100 * entry['zero_share_rough']:.1f} %"
    )
    assert cells[3] == (
        f"{100 * entry['unscored_share']:.1f} % / {100 * entry['unscored_share_rough']:.1f} %"
    )
    assert len(cells) == 1 + 3 + len(entry["tpr_at_fpr"]) + 2
    assert cells[-1] == "n/a"  # this entry does not say which points it scored
    assert re.findall(r"<th>(.*?)</th>", text)[3:8] == [
        "method",
        "AUC",
        "score 0: all / rough",
        "unscored: all / rough",
        "TPR at FPR 0.05",
    ]
    assert "colspan='8'>not evaluated" in row_of(text, "oracle")
    # A row left out on purpose says why.
    assert "not run: off ([evaluate] model_on_closest_laser)" in row_of(text, "model_closest_laser")
    assert "<td>n/a / n/a</td><td>n/a / n/a</td>" in row_of(text, "no_learning")


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
