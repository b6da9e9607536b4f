"""Strict JSON: what every ``--json`` output is, and the check of what a manifest holds."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest

from toolkit import strict_json

PACKAGE = Path(__file__).resolve().parents[1] / "toolkit"


def _strict_loads(text: str) -> object:
    """json.loads refusing the NaN and Infinity tokens, as a strict parser does."""

    def refuse(token: str) -> object:
        raise ValueError(f"not JSON: {token}")

    return json.loads(text, parse_constant=refuse)


def test_non_finite_values_are_null_at_any_depth() -> None:
    doc = {"a": math.nan, "b": [1.5, math.inf, {"c": -math.inf}], "d": (2, "x"), "e": None}
    text = strict_json.dumps(doc)
    want = {"a": None, "b": [1.5, None, {"c": None}], "d": [2, "x"], "e": None}
    assert _strict_loads(text) == want
    assert "NaN" not in text and "Infinity" not in text


def test_non_finite_field_names_the_path() -> None:
    assert strict_json.non_finite_field({"a": [1, {"b": 2.5}], "c": "NaN"}) is None
    assert strict_json.non_finite_field({"a": [1, {"b": math.nan}]}) == "a.1.b"
    assert strict_json.non_finite_field(json.loads('{"s": {"t": 1e999}}')) == "s.t"
    assert strict_json.non_finite_field(math.inf) == "(the document)"


@pytest.mark.parametrize("module", ["cli/*.py", "listing.py"])
def test_every_json_output_of_the_command_line_is_strict(module: str) -> None:
    """The verbs print JSON through strict_json.dumps only: a bare json.dumps would print a
    NaN token for a NaN value (Python's default), which no strict parser reads."""
    for path in PACKAGE.glob(module):
        source = path.read_text(encoding="utf-8")
        assert not re.search(r"\bjson\.dumps?\(", source), path
