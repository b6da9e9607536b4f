"""What learn and evaluate read of the workspace: the training tables, the points under the
tyres as patches, their pairs, and the learned model.

``table_inputs`` checks the tables are the ones the last finished ``terrain tables`` wrote
with the configuration in force and this code; ``split_events`` reads the events of a split;
``patches_of`` streams the event points into tyre patches (:mod:`toolkit.model.patches`),
sampled as ``[model]`` says, with the lasers ranked nearest first
(``lasers_nearest_first``) on the training split alone; ``pair_table`` turns patches into
their pairs, refusing, before allocating, more than :data:`MAX_PAIR_BYTES`; ``load_model``
reads ``model.json`` strictly.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.compute as pc

from toolkit.config import ModelConfig, PipelineConfig
from toolkit.errors import StageError
from toolkit.model.patches import POINT_COLUMNS, TyrePatches, build_patches, lead_order
from toolkit.model.roughness import PairTable, RoughnessParams
from toolkit.stages import tables as tables_stage
from toolkit.stages.contract import Need
from toolkit.stages.runner import check_needs
from toolkit.tableio import iter_table_batches, read_table
from toolkit.workspace import Workspace

#: Rows per batch when streaming the event points.
POINT_BATCH = 1_048_576
#: Largest pair table learning builds, bytes (13 bytes a pair: three float32 logarithms of
#: differences and a validity flag; the search's cache adds up to 16 a pair, up to
#: :data:`toolkit.model.roughness.CACHE_BYTES`): a quarter of the project machine's 24 GiB.
#: Evaluate holds the training split's pairs too (and the oracle's, one after the other).
MAX_PAIR_BYTES = 6 << 30
#: String columns of the event points read as dictionaries (a few distinct values each).
DICTIONARY_COLUMNS = ("log_id", "wheel", "laser")


def table_inputs(workspace: Workspace, config: PipelineConfig) -> dict[str, str]:
    """sha256 of the two tables, by layout name, refused unless they are what the last
    finished ``terrain tables`` wrote, with ``config``, the configuration in force, and this
    code (:func:`~toolkit.stages.runner.check_needs`, as the runner checks every stage's
    needs): tables of another configuration (a ``run -c B --from tables`` whose learn failed
    leaves B's tables under A's ``config.toml``) would otherwise be exported as this one's."""
    tables = tuple(Need(name, tables_stage.STAGE) for name in tables_stage.SPEC.makes)
    return check_needs(tables, workspace.path, workspace.manifest(), config, "export")


def split_events(workspace: Workspace, split: str | None) -> pa.Table:
    """The events of one split (``"train"``, ``"test"``) or all (None), in table order."""
    events = read_table(workspace.events_table, "tables_events")
    # A (log, event) listed twice is the events table's fault: said of it here, before the
    # points are matched to events and the duplicate would look like theirs.
    keys = pa.table({"log_id": events.column("log_id"), "event_id": events.column("event_id")})
    counts = keys.group_by(["log_id", "event_id"]).aggregate([([], "count_all")])
    twice = counts.filter(pc.greater(counts.column("count_all"), 1))
    if twice.num_rows:
        first = twice.slice(0, 1).to_pylist()[0]
        raise StageError(
            f"log {first['log_id']!r} lists event {first['event_id']} "
            f"{first['count_all']} times ({twice.num_rows} duplicated event(s))",
            path=workspace.events_table,
        )
    if split is None:
        return events
    return events.filter(pc.equal(events.column("split"), split))


def _point_batches(workspace: Workspace, columns: Sequence[str]) -> Iterator[pa.RecordBatch]:
    return iter_table_batches(
        workspace.event_points_table,
        "event_points",
        columns=list(columns),
        batch_rows=POINT_BATCH,
        as_dictionary=[c for c in DICTIONARY_COLUMNS if c in columns],
    )


def lasers_nearest_first(workspace: Workspace) -> tuple[str, ...]:
    """Every laser of the training split's event points, nearest first
    (:func:`toolkit.model.patches.lead_order`: the shortest mean time between a point's scan
    and its event), over all their points, not a sample of them: the one ranking both the
    model's nearest-laser sample and the race test's closest laser use. Measured on the
    training split only, so no test event informs a trained row."""
    train = split_events(workspace, "train")
    columns = ("log_id", "event_id", "laser", "t_ns")
    return lead_order(train, _point_batches(workspace, columns), workspace.event_points_table)


