"""What learn and evaluate read of the workspace (:mod:`toolkit.stages.training_data`).

The tables' checks, the split and the patches are exercised through the stages on the
sample log (``test_learn.py``, ``test_evaluate.py``); here, ``model.json`` read strictly.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

from toolkit.errors import StageError
from toolkit.stages.training_data import load_model
from toolkit.workspace import Workspace


@pytest.mark.parametrize(
    ("key", "value", "says"),
    [
        ("omega", 5.9, "'omega' must be an integer, not 5.9"),
        ("omega", "7", "'omega' must be an integer, not '7'"),
        ("upsilon", "1.05", "'upsilon' must be a finite number"),
        ("mu", float("inf"), "'mu' must be a finite number, not inf"),
        ("zeta", True, "'zeta' must be a finite number, not True"),
        ("alpha", 3, "'alpha' must be a list"),
        ("mu", None, "'mu' must be a finite number, not None"),
    ],
)
def test_a_model_json_is_read_strictly(tmp_path: Path, key: str, value: Any, says: str) -> None:
    """A value learn would never write is refused naming the file and the key, not
    truncated (omega 5.9 as 5), converted ("7") or left to fail inside the model."""
    ws = Workspace(tmp_path)
    doc = {"alpha": [1.0, 1.0, 0.01, 1.0, 0.1, 1.0, 0.0, 1.0, 0.0, 1.0], "upsilon": 1.05,
           "omega": 3, "zeta": 1.0, "mu": 0.5}  # fmt: skip
    ws.model_path.write_text(json.dumps(doc))
    params, _ = load_model(ws)
    assert params.omega == 3 and params.mu == 0.5
    ws.model_path.write_text(json.dumps({**doc, key: value}))
    with pytest.raises(StageError, match=re.escape(says)) as err:
        load_model(ws)
    assert str(ws.model_path) in str(err.value)
