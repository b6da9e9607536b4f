"""The dataset card (``README.md``): the Hugging Face YAML header that lets
``datasets.load_dataset`` read the export, then the prose a reader needs to use the data
right, every number counted from the rows written. See ``docs/export.md``."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from numpy.typing import NDArray

from toolkit import __version__
from toolkit.analysis.method_registry import HEADLINE, title
from toolkit.config import PipelineConfig
from toolkit.publish.dataset import (
    CITATION,
    EVENT_POINTS,
    EVENTS,
    SPLITS,
    TYPES,
    DatasetFacts,
    data_file,
    export_config_hash,
)
from toolkit.stages.tables import SplitTotals
from toolkit.tableio import ColumnSpec

LICENSE = "cc-by-4.0"
PRETTY_NAME = "Self-supervised terrain roughness: shock-labelled events and laser points"
#: The paper's training set (sect. 7: miles 60-70): laser points and events, for the card's
#: comparison of point density.
PAPER_TRAIN_POINTS = 887_878
PAPER_TRAIN_EVENTS = 11_470
#: The paper's share of rough events (sect. 7: 42 of 11,470 training, 58 of 13,325 test).
PAPER_ROUGH = ((42, 11_470), (58, 13_325))


def _q(text: str) -> str:
    """A YAML scalar: JSON's double-quoted string is valid YAML."""
    return json.dumps(text, ensure_ascii=False)


def _size_category(rows: int) -> str:
    """The Hub's size category of a dataset of ``rows`` rows (its largest config)."""
    bounds = [
        (1_000, "n<1K"),
        (10_000, "1K<n<10K"),
        (100_000, "10K<n<100K"),
        (1_000_000, "100K<n<1M"),
        (10_000_000, "1M<n<10M"),
        (100_000_000, "10M<n<100M"),
        (1_000_000_000, "100M<n<1B"),
    ]
    return next((name for bound, name in bounds if rows < bound), "n>1B")


def _yaml_header(facts: DatasetFacts) -> list[str]:
    """The card's metadata: license, names, configs -> files, features and split sizes."""
    simulated = any(s.sim is not None for s in facts.sources)
    tags = [
        "robotics",
        "autonomous-driving",
        "off-road",
        "terrain-roughness",
        "lidar",
        "point-cloud",
        "imu",
        "self-supervised",
        *(["simulated", "synthetic"] if simulated else []),
    ]
    largest = max(facts.rows(name, split) for name in facts.columns for split in SPLITS)
    lines = [
        "---",
        f"license: {LICENSE}",
        f"pretty_name: {_q(PRETTY_NAME)}",
        "task_categories:",
        "- tabular-classification",
        "tags:",
        *(f"- {t}" for t in tags),
        "size_categories:",
        f"- {_q(_size_category(largest))}",
        "configs:",
    ]
    for name in facts.columns:
        lines.append(f"- config_name: {name}")
        if name == EVENTS:
            lines.append("  default: true")
        lines.append("  data_files:")
        for split in SPLITS:
            lines += [f"  - split: {split}", f"    path: {_q(data_file(name, split))}"]
    lines.append("dataset_info:")
    for name, columns in facts.columns.items():
        lines += [f"- config_name: {name}", "  features:"]
        for col in columns:
            lines += [f"  - name: {col.name}", f"    dtype: {TYPES[col.type][0]}"]
        lines.append("  splits:")
        for split in SPLITS:
            lines += [
                f"  - name: {split}",
                f"    num_bytes: {facts.arrow_bytes[data_file(name, split)]}",
                f"    num_examples: {facts.rows(name, split)}",
            ]
        files = [data_file(name, split) for split in SPLITS]
        lines += [
            f"  download_size: {sum(facts.files[f][0] for f in files)}",
            f"  dataset_size: {sum(facts.arrow_bytes[f] for f in files)}",
        ]
    lines.append("---")
    return lines


