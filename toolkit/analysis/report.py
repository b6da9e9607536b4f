"""The evaluation report: the ROC figure (Fig. 6 analogue) and ``report/index.html``.

The HTML is a single static page, readable without the code: what was compared, on which
events, the ROC table with its confidence intervals, the learned parameters with what each
means in eq. (3)-(5), the speed-control result, and the figures. Every number on it is read
from ``summary.json`` and ``model.json`` of the same run; nothing is typed in.
"""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from toolkit.analysis.figures import new_figure, save_png_atomic, write_bytes_atomic
from toolkit.analysis.method_registry import (
    HEADLINE,
    METHOD_KEYS,
    RACE_TEST,
    UNLEARNED_START,
    UnknownMethodError,
    method,
    title,
)
from toolkit.analysis.online_page import online_section

#: What the search's steps had to raise (``model.json``'s ``accepted_by``), in words.
_ACCEPTED = {
    "objective": "eq. (6), Tp - lambda Fp (the paper's)",
    "auc": "the area under the ROC curve",
    "pauc": "the area under the ROC curve up to FPR 0.2",
}

#: What each learned parameter does (eqs. 3-5), for the parameter table.
PARAMETER_MEANINGS: tuple[tuple[str, str], ...] = (
    (
        "alpha_1, alpha_2",
        "weight and exponent of the height difference |z_r - z_c| (evidence for roughness)",
    ),
    (
        "alpha_3, alpha_4",
        "weight and exponent of the time between the two observations "
        "(penalty: pose error grows with it, Fig. 4)",
    ),
    (
        "alpha_5, alpha_6",
        "weight and exponent of the horizontal distance between the points (penalty)",
    ),
    ("alpha_7, alpha_8", "weight and exponent of each point's roll rate (penalty)"),
    ("alpha_9, alpha_10", "weight and exponent of each point's pitch rate (penalty)"),
    (
        "alpha_11, alpha_12",
        "beyond the paper, only with [learn] lead_term: weight and exponent of how long "
        "before the event each point was seen (penalty: a far laser's error grows with range)",
    ),
    ("upsilon", "growth of the weight of successive scores in R = sum W_i upsilon^i (eq. 3)"),
    ("omega", "how many of the largest pair scores enter R (eq. 3)"),
    ("zeta", "exponent combining the tyres, R_combined = R_left^zeta + R_right^zeta (eq. 5)"),
    ("mu", "threshold: rough when R_combined > mu"),
)


@dataclass(frozen=True)
class Drawn:
    """One line of the ROC figure: the methods whose curves are the same points (shown
    once, named together), its legend label with the AUC, and its style."""

    names: tuple[str, ...]
    label: str
    color: str
    linestyle: str
    linewidth: float
    zorder: int


def _style(key: str) -> tuple[str, str]:
    """A method's colour and line style; grey for a row no method declares (an old
    summary's)."""
    try:
        m = method(key)
    except UnknownMethodError:
        return "tab:gray", "-"
    return m.color, m.linestyle


def roc_lines(curves: Mapping[str, Any], aucs: Mapping[str, float | None]) -> list[Drawn]:
    """The figure's lines, in drawing order: curves that are the same points merged into
    one line naming every method (identical curves would hide each other), each labelled
    with its AUC, the headline's line last (on top), thicker."""
    groups: list[list[str]] = []
    for name, curve in curves.items():
        for group in groups:
            first = curves[group[0]]
            if np.array_equal(first.fpr, curve.fpr) and np.array_equal(first.tpr, curve.tpr):
                group.append(name)
                break
        else:
            groups.append([name])
    lines = []
    for group in groups:
        # The line takes the style of its most important method: the headline, else the
        # first in the report's order.
        lead = HEADLINE if HEADLINE in group else group[0]
        color, linestyle = _style(lead)
        auc = aucs.get(lead)
        names = " = ".join(title(n) for n in group)
        label = f"{names} (AUC {auc:.3f})" if auc is not None else names
        top = HEADLINE in group
        lines.append(
            Drawn(tuple(group), label, color, linestyle, 2.6 if top else 1.3, 3 if top else 2)
        )
    return sorted(lines, key=lambda d: d.zorder)


