"""The methods declared once: the scores schema, the summary, the report and the stage's
rows all follow the registry."""

from __future__ import annotations

import pytest

from toolkit.analysis import method_registry as reg
from toolkit.analysis.methods import ABLATIONS, Rows
from toolkit.tableio import load_table_schema


def test_the_scores_schema_has_one_column_per_declared_method_in_the_report_order() -> None:
    # The headline's scores are the schema's r_combined/predicted; every other method has
    # its own column, in the order the registry declares them.
    names = [c.name for c in load_table_schema("scores").columns]
    assert names[names.index("ruggedness") + 1 :] == list(reg.SCORE_COLUMNS)
    assert reg.HEADLINE not in names


def test_each_method_is_declared_once_with_its_own_style() -> None:
    keys = [m.key for m in reg.METHODS]
    assert len(keys) == len(set(keys))
    styles = [(m.color, m.linestyle) for m in reg.METHODS]
    assert len(styles) == len(set(styles))
    assert [m.key for m in reg.METHODS if m.kind == "headline"] == [reg.HEADLINE]
    assert reg.MAIN_METHODS + reg.ABLATION_NAMES == reg.METHOD_KEYS


def test_the_ablations_computed_are_the_ablations_declared() -> None:
    assert {*ABLATIONS, reg.UNLEARNED_START} == set(reg.ABLATION_NAMES)


def test_a_row_no_method_declares_is_refused() -> None:
    rows = Rows()
    assert list(rows.methods) == list(reg.METHOD_KEYS)
    with pytest.raises(reg.UnknownMethodError, match="no method 'baseline_typo'"):
        rows.add("baseline_typo", None, {})


def test_an_undeclared_key_of_an_old_summary_is_shown_by_its_key() -> None:
    assert reg.title("retired_method") == "retired_method"
    assert reg.title(reg.HEADLINE) == "self-supervised (this model)"
