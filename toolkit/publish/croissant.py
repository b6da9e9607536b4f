"""The export described a second time, machine-readably, in MLCommons Croissant 1.0
(``croissant.json``, JSON-LD): a file object per Parquet file with its sha256, a file set
and a record set per config. See ``docs/export.md``."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from toolkit import __version__
from toolkit.publish import dataset
from toolkit.publish.dataset import DatasetFacts
from toolkit.tableio import ColumnSpec

DATASET_NAME = "terrain-roughness-self-supervised"
#: Croissant 1.0's JSON-LD context, as the specification's examples give it, with the two terms
#: later 1.0 tooling (mlcroissant) also declares, ``equivalentProperty`` and
#: ``samplingRate``: without them mlcroissant warns that the context is not the standard one.
CROISSANT_CONTEXT: dict[str, Any] = {
    "@language": "en",
    "@vocab": "https://schema.org/",
    "citeAs": "cr:citeAs",
    "column": "cr:column",
    "conformsTo": "dct:conformsTo",
    "cr": "http://mlcommons.org/croissant/",
    "rai": "http://mlcommons.org/croissant/RAI/",
    "data": {"@id": "cr:data", "@type": "@json"},
    "dataType": {"@id": "cr:dataType", "@type": "@vocab"},
    "dct": "http://purl.org/dc/terms/",
    "equivalentProperty": "cr:equivalentProperty",
    "examples": {"@id": "cr:examples", "@type": "@json"},
    "extract": "cr:extract",
    "field": "cr:field",
    "fileProperty": "cr:fileProperty",
    "fileObject": "cr:fileObject",
    "fileSet": "cr:fileSet",
    "format": "cr:format",
    "includes": "cr:includes",
    "isLiveDataset": "cr:isLiveDataset",
    "jsonPath": "cr:jsonPath",
    "key": "cr:key",
    "md5": "cr:md5",
    "parentField": "cr:parentField",
    "path": "cr:path",
    "recordSet": "cr:recordSet",
    "references": "cr:references",
    "regex": "cr:regex",
    "repeated": "cr:repeated",
    "replace": "cr:replace",
    "samplingRate": "cr:samplingRate",
    "sc": "https://schema.org/",
    "separator": "cr:separator",
    "source": "cr:source",
    "subField": "cr:subField",
    "transform": "cr:transform",
}
CROISSANT_CONFORMS_TO = "http://mlcommons.org/croissant/1.0"


def croissant_metadata(facts: DatasetFacts) -> dict[str, Any]:
    """The Croissant 1.0 description of the export (JSON-LD): every file with its sha256,
    a file set per config, and a record set per config whose fields are its columns."""
    sims = [s for s in facts.sources if s.sim is not None]
    return {
        "@context": CROISSANT_CONTEXT,
        "@type": "sc:Dataset",
        "name": DATASET_NAME,
        "description": _description(facts),
        "conformsTo": CROISSANT_CONFORMS_TO,
        "citeAs": dataset.CITATION,
        "license": "https://creativecommons.org/licenses/by/4.0/",
        # Where the dataset is published is not known here: its landing page is the card
        # beside this file (replace with the hosting URL when publishing).
        "url": "README.md",
        "version": __version__,
        # The day the tables were made: the data's date, so exporting the same tables
        # again gives the same file (mlcroissant warns without a datePublished).
        **({"datePublished": facts.tables_finished_utc[:10]} if facts.tables_finished_utc else {}),
        "keywords": [
            "terrain roughness",
            "self-supervised learning",
            "lidar",
            "off-road driving",
            *(["simulated"] if sims else []),
        ],
        "distribution": _distribution(facts),
        "recordSet": [_record_set(name, columns) for name, columns in facts.columns.items()],
    }


def _description(facts: DatasetFacts) -> str:
    """The dataset in a paragraph: the label's rule, the source, each split's counts."""
    counts = facts.counts()
    sims = [s for s in facts.sources if s.sim is not None]
    kind = "simulated" if len(sims) == len(facts.sources) else "recorded" if not sims else "mixed"
    return (
        "Terrain events labelled rough or not from the shock a vehicle's IMU felt on them "
        "(ruggedness = shock in G / speed in mph >= "
        f"{facts.config.label.rough_threshold_g_per_mph:g} G/mph), and the laser points "
        "observed under its rear tyres before it drove there: the data of Stavens & Thrun "
        "(2006), reproduced by the terrain toolkit "
        f"{__version__} from {len(facts.sources)} {kind} log(s). "
        + "; ".join(
            f"{split}: {c.events} events, {c.rough} rough, {c.points} point rows"
            for split, c in counts.items()
        )
        + ". See README.md."
    )


def _distribution(facts: DatasetFacts) -> list[dict[str, Any]]:
    """A FileObject per Parquet file (its size and sha256), then a FileSet per config."""
    distribution: list[dict[str, Any]] = []
    for name in facts.columns:
        for split in dataset.SPLITS:
            path = dataset.data_file(name, split)
            size, sha = facts.files[path]
            distribution.append(
                {
                    "@type": "cr:FileObject",
                    "@id": path,
                    "name": path,
                    "description": f"the {split} split of the {name} config",
                    "contentUrl": path,
                    "contentSize": f"{size} B",
                    "encodingFormat": "application/x-parquet",
                    "sha256": sha,
                }
            )
    for name in facts.columns:
        distribution.append(
            {
                "@type": "cr:FileSet",
                "@id": f"{name}-files",
                "name": f"{name}-files",
                "description": f"the {name} config's Parquet files, one per split",
                "encodingFormat": "application/x-parquet",
                "includes": f"data/{name}/*.parquet",
            }
        )
    return distribution


def _record_set(name: str, columns: Sequence[ColumnSpec]) -> dict[str, Any]:
    """One config as a RecordSet: a field per column (the points' split: their file)."""
    fields: list[dict[str, Any]] = [
        {
            "@type": "cr:Field",
            "@id": f"{name}/{col.name}",
            "name": col.name,
            "description": col.description + (f" [{col.unit}]" if col.unit else ""),
            "dataType": dataset.TYPES[col.type][1],
            "source": {"fileSet": {"@id": f"{name}-files"}, "extract": {"column": col.name}},
        }
        for col in columns
    ]
    if name == dataset.EVENT_POINTS:
        # A point's split is the file it is in (its event's split).
        fields.append(
            {
                "@type": "cr:Field",
                "@id": f"{name}/split",
                "name": "split",
                "description": "'train' or 'test': the split of the point's event (its file)",
                "dataType": "sc:Text",
                "source": {
                    "fileSet": {"@id": f"{name}-files"},
                    "extract": {"fileProperty": "fullpath"},
                    "transform": {
                        "regex": f"^data/{name}/(train|test)-[0-9]+-of-[0-9]+\\.parquet$"
                    },
                },
            }
        )
    return {
        "@type": "cr:RecordSet",
        "@id": name,
        "name": name,
        "description": (
            "one row per event: its shock, speed, ruggedness, rough label and split"
            if name == dataset.EVENTS
            else "one row per laser point, event and rear tyre (the paper's L_i)"
        ),
        "field": fields,
    }


__all__ = ["CROISSANT_CONFORMS_TO", "CROISSANT_CONTEXT", "DATASET_NAME", "croissant_metadata"]