def roc_png(
    path: Path,
    curves: Mapping[str, Any],
    aucs: Mapping[str, float | None],
    title: str = "Fig. 6 analogue: ROC on the test split",
) -> Path:
    """The ROC curves of each method, one figure: objects with ``fpr`` and ``tpr`` arrays
    (K,), scikit-learn's points with every threshold kept (``toolkit.model.roc.RocCurve``),
    and each method's AUC; drawn as :func:`roc_lines` says, the legend beside the axes (it
    covered the curves' lower left inside them).

    Consecutive points are joined by straight lines, as scikit-learn draws them: a tie
    between rough and smooth events (many events score exactly 0) is one diagonal segment,
    so the area under the drawn line is the AUC in the table beside it. A staircase would
    draw each tie's FPR rise before its TPR rise and, with a large tie, lose much of that
    area (the tie counts half in the AUC, as the Mann-Whitney counts it).
    """
    fig = new_figure(11.0, 5.5)
    ax = fig.add_axes((0.07, 0.1, 0.45, 0.8))
    for line in roc_lines(curves, aucs):
        curve = curves[line.names[0]]
        ax.plot(
            curve.fpr,
            curve.tpr,
            color=line.color,
            linestyle=line.linestyle,
            linewidth=line.linewidth,
            zorder=line.zorder,
            label=line.label,
        )
    ax.plot([0, 1], [0, 1], color="0.7", linewidth=0.8, label="chance", zorder=1)
    ax.set_xlabel("false-positive rate")
    ax.set_ylabel("true-positive rate")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.01)
    ax.set_title(title)
    handles, labels = ax.get_legend_handles_labels()
    # The legend lists the headline first (it is drawn last, to lie on top).
    order = sorted(range(len(labels)), key=lambda k: 0 if handles[k].get_zorder() == 3 else 1)
    ax.legend(
        [handles[k] for k in order],
        [labels[k] for k in order],
        loc="upper left",
        bbox_to_anchor=(1.03, 1.0),
        fontsize=7,
        frameon=False,
    )
    ax.grid(alpha=0.3)
    return save_png_atomic(fig, path)


@dataclass(frozen=True)
class ReportInputs:
    """What the page shows: the run's summary and model documents, figure file names (in
    the report directory), and copied per-log figures as (caption, file name)."""

    summary: Mapping[str, Any]
    model: Mapping[str, Any]
    roc_figures: Sequence[str]
    speed_files: Sequence[str]
    log_figures: Sequence[tuple[str, str]] = field(default=())
    #: Learning while driving's figure, when the workspace has an online replay.
    online_figure: str | None = None


def _fmt(v: Any, digits: int = 3) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return html.escape(str(v))


def _share_pair(m: Mapping[str, Any], key: str) -> str:
    """``"all % / rough %"`` of the share ``key`` and ``key + "_rough"`` of a method's
    entry; n/a for a share the entry lacks (a summary written before it was stated)."""

    def pct(v: Any) -> str:
        return "n/a" if v is None else f"{100 * v:.1f} %"

    return f"{pct(m.get(key))} / {pct(m.get(key + '_rough'))}"