def _pct(part: int, whole: int) -> str:
    return f"{100.0 * part / whole:.2f} %" if whole else "n/a"


def _num(value: float) -> str:
    """A measured value for people: 4 significant digits."""
    return f"{value:.4g}"


def _cell(text: str) -> str:
    """Text for a Markdown table cell."""
    return text.replace("|", "\\|").replace("\n", " ")


def _column_table(columns: Sequence[ColumnSpec]) -> list[str]:
    lines = ["| column | type | unit | meaning |", "| --- | --- | --- | --- |"]
    for col in columns:
        values = f" (one of {', '.join(repr(v) for v in col.values)})" if col.values else ""
        lines.append(
            f"| `{col.name}` | {TYPES[col.type][0]} | {col.unit or '-'} | "
            f"{_cell(col.description + values)} |"
        )
    return lines


def _shock_definition(config: PipelineConfig) -> str:
    lc = config.label
    statistic = {
        "max_abs": "the peak (largest absolute value)",
        "rms": "the root mean square",
    }.get(lc.shock_statistic, f"the {lc.shock_statistic}")
    return (
        f"`shock_g` is {statistic} over the event of the IMU's z acceleration (in the vehicle "
        f"frame) passed through a {lc.fir_taps}-tap linear-phase FIR high-pass filter that "
        f"removes 0-{lc.fir_stop_hz:g} Hz (gain 1 within 5 % from {lc.fir_pass_hz:g} Hz up): "
        "removing 0 Hz removes gravity, the rest the suspension's oscillations (paper, sect. "
        f"5.1), in G (1 G = {lc.gravity_mps2:g} m/s^2)."
        + (
            " Each filtered impact counts for the one event whose span holds its peak time: "
            "the filter's response to an impact in a neighbouring event is left out "
            '(`label.attribution = "impact"`).'
            if lc.attribution == "impact" and lc.shock_statistic == "max_abs"
            else ""
        )
    )