def closest_laser(
    workspace: Workspace, order: tuple[str, ...], configured: str | None
) -> str | None:
    """The configured closest laser, or the nearest of the training split's lasers
    (:func:`lasers_nearest_first`; ``order`` when the model already ranked them), None
    without points. Ranked on every point of the training events: the model's patches are a
    sample that keeps the nearest laser first, so the few other points in them come from
    unusual patches and would rank the lasers wrongly (on five 20-mile races their median
    look-ahead put the second laser first)."""
    if configured:
        return configured
    ranked = order or lasers_nearest_first(workspace)
    return ranked[0] if ranked else None


def laser_order(workspace: Workspace, model: ModelConfig) -> tuple[str, ...]:
    """The lasers nearest first when ``[model] point_sample = "nearest_laser"``
    (:func:`lasers_nearest_first`); () for any other sample."""
    if model.point_sample != "nearest_laser":
        return ()
    return lasers_nearest_first(workspace)


def patches_of(
    workspace: Workspace,
    events: pa.Table,
    model: ModelConfig,
    *,
    only_laser: str | None = None,
    order: Sequence[str] | None = None,
) -> TyrePatches:
    """The tyre patches of ``events``, streamed from ``tables/event_points.parquet``, sampled
    as ``model`` says (``order``: the lasers nearest first, :func:`laser_order` when None)."""
    if order is None:
        order = laser_order(workspace, model)
    return build_patches(
        events,
        _point_batches(workspace, POINT_COLUMNS),
        model.max_points_per_wheel,
        only_laser=only_laser,
        sample=model.point_sample,
        laser_order=order,
        source=workspace.event_points_table,
    )


def pair_table(patches: TyrePatches, model: ModelConfig, path: Path) -> PairTable:
    """The pairs of ``patches``; StageError, before allocating, when they would take more
    than :data:`MAX_PAIR_BYTES` (an uncapped ``[model] max_points_per_wheel`` on dense
    lasers: N points a tyre make N (N - 1) / 2 pairs)."""
    n = patches.n_max
    need = patches.groups * (n * (n - 1) // 2) * 13
    if need > MAX_PAIR_BYTES:
        raise StageError(
            f"{patches.groups} tyre patches of up to {n} points make {need / 2**30:.1f} GiB of "
            f"pairs (limit {MAX_PAIR_BYTES / 2**30:.0f} GiB); set [model] max_points_per_wheel "
            f"(now {model.max_points_per_wheel}) to 40 or so",
            path=path,
        )
    return PairTable(patches)


def load_model(workspace: Workspace) -> tuple[RoughnessParams, dict[str, Any]]:
    """The learned parameters and the whole ``model.json``; StageError if missing or
    malformed."""
    path = workspace.model_path
    if not path.is_file():
        raise StageError("no model; run `terrain learn` first", path=path)
    return load_model_file(path)


def load_model_file(path: Path) -> tuple[RoughnessParams, dict[str, Any]]:
    """The parameters and the whole document of a ``model.json`` at ``path``; StageError
    if missing or malformed."""
    if not path.is_file():
        raise StageError("no such model file", path=path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise StageError(f"unreadable model: {exc}", path=path) from exc
    if not isinstance(doc, dict):
        raise StageError("unreadable model: not a JSON object", path=path)

    def number(key: str, value: Any, integer: bool = False) -> float:
        """A JSON number as written by learn: finite, not a string or a boolean, and for
        omega a whole number (5.9 is not truncated to 5)."""
        ok = isinstance(value, int) if integer else isinstance(value, (int, float))
        if isinstance(value, bool) or not ok or not math.isfinite(value):
            kind = "an integer" if integer else "a finite number"
            raise StageError(f"model key {key!r} must be {kind}, not {value!r}", path=path)
        return float(value)

    for key in ("alpha", "upsilon", "omega", "zeta", "mu"):
        if key not in doc:
            raise StageError(f"unreadable model: no key {key!r}", path=path)
    if not isinstance(doc["alpha"], list):
        raise StageError(f"model key 'alpha' must be a list, not {doc['alpha']!r}", path=path)
    try:
        params = RoughnessParams(
            tuple(number(f"alpha[{i}]", a) for i, a in enumerate(doc["alpha"])),
            number("upsilon", doc["upsilon"]),
            int(number("omega", doc["omega"], integer=True)),
            number("zeta", doc["zeta"]),
            number("mu", doc["mu"]),
        )
    except (ValueError, TypeError) as exc:
        raise StageError(f"unreadable model: {exc}", path=path) from exc
    if not params.admissible():
        raise StageError(f"model parameters outside the model's domain: {params}", path=path)
    return params, doc


__all__ = [
    "MAX_PAIR_BYTES",
    "closest_laser",
    "laser_order",
    "lasers_nearest_first",
    "load_model",
    "load_model_file",
    "pair_table",
    "patches_of",
    "split_events",
    "table_inputs",
]
