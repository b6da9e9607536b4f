"""What a test-then-train replay showed (``WS/online/summary.json``): the numbers the
report's section on learning while driving states.

Every number is over the events of ``WS/online/scores.parquet`` (one row per event, as the
online learner met it) and the updates of ``WS/online/steps.parquet``:

- ``test``: on the test split (each log's second half with ``[tables] split_scope =
  "per_log"``), the AUC and TPR at each FPR of the online scores *as they were when each
  event was seen* (their standings, which compare across model versions:
  :mod:`toolkit.model.online`), beside the offline model (learned on the training split),
  the start unlearned, the frozen early model and the online model at its drive's end;
- ``stretches``: per ``stretch_m`` of distance driven (pooled over drives), the online
  scores' AUC as they came, the offline model's on the same events, and the final online
  model's (forgetting: how it ranks stretches it learned from long before);
- ``within_0_02_from_m``: the start of the first stretch from which every later one scored
  as it came is within 0.02 AUC of the offline model on the same events (null: never);
- ``label_latency_s``: from an event seen to its label known;
- ``out_of_order_labels``: events whose label was known before that of an event driven
  earlier (the buffer takes them in the order known);
- ``gaps``: stretches of a drive longer than two updates with no event (no pose, no IMU, no
  points: whatever a log lacked), across which the model stood still;
- ``first_update_m``: per drive, where the model first changed.

Timings (the update's p50 and p95, the replay's speed) are not here: they differ from run to
run, so they are in the stage's manifest record, and the report reads them there.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from toolkit.arrays import BoolArray, FloatArray
from toolkit.model.roc import auc, fpr_key, roc, tpr_at_fpr

#: The score columns compared on the test split, and what the summary calls each; a pair
#: is a standing with its raw score, which breaks the standing's ties (:func:`comparable`).
COMPARED: dict[str, str | tuple[str, str]] = {
    "online": ("standing", "r_online"),
    "online_raw": "r_online",
    "offline": "r_offline",
    "offline_as_met": ("standing_offline", "r_offline"),
    "start": "r_start",
    "frozen": ("standing_frozen", "r_frozen"),
    "final": ("standing_final", "r_final"),
}
#: The false-positive rates the TPR is stated at (sect. 7's operating points; the issue's
#: 5, 10 and 20 %), fixed so that the replay is not keyed by ``[evaluate]``.
FPRS = (0.05, 0.1, 0.2)
#: How close the online scores must come to the offline model's AUC (the issue's 0.02).
WITHIN_AUC = 0.02


def comparable(standing: FloatArray, raw: FloatArray) -> FloatArray:
    """Standings (E,) made a total order: ties broken by the raw scores (E,).

    A standing is a share of the reference's smooth events (up to 1,024): every event above
    all of them stands at 1, and those ties would throw away how far above they are (on the
    four unseen races, against the buffer's 256, a model that never changed ranked the test
    split at 0.911 by its scores and 0.882 by its standings). Within a tie the raw scores
    decide, added below the standings' resolution (steps of 1 / 2N), so no standing's order
    changes."""
    order = np.argsort(np.argsort(np.where(np.isnan(raw), -np.inf, raw), kind="stable"))
    return np.asarray(standing, np.float64) + 1e-7 * (order + 1) / max(raw.size, 1)


def _score(scores: Mapping[str, np.ndarray], column: str | tuple[str, str]) -> FloatArray:
    if isinstance(column, tuple):
        return comparable(scores[column[0]], scores[column[1]])
    return scores[column]


def rates(scores: FloatArray, rough: BoolArray, fprs: Sequence[float]) -> dict[str, Any] | None:
    """AUC and TPR at each FPR of ``scores`` (E,) against ``rough`` (E,), with the counts;
    None without both classes. NaN scores (not scored) rank below every other."""
    n_rough = int(rough.sum())
    if n_rough == 0 or n_rough == rough.size:
        return None
    curve = roc(scores, rough)
    return {
        "auc": auc(scores, rough),
        "tpr_at_fpr": {fpr_key(f): tpr_at_fpr(curve, f) for f in fprs},
        "events": int(rough.size),
        "rough": n_rough,
    }


def _auc_or_none(scores: FloatArray, rough: BoolArray) -> float | None:
    n = int(rough.sum())
    return auc(scores, rough) if 0 < n < rough.size else None


def stretches(
    s_m: FloatArray, rough: BoolArray, columns: Mapping[str, FloatArray], stretch_m: float
) -> list[dict[str, Any]]:
    """Per stretch ``[k stretch_m, (k + 1) stretch_m)`` of distance driven: its events, rough
    ones, and each column's AUC on them (None without both classes)."""
    if s_m.size == 0:
        return []
    k = np.floor(s_m / stretch_m).astype(np.int64)
    out = []
    for i in range(int(k.max()) + 1):
        rows = k == i
        entry: dict[str, Any] = {
            "from_m": i * stretch_m,
            "to_m": (i + 1) * stretch_m,
            "events": int(rows.sum()),
            "rough": int(rough[rows].sum()),
        }
        for name, col in columns.items():
            entry[name] = _auc_or_none(col[rows], rough[rows])
        out.append(entry)
    return out