def _log_rows(facts: DatasetFacts) -> list[str]:
    """The provenance table: one row per source log."""
    lines = [
        "| log_id | source file | sha256 | bytes | origin | events train / test |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for s in facts.sources:
        n = {
            split: int(
                np.count_nonzero(
                    np.asarray(facts.events[split].column("log_id").to_pylist(), dtype=object)
                    == s.log_id
                )
            )
            for split in SPLITS
        }
        if s.sim is not None:
            what = "simulated (`terrain sim`"
            details = [f"{k} {s.sim[k]}" for k in ("profile", "seed") if k in s.sim]
            origin = what + (", " + ", ".join(details) if details else "") + ")"
        else:
            origin = "recorded"
        lines.append(
            f"| `{s.log_id}` | `{_cell(s.file_name)}` | `{s.sha256}` | {s.size_bytes} | "
            f"{origin} | {n['train']} / {n['test']} |"
        )
    return lines


def _distance_lines(facts: DatasetFacts) -> list[str]:
    """Per log and split, the stretch of the driven path its events cover."""
    lines = []
    for s in facts.sources:
        parts = []
        for split in SPLITS:
            ev = facts.events[split]
            mine = ev.filter(pc.equal(ev.column("log_id"), s.log_id))
            if mine.num_rows:
                lo = float(pc.min(mine.column("s_start_m")).as_py())
                hi = float(pc.max(mine.column("s_end_m")).as_py())
                parts.append(f"{split} {lo:.1f}-{hi:.1f} m")
            else:
                parts.append(f"{split} none")
        lines.append(f"- `{s.log_id}`: " + ", ".join(parts))
    return lines


def _per_tyre(events: pa.Table) -> NDArray[np.int64]:
    return np.concatenate(
        [events.column("points_left").to_numpy(), events.column("points_right").to_numpy()]
    ).astype(np.int64)


def dataset_card(facts: DatasetFacts) -> str:
    """The dataset card (``README.md``): YAML metadata, then what a reader must know."""
    counts = facts.counts()
    total = SplitTotals(
        sum(c.events for c in counts.values()),
        sum(c.rough for c in counts.values()),
        sum(c.points for c in counts.values()),
    )
    lines = [
        *_yaml_header(facts),
        *_introduction(facts, total),
        *_loading(facts),
        *_columns(facts),
        *_label(facts),
        *_frames_and_units(facts),
        *_split(facts, counts),
        *_model_scores(facts),
        *_provenance(facts),
        "",
        "## Known limitations",
        "",
        *_limitations(facts, counts, total),
        *_citation_and_license(),
    ]
    return "\n".join(lines)


def _introduction(facts: DatasetFacts, total: SplitTotals) -> list[str]:
    """The title and what the data is, how much, and from how many (simulated) logs."""
    sims = [s for s in facts.sources if s.sim is not None]
    return [
        "",
        f"# {PRETTY_NAME}",
        "",
        "Terrain *events* (consecutive stretches of a vehicle's driven path) labelled "
        "*rough* or not from the shock the vehicle's IMU felt on them, and the laser points "
        "observed on the ground under its rear tyres before it drove there: the training and "
        "test data of Stavens & Thrun (2006), *A Self-Supervised Terrain Roughness Estimator "
        "for Off-Road Autonomous Driving*. A model sees the points of an event and predicts "
        "whether it is rough; the labels come from the vehicle itself (self-supervised).",
        "",
        f"{total.events} events ({total.rough} rough) and {total.points} point rows from "
        f"{len(facts.sources)} log(s)"
        + (
            f", {len(sims)} of them simulated"
            if sims and len(sims) < len(facts.sources)
            else (": simulated data" if sims else ": recorded data")
        )
        + f". Made by the `terrain` toolkit version {__version__} (`terrain export`).",
    ]


def _loading(facts: DatasetFacts) -> list[str]:
    """How to load the data, and every file with its rows, bytes and sha256."""
    lines = [
        "",
        "## Loading",
        "",
        "Two configs, each with a `train` and a `test` split:",
        "",
        "```python",
        "from datasets import load_dataset",
        'events = load_dataset("path/to/this/folder", "events")        # DatasetDict: train, test',
        'points = load_dataset("path/to/this/folder", "event_points")',
        "```",
        "",
        "or read the Parquet files directly (`polars.read_parquet`, `pandas.read_parquet`, "
        "`pyarrow.parquet.read_table`), or through `croissant.json` (MLCommons Croissant 1.0, "
        "`mlcroissant.Dataset(jsonld=...)`, record sets `events` and `event_points`). An "
        "event's points are the `event_points` rows with its `log_id` and `event_id`; `wheel` "
        "says under which rear tyre.",
        "",
        "| config | split | file | rows | bytes | sha256 |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for name in facts.columns:
        for split in SPLITS:
            path = data_file(name, split)
            size, sha = facts.files[path]
            lines.append(
                f"| {name} | {split} | `{path}` | {facts.rows(name, split)} | {size} | `{sha}` |"
            )
    return lines


def _columns(facts: DatasetFacts) -> list[str]:
    """Each config's columns: type, unit, meaning."""
    return [
        "",
        "## Columns",
        "",
        "### `events`: one row per event",
        "",
        *_column_table(facts.columns[EVENTS]),
        "",
        "### `event_points`: one row per laser point, event and rear tyre",
        "",
        *_column_table(facts.columns[EVENT_POINTS]),
    ]


def _label(facts: DatasetFacts) -> list[str]:
    """The label's definition with the configuration's numbers, and the data's ranges."""
    cfg = facts.config
    all_events = pa.concat_tables([facts.events[s] for s in SPLITS])
    return [
        "",
        "## The label",
        "",
        "- " + _shock_definition(cfg),
        "- `speed_mph` is the vehicle's mean speed over the event (its length over the time "
        "taken), in mph (1 mph = 0.44704 m/s).",
        "- `ruggedness` = `shock_g` / `speed_mph`, in G per mph: shock grows about linearly "
        "with speed, so the quotient is a speed-independent measure of the terrain (sect. "
        "5.2).",
        f"- `rough` = `ruggedness` >= {cfg.label.rough_threshold_g_per_mph:g} G/mph (sect. 7 "
        "uses .02 G/mph), the class to detect.",
        f"- Events are {cfg.label.event_length_m:g} m stretches of the rear axle's path "
        "(`s_start_m`, `s_end_m`: distance along it); events slower than "
        f"{cfg.label.min_speed_mps:g} m/s are not labelled.",
        f"- Here `shock_g` ranges from {_num(float(pc.min(all_events.column('shock_g')).as_py()))} "
        f"to {_num(float(pc.max(all_events.column('shock_g')).as_py()))} G, `speed_mph` from "
        f"{_num(float(pc.min(all_events.column('speed_mph')).as_py()))} to "
        f"{_num(float(pc.max(all_events.column('speed_mph')).as_py()))} mph.",
    ]


def _frames_and_units(facts: DatasetFacts) -> list[str]:
    """The points' frames and units, which points are listed, each log's ENU origin."""
    cfg = facts.config
    lines = [
        "",
        "## Frames and units of the points",
        "",
        "- `x`, `y`, `z`: metres in a local ENU frame (x east, y north, z up) whose origin is "
        "the log's first valid GPS fix: each log has its own origin, so coordinates of "
        "different logs are not in one frame.",
        "- `tau`: the time the point was observed, in seconds on the log's clock (`t_ns`, the "
        "same time in integer nanoseconds, is exact; `tau` = `t_ns` / 1e9).",
        "- `roll_rate`, `pitch_rate`: rad/s, the time derivatives of the vehicle's estimated "
        "roll and pitch when the point was observed (the paper's gamma and psi).",
        "- `laser`: the topic of the laser that saw the point; `wheel`: `left` or `right` rear "
        "tyre.",
        f"- Which points: those within {cfg.model.wheel_window_radius_m:g} m of the ground a "
        "rear tyre traversed during the event, observed before the rear axle got there and at "
        f'most {cfg.tables.max_lookahead_s:g} s before (sect. 7: "within 30cm of terrain the '
        "vehicle's rear tires traversed\").",
    ]
    origins = [
        (s.log_id, s.header["pose"]["enu_origin"])
        for s in facts.sources
        if isinstance(s.header.get("pose", {}).get("enu_origin"), dict)
    ]
    for log_id, o in origins:
        lines.append(
            f"- ENU origin of `{log_id}`: latitude {o.get('latitude_deg')}, longitude "
            f"{o.get('longitude_deg')} (degrees, WGS84), altitude {o.get('altitude_m')} m."
        )
    return lines


def _split(facts: DatasetFacts, counts: Mapping[str, SplitTotals]) -> list[str]:
    """How the split is made, the stretches each covers, and per split the counts."""
    cfg = facts.config
    scope = (
        "the logs in time order taken as one route"
        if cfg.tables.split_scope == "all_logs"
        else "each log on its own"
    )
    lines = [
        "",
        "## The split",
        "",
        f"By distance driven, as the paper trains on miles 60-70 of the race and tests on "
        f"miles 70-80: the first {100 * cfg.tables.train_fraction:g} % of the driven distance "
        f"({scope}) trains, the rest tests; an event belongs to the side its middle lies on, "
        "and its points to its split. Stretches covered:",
        "",
        *_distance_lines(facts),
        "",
        "| split | events | rough | rough share | point rows | points per tyre (median) |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for split in SPLITS:
        c = counts[split]
        tyre = _per_tyre(facts.events[split])
        median = f"{float(np.median(tyre)):g}" if tyre.size else "n/a"
        lines.append(
            f"| {split} | {c.events} | {c.rough} | {_pct(c.rough, c.events)} | {c.points} | "
            f"{median} |"
        )
    return lines


def _model_scores(facts: DatasetFacts) -> list[str]:
    """What the model's scores in the events files are (nothing without scores)."""
    if facts.scores is None:
        return []
    scored_mu = facts.scores.mu
    mu = "" if scored_mu is None else f" (mu = {scored_mu!r} in the model that was scored)"
    return [
        "",
        "## The model's scores",
        "",
        f"The `events` files carry the scores of the report's headline method, {title(HEADLINE)}"
        ": the roughness model `terrain learn` fitted on the train split: `r_combined` (eq. 5) "
        "and `predicted` = `r_combined` > mu"
        f"{mu}. On the train split they are in-sample; only the test split measures the "
        "model. They are not labels: a new model should ignore them.",
    ]


def _provenance(facts: DatasetFacts) -> list[str]:
    """The toolkit, the tables and configuration hashes, and the source logs."""
    cfg = facts.config
    sims = [s for s in facts.sources if s.sim is not None]
    lines = ["", "## Provenance", ""]
    lines += [
        f"Exported by the `terrain` toolkit version {__version__} from a workspace whose "
        "tables `terrain tables` wrote (sha256: "
        + ", ".join(f"`{k}` {v}" for k, v in sorted(facts.tables.items()))
        + f"), configuration `{cfg.name}` (its label, tables, model and vehicle sections "
        f"hash to {export_config_hash(cfg)}, the `config_hash` of every Parquet file's "
        "metadata). Source logs (MCAP), by their sha256:",
        "",
        *_log_rows(facts),
    ]
    for s in sims:
        lines.append("")
        lines.append(
            f"`{s.log_id}` is simulated: its terrain, vehicle and sensors were generated by "
            "the toolkit's simulator (`terrain sim`), not recorded on a vehicle."
        )
    return lines


def _citation_and_license() -> list[str]:
    """The paper to cite, and the data's license."""
    return [
        "",
        "## Citation",
        "",
        "The method and the experiment this data reproduces:",
        "",
        "```bibtex",
        CITATION,
        "```",
        "",
        "## License",
        "",
        "Creative Commons Attribution 4.0 International (CC BY 4.0).",
        "",
    ]


def _limitations(
    facts: DatasetFacts, counts: Mapping[str, SplitTotals], total: SplitTotals
) -> list[str]:
    """What a user of the data must keep in mind, with this data's numbers: one bullet each,
    those that do not apply to this data left out."""
    bullets = [
        _rare_positives(counts),
        _simulated_data(facts),
        _point_density(facts, counts),
        _rows_not_distinct(facts, total),
        _not_every_stretch(facts),
        _small(facts),
        "- **Labels from the vehicle's own sensors.** Shock depends on the vehicle and its "
        "suspension, and dividing by speed is a linear approximation (the paper's Fig. 5); "
        "an event is rough for this vehicle at the speed it drove.",
        "- **Each log has its own frame.** Compare coordinates only within a log (the same "
        "`log_id`).",
    ]
    return [b for b in bullets if b]


def _rare_positives(counts: Mapping[str, SplitTotals]) -> str:
    """The rough share of each split, against the paper's."""
    paper = " and ".join(f"{k} of {n:,}, {_pct(k, n)}" for k, n in PAPER_ROUGH)
    return (
        "- **Rare positives.** "
        + "; ".join(
            f"{split}: {c.rough} rough of {c.events} events ({_pct(c.rough, c.events)})"
            for split, c in counts.items()
        )
        + f" (the paper: {paper}). With so few positives, rates and ROC curves on the test "
        "split are uncertain: report confidence intervals."
    )


def _simulated_data(facts: DatasetFacts) -> str:
    """How many logs are simulated and the pose's error against their truth; "" if none."""
    sims = [s for s in facts.sources if s.sim is not None]
    if not sims:
        return ""
    accuracy = []
    for s in sims:
        acc = s.header.get("pose_accuracy", {})
        if "horizontal_rmse_m" in acc and "vertical_rmse_m" in acc:
            accuracy.append(
                f"`{s.log_id}`: horizontal {acc['horizontal_rmse_m']} m, vertical "
                f"{acc['vertical_rmse_m']} m RMSE"
            )
    return (
        f"- **Simulated data.** {len(sims)} of {len(facts.sources)} log(s) are simulated: "
        "terrain, vehicle dynamics, IMU, GPS and lasers are models, so a method that works "
        "here has not been shown to work on a real vehicle."
        + (
            " The points carry the errors of the estimated pose against the simulator's "
            "truth (" + "; ".join(accuracy) + ")."
            if accuracy
            else ""
        )
    )


def _point_density(facts: DatasetFacts, counts: Mapping[str, SplitTotals]) -> str:
    """Point rows per tyre and event here, against the paper's training set."""
    train = counts["train"]
    paper_tyre = PAPER_TRAIN_POINTS / PAPER_TRAIN_EVENTS / 2
    tyre = _per_tyre(pa.concat_tables([facts.events[s] for s in SPLITS]))
    mean_tyre = float(tyre.mean()) if tyre.size else 0.0
    return (
        f"- **Points per tyre far denser than the paper's.** {_num(mean_tyre)} point rows per "
        f"tyre and event on average here, against {_num(paper_tyre)} in the paper's training "
        f"set ({PAPER_TRAIN_POINTS:,} points for {PAPER_TRAIN_EVENTS:,} events): about "
        f"{_num(mean_tyre / paper_tyre)} times as many, from the lasers' rates and mounting "
        "and the event length. A model tuned here may need re-tuning (e.g. a cap on points "
        f"per tyre) at the paper's density. Train split: {train.points} point rows for "
        f"{train.events} events."
    )


def _rows_not_distinct(facts: DatasetFacts, total: SplitTotals) -> str:
    """Points listed under two events; "" when the tables stage did not count them."""
    distinct = facts.tables_counts.get("distinct_points")
    if not distinct:
        return ""
    return (
        "- **Rows are not distinct points.** A point near the boundary of two events is "
        f"listed under each: the tables stage counted {distinct} distinct points under the "
        "tyres (before leaving out the events it could not score) for these "
        f"{total.points} point rows."
    )


def _not_every_stretch(facts: DatasetFacts) -> str:
    """The events left out and the stretches never labelled; "" if none."""
    dropped = int(facts.tables_rejects.get("too_few_points", 0))
    label_rejects: dict[str, int] = {}
    for s in facts.sources:
        for reason, n in (s.header.get("label", {}).get("rejects", {}) or {}).items():
            label_rejects[str(reason)] = label_rejects.get(str(reason), 0) + int(n)
    parts = []
    if dropped:
        parts.append(
            f"{dropped} event(s) had fewer than {facts.config.tables.min_points_per_wheel} "
            "points under a tyre and were left out (they cannot be scored)"
        )
    if any(label_rejects.values()):
        parts.append(
            "stretches not labelled at all: "
            + ", ".join(f"{n} {reason}" for reason, n in sorted(label_rejects.items()) if n)
        )
    if not parts:
        return ""
    return (
        "- **Not every stretch is an event.** " + "; ".join(parts) + ". The events are "
        "the driven path minus these, which is not a random sample of it."
    )


def _small(facts: DatasetFacts) -> str:
    """The length of path the events cover, against the paper's splits."""
    length = sum(
        float(pc.sum(pc.subtract(e.column("s_end_m"), e.column("s_start_m"))).as_py() or 0.0)
        for e in facts.events.values()
    )
    return (
        f"- **Small.** The events cover {length:.0f} m of driving; the paper's splits are 10 "
        "miles (16.1 km) each."
    )


__all__ = ["LICENSE", "PRETTY_NAME", "dataset_card"]
