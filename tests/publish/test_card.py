"""The dataset card (``README.md``) of ``terrain export``: its YAML header is what
``datasets.load_dataset`` reads the export by, and its prose states the data's numbers."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from tests.publish.exported import CONFIGS, SPLITS, assert_same_rows, card_header
from tests.stages.test_learn import Pipeline
from toolkit import __version__
from toolkit.config import PipelineConfig
from toolkit.manifest import Manifest, file_sha256
from toolkit.publish.dataset import data_file
from toolkit.publish.export import ExportResult


def test_datasets_loads_both_configs_and_splits_as_the_tables_hold_them(
    exported: tuple[Path, ExportResult],
    expected: dict[str, dict[str, pa.Table]],
    hf_offline: Path,
) -> None:
    """``datasets.load_dataset(OUT, config)``, as a team that knows nothing of the toolkit
    loads it: train and test splits, the card's features (dtypes of the Parquet files), and
    every row of the tables, in order; without a config it loads ``events``."""
    import datasets

    out, _ = exported
    for config in CONFIGS:
        loaded = datasets.load_dataset(str(out), config, cache_dir=str(hf_offline))
        assert sorted(loaded) == sorted(SPLITS)
        for split in SPLITS:
            ds = loaded[split]
            want = expected[config][split]
            assert ds.num_rows == want.num_rows
            assert {n: f.dtype for n, f in ds.features.items()} == {
                f.name: {"double": "float64"}.get(str(f.type), str(f.type)) for f in want.schema
            }
            table = ds.with_format("arrow")[:]
            assert_same_rows({n: table.column(n) for n in table.column_names}, want, config)
    default = datasets.load_dataset(str(out), cache_dir=str(hf_offline))
    assert default["train"].num_rows == expected["events"]["train"].num_rows
    assert default["train"].column_names == expected["events"]["train"].column_names


def test_the_card_maps_configs_to_files_and_states_the_data_s_numbers(
    exported: tuple[Path, ExportResult],
    expected: dict[str, dict[str, pa.Table]],
    pipeline: Pipeline,
    config: PipelineConfig,
) -> None:
    """The YAML header: license, pretty name, configs -> split files that exist, features
    equal to the files' columns and types, split sizes; the prose: the toolkit's version,
    the source log's id and sha256, that it is simulated, the label's definition with the
    configured threshold, the split's fraction, and per split the events, rough events and
    point rows counted from the tables."""
    out, _ = exported
    header = card_header(out)
    assert header["license"] == "cc-by-4.0" and header["pretty_name"]
    assert "tabular-classification" in header["task_categories"]
    assert "simulated" in header["tags"]
    assert [c["config_name"] for c in header["configs"]] == list(CONFIGS)
    for entry in header["configs"]:
        files = {f["split"]: f["path"] for f in entry["data_files"]}
        assert files == {s: data_file(entry["config_name"], s) for s in SPLITS}
        assert all((out / p).is_file() for p in files.values())
    info = {i["config_name"]: i for i in header["dataset_info"]}
    for config_name in CONFIGS:
        schema = pq.read_schema(out / data_file(config_name, "train"))
        features = [(f["name"], f["dtype"]) for f in info[config_name]["features"]]
        assert features == [
            (f.name, {"double": "float64"}.get(str(f.type), str(f.type))) for f in schema
        ]
        splits = {s["name"]: s["num_examples"] for s in info[config_name]["splits"]}
        assert splits == {s: expected[config_name][s].num_rows for s in SPLITS}
        assert info[config_name]["download_size"] == sum(
            (out / data_file(config_name, s)).stat().st_size for s in SPLITS
        )

    text = (out / "README.md").read_text(encoding="utf-8")
    manifest = Manifest(pipeline.ws.log_manifest_path(pipeline.log_id)).read()
    assert f"version {__version__}" in text
    assert pipeline.log_id in text and manifest["source"]["sha256"] in text
    assert "simulated" in text.lower()
    threshold = config.label.rough_threshold_g_per_mph
    assert f"`rough` = `ruggedness` >= {threshold:g} G/mph" in text
    assert f"{config.label.fir_taps}-tap" in text and f"0-{config.label.fir_stop_hz:g} Hz" in text
    assert f"the first {100 * config.tables.train_fraction:g} % of the driven distance" in text
    for split in SPLITS:
        events = expected["events"][split]
        rough = sum(events.column("rough").to_pylist())
        points = expected["event_points"][split].num_rows
        assert f"| {split} | {events.num_rows} | {rough} | " in text
        assert f" | {points} | " in text
    assert "r_combined" in text and "## The model's scores" in text
    for path in (data_file(c, s) for c in CONFIGS for s in SPLITS):
        assert f"`{path}`" in text and file_sha256(out / path) in text