def within_from_m(rows: Sequence[Mapping[str, Any]], against: str = "offline") -> float | None:
    """The start of the first stretch from which every later stretch with both classes has
    its online AUC within :data:`WITHIN_AUC` of the ``against`` column's (None: never)."""
    start: float | None = None
    for row in rows:
        if row["online"] is None or row[against] is None:
            continue
        if row["online"] >= row[against] - WITHIN_AUC:
            start = row["from_m"] if start is None else start
        else:
            start = None
    return start


def out_of_order(drive: np.ndarray, t_seen_ns: np.ndarray, t_known_ns: np.ndarray) -> int:
    """Events (E,) whose label was known before the label of an event of the same drive
    seen before them."""
    count = 0
    for d in np.unique(drive):
        mine = np.flatnonzero(drive == d)
        known = t_known_ns[mine[np.argsort(t_seen_ns[mine], kind="stable")]]
        count += int((known < np.maximum.accumulate(known)).sum())
    return count


def gaps(drive: np.ndarray, s_m: FloatArray, longer_than_m: float) -> list[dict[str, Any]]:
    """Stretches of each drive longer than ``longer_than_m`` between consecutive events."""
    out = []
    for d in np.unique(drive):
        s = np.sort(s_m[drive == d])
        wide = np.flatnonzero(np.diff(s) > longer_than_m)
        out += [{"drive": int(d), "from_m": float(s[i]), "to_m": float(s[i + 1])} for i in wide]
    return out


def online_summary(
    scores: Mapping[str, np.ndarray],
    steps: Mapping[str, np.ndarray],
    *,
    fprs: Sequence[float],
    stretch_m: float,
    update_every_m: float,
    frozen_after_m: float,
) -> dict[str, Any]:
    """The summary (module docstring) of a replay's ``scores`` and ``steps`` (their tables'
    columns as arrays)."""
    rough = scores["rough"].astype(bool)
    test = scores["split"] == "test"
    latency_s = (scores["t_known_ns"] - scores["t_seen_ns"]) / 1e9
    drive = scores["drive"]
    first_update = {}
    for d in np.unique(steps["drive"]):
        changed = (steps["drive"] == d) & (steps["version"] >= 1)
        first_update[str(int(d))] = float(steps["end_m"][changed].min()) if changed.any() else None
    rows = stretches(
        scores["s_m"],
        rough,
        {
            name: _score(scores, COMPARED[name])
            for name in ("online", "offline", "offline_as_met", "final")
        },
        stretch_m,
    )
    compared = {
        name: rates(_score(scores, col)[test], rough[test], fprs) for name, col in COMPARED.items()
    }
    return {
        "test": compared,
        "stretch_m": stretch_m,
        "stretches": rows,
        "within_0_02_from_m": within_from_m(rows),
        # The same, against the offline model measured as the online scores are.
        "within_0_02_as_met_from_m": within_from_m(rows, "offline_as_met"),
        "update_every_m": update_every_m,
        "frozen_after_m": frozen_after_m,
        "label_latency_s": {
            "p50": float(np.percentile(latency_s, 50)) if latency_s.size else None,
            "p95": float(np.percentile(latency_s, 95)) if latency_s.size else None,
        },
        "out_of_order_labels": out_of_order(drive, scores["t_seen_ns"], scores["t_known_ns"]),
        "gaps": gaps(drive, scores["s_m"], 2.0 * update_every_m),
        "first_update_m": first_update,
        "drives": int(np.unique(drive).size),
        "updates": int(steps["step"].size),
        "events": int(rough.size),
        "rough": int(rough.sum()),
        "not_reached": int((scores["version"] < 0).sum()),
    }


def changed_anywhere(summary: Mapping[str, Any]) -> bool:
    """Whether the model changed on some drive of the replay (its ``first_update_m``)."""
    return any(m is not None for m in (summary.get("first_update_m") or {}).values())


def learning_verdict(test: Mapping[str, Any]) -> tuple[bool, str] | None:
    """Whether learning while driving helped: the online scores' test AUC against the
    start's, unlearned (the summary's ``test``), and the sentence that says so; None when
    either AUC is missing (one class only)."""
    online, first = test.get("online"), test.get("start")
    if not online or not first or online.get("auc") is None or first.get("auc") is None:
        return None
    ours, start = float(online["auc"]), float(first["auc"])
    if ours > start:
        return True, (
            f"learning while driving helped: the online scores' test AUC, {ours:.3f}, is "
            f"{ours - start:.3f} above its start's, unlearned ({start:.3f})"
        )
    return False, (
        f"learning while driving did not help here: the online scores' test AUC, {ours:.3f}, "
        f"is not above its start's, unlearned ({start:.3f}, {ours - start:+.3f})"
    )


__all__ = [
    "COMPARED",
    "changed_anywhere",
    "comparable",
    "FPRS",
    "learning_verdict",
    "WITHIN_AUC",
    "online_summary",
    "rates",
    "stretches",
    "within_from_m",
]
