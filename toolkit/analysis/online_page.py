"""The report's section on learning while driving (sect. 8), from the summary's ``online_learning``
entry (:mod:`toolkit.stages.evaluate_online`): a table of the test split's numbers, the
prequential curve against distance driven, and what the replay cost.

The figure (``online_prequential.png``) draws, per stretch of distance driven (pooled over
the drives), the AUC of the online scores as they came, the offline model's on the same
events, and the online model's at its drive's end on them (forgetting: how the model that
learned on, ranks the stretches it learned from long before).
"""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from toolkit.analysis.figures import new_figure, save_png_atomic
from toolkit.analysis.online_summary import changed_anywhere, learning_verdict

PNG_NAME = "online_prequential.png"
#: The rows of the section's table: summary key -> what it is.
ROWS = {
    "online": "online, as each event was seen (its standing)",
    "offline": "offline model (trained on the training split)",
    "offline_as_met": "offline model, ranked as the online scores are (standing)",
    "frozen": "frozen early model",
    "final": "online model at its drive's end",
    "start": "its start, unlearned",
}
#: The stretches' curves: key -> (label, line style).
CURVES = {
    "online": ("online, as it came", "-"),
    "offline": ("offline model", "--"),
    "final": ("online model at the end (forgetting)", ":"),
}


def prequential_png(path: Path, stretches: Sequence[Mapping[str, Any]]) -> Path:
    """Draw each curve of :data:`CURVES` against the stretches' distance (km) to ``path``."""
    fig = new_figure(7.0, 4.0)
    ax = fig.add_subplot(1, 1, 1)
    for key, (label, style) in CURVES.items():
        km = [(r["from_m"] + r["to_m"]) / 2000.0 for r in stretches if r.get(key) is not None]
        auc = [r[key] for r in stretches if r.get(key) is not None]
        ax.plot(km, auc, style, marker="o", markersize=3, label=label)
    ax.set_xlabel("distance driven in the drive (km)")
    ax.set_ylabel("AUC of the stretch's events")
    ax.set_ylim(0.4, 1.0)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title("Learning while driving: each stretch scored as it came")
    return save_png_atomic(fig, path)


def _num(v: Any, digits: int = 3) -> str:
    return "n/a" if v is None else f"{v:.{digits}f}"


def _rates_row(name: str, m: Mapping[str, Any] | None) -> str:
    if m is None:
        return f"<tr><td>{html.escape(name)}</td><td colspan='4'>one class only</td></tr>"
    tpr = "".join(f"<td>{_num(v, 2)}</td>" for v in m["tpr_at_fpr"].values())
    return f"<tr><td>{html.escape(name)}</td><td>{_num(m['auc'])}</td>{tpr}</tr>"


def _said(o: Mapping[str, Any]) -> list[str]:
    """The section's sentences: the distance to the offline model, speed control, cost."""
    within = o.get("within_0_02_from_m")
    stretch = f"stretches of {o['stretch_m'] / 1000:g} km, pooled over {o['drives']} drive(s)"
    lines = [
        (
            f"The online scores were never within 0.02 AUC of the offline model on every later "
            f"stretch ({stretch})."
            if within is None
            else f"From {within / 1000:.1f} km driven on, the online scores were within 0.02 "
            f"AUC of the offline model on every stretch ({stretch})."
        )
    ]
    verdict = learning_verdict(o["test"])
    if not changed_anywhere(o):
        # Its scores are then the start's (ranked by standing): a verdict would mislead.
        lines.append("The model never changed on any drive: the online scores are its start's.")
    elif verdict is not None:
        lines.append(verdict[1][0].upper() + verdict[1][1:] + ".")
    speed = o.get("speed_control") or {}
    if speed.get("online") is not None and speed.get("offline"):
        share = speed["online"] / speed["offline"]
        lines.append(
            f"Speed control (Fig. 7) driven by the online flags as they were: shock "
            f"{100 * speed['online']:.0f} % below the reactive controller at equal time, "
            f"{100 * share:.0f} % of the offline model's {100 * speed['offline']:.0f} %."
        )
    # Times differ from run to run, and the report is the same file for the same inputs:
    # they are where the run's record is.
    lines.append(
        "The updates' time (p50, p95, max) and the replay's speed against real time are in "
        "the workspace's manifest.json (stage online, timings_s), and said by `terrain online`."
    )
    lat = o["label_latency_s"]
    lines.append(
        f"A label was known {_num(lat['p50'], 2)} s (p50), {_num(lat['p95'], 2)} s (p95) "
        "after its event's last point was seen."
    )
    if o.get("gaps"):
        lines.append(f"{len(o['gaps'])} stretch(es) held no event; the model stood still there.")
    return [f"<p>{html.escape(x)}</p>" for x in lines]


def online_section(summary: Mapping[str, Any], figure: str | None) -> list[str]:
    """The section's HTML lines (none without an ``online_learning`` entry)."""
    o = summary.get("online_learning")
    if not isinstance(o, Mapping):
        return []
    fprs: Mapping[str, Any] = next(
        (m["tpr_at_fpr"] for m in o["test"].values() if m is not None), {}
    )
    head = "".join(f"<th>TPR at FPR {html.escape(k)}</th>" for k in fprs)
    parts = [
        "<h2>Learning while driving (sect. 8)</h2>",
        "<p>Each log replayed as driven: every event scored by the model as it stood when "
        "the event's last point was seen; its label learned from once the rear axle had "
        f"passed and the shock filter had its samples. An update every "
        f"{o['update_every_m']:g} m; the frozen model is the online one after "
        f"{o['frozen_after_m'] / 1000:g} km.</p>",
        f"<table><tr><th>test split</th><th>AUC</th>{head}</tr>",
        *(_rates_row(label, o["test"].get(key)) for key, label in ROWS.items()),
        "</table>",
        *_said(o),
    ]
    if figure:
        parts.append(f"<p><img src='{html.escape(figure)}' alt='prequential AUC'></p>")
    return parts


__all__ = ["PNG_NAME", "online_section", "prequential_png"]
