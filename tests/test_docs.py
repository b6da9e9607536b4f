"""The repository's own documents: the contract lists every table as ``schemas/`` defines it,
and nothing points outside the clone."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from toolkit.tableio import load_table_schema, table_schema_names

REPO = Path(__file__).resolve().parents[1]
CONTRACT = REPO / "docs" / "contract.md"


@pytest.mark.parametrize("name", table_schema_names())
def test_the_contract_lists_each_table_with_its_columns_and_units(name: str) -> None:
    rows = [line for line in CONTRACT.read_text().splitlines() if line.startswith(f"| `{name}` |")]
    assert len(rows) == 1, f"docs/contract.md has no row for the {name!r} table"
    for column in load_table_schema(name).columns:
        want = f"`{column.name}`" + (f" ({column.unit})" if column.unit else "")
        assert want in rows[0], f"{name}: {want} missing from docs/contract.md"


def test_no_document_points_outside_the_clone() -> None:
    """A clone has nothing beside it: no link to ``../shared`` or any other parent folder."""
    documents = [REPO / "README.md", *REPO.glob("docs/*.md"), *REPO.glob("*/README.md")]
    for doc in documents:
        assert not re.search(r"\.\./shared|\]\(\.\./", doc.read_text()), doc
