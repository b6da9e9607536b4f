"""The report's entry for learning while driving: ``WS/online/``'s summary (when ``terrain
online`` has run), with Fig. 7 driven by the online flags as they were when each event was
seen, beside the offline model's.

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

from toolkit.analysis.online_page import PNG_NAME, prequential_png
from toolkit.analysis.summary import shock_reduction
from toolkit.arrays import BoolArray
from toolkit.config import EvaluateConfig
from toolkit.errors import StageError
from toolkit.tableio import read_table
from toolkit.workspace import Workspace


def online_flags(workspace: Workspace, events: pa.Table) -> BoolArray:
    """The online verdict of each row of ``events`` (by log and event id) as it was when
    the event was seen; StageError when the replay left one out."""
    online = read_table(workspace.path("online_scores"), "online_scores")
    keys = pl.DataFrame(events.select(["log_id", "event_id"]))
    flags = pl.DataFrame(online.select(["log_id", "event_id", "predicted"]))
    got = keys.join(flags, on=["log_id", "event_id"], how="left", maintain_order="left")
    missing = got["predicted"].null_count()
    if missing:
        raise StageError(
            f"{missing} event(s) of the tables are not in the online replay; run `terrain "
            "online` again",
            path=workspace.path("online_scores"),
        )
    return got["predicted"].to_numpy().astype(bool)


def online_entry(
    workspace: Workspace,
    events: pa.Table,
    test: BoolArray,
    ev: EvaluateConfig,
    offline_reduction: float | None,
    report: Path,
) -> tuple[dict[str, Any] | None, list[Path]]:
    """The summary's ``online`` entry and its figure (module docstring); None and no figure
    when the workspace has no online replay."""
    path = workspace.path("online_summary")
    if not path.is_file():
        return None, []
    entry: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    flags = online_flags(workspace, events)
    entry["speed_control"] = {
        "online": shock_reduction(events, flags, test, ev) if np.any(test) else None,
        "offline": offline_reduction,
    }
    return entry, [prequential_png(report / PNG_NAME, entry["stretches"])]


__all__ = ["online_entry", "online_flags"]
