"""The report's row and entry for learning while driving, when ``terrain online`` has run:
the ``online`` method (each event's standing as it was seen, :func:`online_row`), and the
summary's ``online_learning`` entry, with Fig. 7 driven by the online flags as they were
when each event was seen, beside the offline model's.

The entry is the online stage's ``summary.json`` (:mod:`toolkit.analysis.online_summary`)
plus ``speed_control``: the largest shock reduction at equal time against the reactive race
controller of the proactive controller driven by the online flags (``online``) and by the
offline model's (``offline``, the report's headline).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa

from toolkit.analysis.methods import MethodScores
from toolkit.analysis.online_page import PNG_NAME, prequential_png
from toolkit.analysis.online_summary import comparable
from toolkit.analysis.summary import shock_reduction
from toolkit.arrays import BoolArray
from toolkit.config import EvaluateConfig
from toolkit.errors import StageError
from toolkit.model.roughness import EventScores, RoughnessParams
from toolkit.tableio import read_table
from toolkit.workspace import Workspace


def online_columns(workspace: Workspace, events: pa.Table) -> dict[str, np.ndarray]:
    """``online/scores.parquet``'s standing, verdict and start score of each row of
    ``events`` (by log and event id), as they were when each event was seen; StageError
    when the replay left one out."""
    online = read_table(workspace.path("online_scores"), "online_scores")
    # The events' own order kept by a row number (polars 1.0's join has no maintain_order).
    keys = pl.DataFrame(events.select(["log_id", "event_id"])).with_row_index("row")
    wanted = ["log_id", "event_id", "standing", "r_online", "predicted", "r_start"]
    got = keys.join(
        pl.DataFrame(online.select(wanted)), on=["log_id", "event_id"], how="left"
    ).sort("row")
    missing = got["predicted"].null_count()
    if missing:
        raise StageError(
            f"{missing} event(s) of the tables are not in the online replay; run `terrain "
            "online` again",
            path=workspace.path("online_scores"),
        )
    standing = got["standing"].fill_null(np.nan).to_numpy().astype(np.float64)
    raw = got["r_online"].fill_null(np.nan).to_numpy().astype(np.float64)
    return {
        # Its ties broken by the raw scores, as the replay's summary ranks it.
        "standing": comparable(standing, raw),
        "predicted": got["predicted"].to_numpy().astype(bool),
        "r_start": got["r_start"].fill_null(np.nan).to_numpy().astype(np.float64),
    }


def online_row(workspace: Workspace, events: pa.Table) -> MethodScores | None:
    """The report's ``online`` row: each event's standing as it was seen (its R_combined),
    its verdict then, and the start's score (what learning while driving began from); None
    when the workspace has no online replay."""
    path = workspace.path("online_summary")
    if not path.is_file():
        return None
    begun = json.loads(path.read_text(encoding="utf-8"))["start"]
    # No mu yet (nothing flagged before a label is seen): the largest float, which the
    # summary's JSON can hold and no score reaches.
    mu = begun["mu"] if begun["mu"] is not None else float(np.finfo(np.float64).max)
    start = RoughnessParams.from_vector(begun["b"], mu)
    col = online_columns(workspace, events)
    nan = np.full(events.num_rows, np.nan)
    scores = EventScores(nan, nan, col["standing"], col["predicted"])
    return MethodScores(scores, None, start, start=col["r_start"])


def online_entry(
    workspace: Workspace,
    events: pa.Table,
    test: BoolArray,
    ev: EvaluateConfig,
    offline_reduction: float | None,
    report: Path,
) -> tuple[dict[str, Any] | None, list[Path]]:
    """The summary's ``online_learning`` entry and its figure (module docstring); None and no figure
    when the workspace has no online replay."""
    path = workspace.path("online_summary")
    if not path.is_file():
        return None, []
    entry: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    flags = online_columns(workspace, events)["predicted"]
    entry["speed_control"] = {
        "online": shock_reduction(events, flags, test, ev) if np.any(test) else None,
        "offline": offline_reduction,
    }
    return entry, [prequential_png(report / PNG_NAME, entry["stretches"])]


__all__ = ["online_columns", "online_entry", "online_row"]