def _roc_rows(summary: Mapping[str, Any], n_fprs: int) -> list[str]:
    """The ROC table's rows: method, AUC [CI], share scored 0, share unscored, TPR at each
    of the ``n_fprs`` FPRs [CI], Spearman."""
    rows = []
    ablations = summary.get("ablations") or {}
    entries: list[tuple[str, Any]] = [
        (k, summary.get(k)) for k in METHOD_KEYS if k not in ablations and k in summary
    ]
    entries += list(ablations.items())
    for key, m in entries:
        name = html.escape(title(key))
        if not m:
            why = (summary.get("not_run") or {}).get(key)
            text = f"not run: {html.escape(why)}" if why else "not evaluated"
            rows.append(f"<tr><td>{name}</td><td colspan='{n_fprs + 6}'>{text}</td></tr>")
            continue
        ci = m.get("auc_ci95") or [None, None]
        cells = [
            f"{_fmt(m['auc'])} [{_fmt(ci[0])}, {_fmt(ci[1])}]",
            _start_cell(m),
            _share_pair(m, "zero_share"),
            _share_pair(m, "unscored_share"),
        ]
        for fpr, tpr in m["tpr_at_fpr"].items():
            lo, hi = (m.get("tpr_at_fpr_ci95") or {}).get(fpr, [None, None])
            cells.append(f"{_fmt(tpr, 2)} [{_fmt(lo, 2)}, {_fmt(hi, 2)}]")
        cells.append(_fmt(m.get("spearman_vs_ruggedness")))
        cells.append(html.escape(_points_text(m.get("points"))))
        rows.append(f"<tr><td>{name}</td>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    return rows


def _start_cell(m: Mapping[str, Any]) -> str:
    """A learned row's start, unlearned: its test AUC and what learning added ("-" for a
    row without a start)."""
    start = m.get("start_auc")
    if start is None or m.get("auc") is None:
        return "-"
    return f"{_fmt(start)} ({float(m['auc']) - float(start):+.3f})"


def _points_text(points: Mapping[str, Any] | None) -> str:
    """Which laser points a method scored, in words (``entry["points"]`` of the summary)."""
    if not points:
        return "n/a"
    sample = {
        "hash": "uniform sample of all lasers",
        "nearest_laser": "nearest laser first",
        "freshest": "seen last first",
    }.get(str(points.get("sample")), str(points.get("sample")))
    text = f"{points['only_laser']} only" if points.get("only_laser") else sample
    if points.get("same_as"):
        text += f" (the same points as {title(points['same_as'])})"
    return f"{text}; true heights" if points.get("z") else text


def _warnings_box(warnings: Sequence[Any] | None) -> list[str]:
    """The run's warnings (``summary["warnings"]``) in a framed box, for the top of the
    page: each qualifies the numbers below it (a small split, a missing oracle), so it is
    read before them. Nothing when there is none."""
    if not warnings:
        return []
    return [
        "<div class='warnings' style='border:2px solid #c60;background:#fff4e5;"
        "padding:.2em 1em;margin:1em 0'><h2>Warnings</h2><ul>",
        *[f"<li>{html.escape(str(w))}</li>" for w in warnings],
        "</ul></div>",
    ]


def _page_head(s: Mapping[str, Any]) -> list[str]:
    """The page's head, title, warnings and what is reproduced."""
    return [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        "<title>terrain: evaluation report</title>",
        "<style>body{font-family:sans-serif;max-width:60em;margin:2em auto;line-height:1.4}"
        "table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left}"
        "img{max-width:100%}</style></head><body>",
        "<h1>Terrain roughness: evaluation report</h1>",
        *_provenance(s),
        *_warnings_box(s.get("warnings")),
        "<p>A reproduction of Stavens &amp; Thrun (2006), <i>A Self-Supervised Terrain Roughness "
        "Estimator for Off-Road Autonomous Driving</i>. Each event is a 1.4 m stretch of the rear "
        "axle's path; it is <b>rough</b> when the shock the IMU felt there divided by the speed "
        "(its ruggedness) is at least the label threshold. Every method scores the laser points "
        "seen ahead of the rear tyres before the vehicle got there; the learned model's "
        "parameters come from the training split only; everything below is on the test split "
        "unless it says otherwise.</p>",
    ]


def _provenance(s: Mapping[str, Any]) -> list[str]:
    """Where the numbers come from, first: simulated or recorded logs (which), the
    configuration and the toolkit's version; a report of simulated data says so."""
    prov = s.get("provenance")
    if not isinstance(prov, Mapping):
        return []
    logs = [g for g in prov.get("logs") or [] if isinstance(g, Mapping)]
    simulated = sum(g.get("kind") == "simulated" for g in logs)
    recorded = len(logs) - simulated
    if logs and simulated == len(logs):
        kind = f"<b>simulated data</b>: {simulated} log(s) of the toolkit's simulator"
    elif simulated:
        kind = f"{recorded} recorded and <b>{simulated} simulated</b> log(s)"
    else:
        kind = f"{recorded} recorded log(s)"
    names = ", ".join(
        f"<code>{html.escape(str(g.get('log_id')))}</code> "
        f"({html.escape(Path(str(g.get('source') or '')).name or 'source unknown')})"
        for g in logs
    )
    cfg = prov.get("configuration") or {}
    return [
        f"<p class='provenance'>From {kind}: {names}. Configuration "
        f"<code>{_fmt(cfg.get('name'))}</code>; terrain {_fmt(s.get('toolkit_version'))}.</p>"
    ]


def _events_section(s: Mapping[str, Any]) -> list[str]:
    """The events and rough events of each split."""
    return [
        "<h2>Events</h2><table><tr><th>split</th><th>events</th><th>rough</th></tr>",
        f"<tr><td>train</td><td>{s.get('train_events')}</td><td>{s.get('train_positives')}</td></tr>",
        f"<tr><td>test</td><td>{s.get('test_events')}</td><td>{s.get('test_positives')}</td></tr></table>",
    ]


def _roc_section(s: Mapping[str, Any], roc_figures: Sequence[str]) -> list[str]:
    """Fig. 6's analogue: the ROC table (columns: the FPRs of the first method evaluated)
    and the ROC figures."""
    entries = [s.get(k) for k in METHOD_KEYS] + list((s.get("ablations") or {}).values())
    fprs = next((list(v["tpr_at_fpr"]) for v in entries if isinstance(v, Mapping)), [])
    head = "".join(f"<th>TPR at FPR {html.escape(f)}</th>" for f in fprs)
    return [
        "<h2>Sensitivity against specificity (Fig. 6)</h2>",
        "<p>Area under the ROC curve and true-positive rate at fixed false-positive rates, with "
        "95 % intervals from a stratified bootstrap over test events; the last column is "
        "Spearman's rank correlation between the score and the ruggedness. The race's obstacle "
        "test generates the pair scores of the baselines, with their own trained upsilon, "
        f"omega, zeta and mu (sect. 7.1); its closest laser here: "
        f"<code>{_fmt(s.get('closest_laser'))}</code>.</p>",
        "<p><i>Score 0</i> is the share of the events a method scored whose score is exactly "
        "0, over all of them / over the rough ones; <i>unscored</i> the share it could not "
        "score (e.g. no laser point under a tyre), over all events / over the rough ones, ranked "
        "below every score. Each is one tie: the method does not rank the events in it, and "
        "its ROC curve crosses them as one straight segment (the AUC counts a tied rough and "
        "smooth pair as half a win).</p>",
        "<p><i>Its start</i> is a learned row's test AUC with the parameters its search began "
        "from, unlearned, and in brackets what learning added to it.</p>",
        "<table><tr><th>method</th><th>AUC</th><th>its start (learning)</th>"
        "<th>score 0: all / rough</th>"
        f"<th>unscored: all / rough</th>{head}<th>Spearman</th><th>points scored</th></tr>",
        *_roc_rows(s, len(fprs)),
        "</table>",
        *conclusion(s),
        *[f"<p><img src='{html.escape(f)}' alt='ROC curves'></p>" for f in roc_figures],
    ]


def _auc_with_interval(entry: Mapping[str, Any]) -> str:
    lo, hi = (entry.get("auc_ci95") or [None, None])[:2]
    return f"{_fmt(entry.get('auc'))} (95 % interval {_fmt(lo)}-{_fmt(hi)})"


def conclusion(s: Mapping[str, Any]) -> list[str]:
    """What the table says, in words: whether the learned model beats the race's obstacle
    test on its closest laser (the paper's comparison, Fig. 6), with both intervals and
    whether they overlap; and whether learning helped, against the model's own unlearned
    start (the ``no_learning`` row), said plainly when it did not."""
    model = s.get(HEADLINE)
    if not isinstance(model, Mapping) or model.get("auc") is None:
        return []
    said: list[str] = []
    race = s.get(RACE_TEST)
    if isinstance(race, Mapping) and race.get("auc") is not None:
        ours, theirs = float(model["auc"]), float(race["auc"])
        lo, hi = model.get("auc_ci95") or (ours, ours)
        rlo, rhi = race.get("auc_ci95") or (theirs, theirs)
        apart = None not in (lo, hi, rlo, rhi) and (lo > rhi or hi < rlo)
        verdict = "above" if ours > theirs else ("equal to" if ours == theirs else "below")
        how = (
            "and the intervals do not overlap"
            if apart
            else "but the intervals overlap: this test split cannot tell the two apart"
        )
        said.append(
            f"The learned model's test AUC is {_auc_with_interval(model)}, {verdict} the race's "
            f"obstacle test on the closest laser, {_auc_with_interval(race)}, {how} "
            f"({_fmt(s.get('test_positives'))} rough events among {_fmt(s.get('test_events'))})."
        )
    start = (s.get("ablations") or {}).get(UNLEARNED_START)
    if isinstance(start, Mapping) and start.get("auc") is not None:
        gain = float(model["auc"]) - float(start["auc"])
        if gain > 0:
            said.append(
                f"Learning helped: the model is {gain:.3f} above its own unlearned start "
                f"({_auc_with_interval(start)})."
            )
        else:
            said.append(
                f"<b>Learning did not help here</b>: the learned model is not above its own "
                f"unlearned start, {_auc_with_interval(start)} ({gain:+.3f}); what the table "
                "shows of it is the hand-set starting guess, not what was learned."
            )
    said += _learning_elsewhere(s)
    return [f"<p class='conclusion'>{' '.join(said)}</p>"] if said else []


def _learning_elsewhere(s: Mapping[str, Any]) -> list[str]:
    """Whether learning helped the other learned rows (each against its own start's test
    AUC), named when it did not."""
    entries = [(k, s.get(k)) for k in METHOD_KEYS if k != HEADLINE]
    entries += list((s.get("ablations") or {}).items())
    judged = [
        (key, float(m["auc"]), float(m["start_auc"]))
        for key, m in entries
        if isinstance(m, Mapping) and m.get("auc") is not None and m.get("start_auc") is not None
    ]
    if not judged:
        return []
    failed = [
        f"{html.escape(title(key))}, {ours:.3f} against {start:.3f} ({ours - start:+.3f})"
        for key, ours, start in judged
        if ours <= start
    ]
    if not failed:
        return [f"Every other learned row ({len(judged)}) ends above its own start."]
    return [
        f"<b>Learning did not help {len(failed)} of the other {len(judged)} learned rows</b> "
        f"(test AUC against their start's): {'; '.join(failed)}."
    ]


def _model_section(s: Mapping[str, Any], m: Mapping[str, Any]) -> list[str]:
    """The learned model (sect. 4 and 6): how the search of eqs. (6)-(7) ended, the
    parameters of eqs. (3)-(5) and what each means."""
    alpha = m.get("alpha", [])
    params = [("alpha_" + str(i + 1), a) for i, a in enumerate(alpha)]
    params += [(k, m.get(k)) for k in ("upsilon", "omega", "zeta", "mu")]
    return [
        "<h2>The learned model (sect. 4 and 6)</h2>",
        f"<p>Coordinate ascent (sect. 6) accepted a step when it raised "
        f"<b>{html.escape(_ACCEPTED.get(str(m.get('accepted_by')), 'eq. (6)'))}</b> on the "
        f"training split (training AUC {_fmt(m.get('train_auc'))}); mu is eq. (6)'s best "
        f"threshold: Tp - {_fmt(m.get('lambda'), 1)} Fp = {_fmt(m.get('objective'))} (Tp "
        f"{_fmt(m.get('tp_rate'))}, Fp {_fmt(m.get('fp_rate'), 4)}) after "
        f"{_fmt(m.get('iterations'))} iterations. Its points: "
        f"{html.escape(_points_text((s.get(HEADLINE) or {}).get('points')))}. The row "
        "<i>the paper's method as written</i> is the same search accepting steps by eq. (6) "
        "itself, on a uniform sample of every laser's points.</p>",
        "<table><tr><th>parameter</th><th>value</th></tr>",
        *[f"<tr><td>{html.escape(k)}</td><td>{_fmt(v, 4)}</td></tr>" for k, v in params],
        "</table><p>What they mean:</p><table>",
        *[
            f"<tr><td>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>"
            for k, v in PARAMETER_MEANINGS
        ],
        "</table>",
    ]


#: Completion times (drive time x) at which the speed-control result is stated.
SPEED_TIME_BUDGETS = (1.25, 1.5)


def speed_headline(sp: Mapping[str, Any]) -> str:
    """The speed-control result in words: the proactive controller's shock reduction over
    the reactive one at equal completion time, at stated time budgets (the best point of a
    sweep alone would quote whatever slowest setting the sweep reached), the largest with
    its time, and the count of shocks it rests on (one more or one fewer moves a share by
    1/N)."""
    front = [
        (float(p["time_norm"]), float(p["reduction"]))
        for p in sp.get("reductions_along_reactive_front") or []
        if p.get("time_norm") is not None and p.get("reduction") is not None
    ]
    if not front:
        return "Shock reduction at equal completion time: n/a (the curves' times do not overlap)."
    parts = []
    for budget in SPEED_TIME_BUDGETS:
        within = [r for t, r in front if t <= budget]
        share = f"{100 * max(within):.0f} %" if within else "n/a (no setting that fast)"
        parts.append(f"within {budget:g}x the drive time, {share}")
    t_best, r_best = max(front, key=lambda p: p[1])
    shocks = (sp.get("no_change") or {}).get("shocks_over_floor")
    rests = (
        f" It rests on {shocks} shock(s) above the floor at the logged speed"
        + (": too few to state it finer than about 1/" + f"{shocks}." if shocks < 30 else ".")
        if isinstance(shocks, int) and shocks > 0
        else ""
    )
    return (
        "Shock reduction of the proactive over the reactive controller at equal completion "
        f"time: <b>{'; '.join(parts)}</b>; the largest, {100 * r_best:.0f} %, at "
        f"{t_best:.2f}x the drive time.{rests}"
    )


def _speed_section(s: Mapping[str, Any], speed_files: Sequence[str]) -> list[str]:
    """Fig. 7's analogue: the speed-control result, its figure and its curves."""
    sp = s.get("speed_control", {})
    return [
        "<h2>Speed control (Fig. 7)</h2>",
        "<p>The test route replayed with the speed lowered reactively (after the IMU measured a "
        "rough event, as in the race) or proactively (before events the model flags). Shock at "
        "another speed is ruggedness x speed (sect. 5.2); counted is the part of each event's "
        f"shock above {_fmt(sp.get('shock_floor_g'), 2)} G. Both axes are normalised by driving "
        f"at the logged speed. {speed_headline(sp)}</p>",
        "<p>In the figure, each faint point is one setting of a controller's sweep (how much "
        "it slows, for how long); the line joins that controller's best trade-offs (no other "
        "setting is both faster and smoother), and the star is the drive at the logged "
        "speed.</p>",
        *[
            f"<p><img src='{html.escape(f)}' alt='speed trade-off'></p>"
            for f in speed_files
            if f.endswith(".png")
        ],
        *[
            f"<p>Curves: <a href='{html.escape(f)}'>{html.escape(f)}</a></p>"
            for f in speed_files
            if f.endswith(".csv")
        ],
    ]


def _log_figures_section(log_figures: Sequence[tuple[str, str]]) -> list[str]:
    """The copied per-log figures (Figs. 4 and 5) under their captions; nothing if none."""
    if not log_figures:
        return []
    parts = ["<h2>Per-log figures (Figs. 4 and 5)</h2>"]
    if not any(caption.startswith("Fig. 5") for caption, _ in log_figures):
        parts.append(
            "<p>Fig. 4 (how far apart two scans see the same ground, against the time "
            "between them) is drawn for every log. Fig. 5 (shock against speed over one "
            "obstacle type) needs a calibration drive, the same obstacle passed at several "
            "speeds (<code>terrain sim --profile calibration</code>), and no log here is "
            "one.</p>"
        )
    for caption, name in log_figures:
        parts.append(
            f"<h3>{html.escape(caption)}</h3><p><img src='{html.escape(name)}' "
            f"alt='{html.escape(caption)}'></p>"
        )
    return parts


def index_html(inputs: ReportInputs) -> str:
    """The page (module docstring): its sections, one per line group, in reading order."""
    s, m = inputs.summary, inputs.model
    parts = [
        *_page_head(s),
        *_events_section(s),
        *_roc_section(s, inputs.roc_figures),
        *_model_section(s, m),
        *_speed_section(s, inputs.speed_files),
        *online_section(s, inputs.online_figure),
        *_log_figures_section(inputs.log_figures),
        f"<p><small>terrain {_fmt(s.get('toolkit_version'))}</small></p></body></html>\n",
    ]
    return "\n".join(parts)


def write_index_html(path: Path, inputs: ReportInputs) -> Path:
    """Write :func:`index_html` atomically."""
    return write_bytes_atomic(path, index_html(inputs).encode("utf-8"))


__all__ = [
    "Drawn",
    "ReportInputs",
    "index_html",
    "roc_lines",
    "roc_png",
    "write_index_html",
]
