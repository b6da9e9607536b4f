"""Strict JSON (RFC 8259), which has no token for NaN or an infinity.

Python's :mod:`json` writes ``NaN`` and ``Infinity`` by default and reads them back, and reads
a number too large for a float (``1e999``) as an infinity: output another program cannot
parse, and input that is no number. Every ``--json`` output of the command line goes through
:func:`dumps` (a NaN or infinite value is ``null``: no value, which it is); a file the toolkit
reads back, such as a manifest, is checked with :func:`non_finite_field`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any


def finite_or_null(obj: Any) -> Any:
    """``obj`` with every NaN or infinite float, at any depth of its dicts, lists and tuples,
    replaced by None (JSON ``null``); anything else as it is."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {k: finite_or_null(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [finite_or_null(v) for v in obj]
    return obj


def dumps(obj: Any, *, indent: int | None = 2, sort_keys: bool = False) -> str:
    """``obj`` as strict JSON text: non-finite floats as ``null`` (:func:`finite_or_null`),
    and ``allow_nan=False`` so nothing else can bring a ``NaN`` token in."""
    return json.dumps(finite_or_null(obj), indent=indent, sort_keys=sort_keys, allow_nan=False)


def non_finite_field(obj: Any, where: str = "") -> str | None:
    """The dotted path (``stages.pose.timings_s.filter``; list items by index) of the first
    NaN or infinite number in parsed JSON ``obj``, or None when every number is finite."""
    if isinstance(obj, float):
        return None if math.isfinite(obj) else where or "(the document)"
    if isinstance(obj, Mapping):
        items: Any = obj.items()
    elif isinstance(obj, list):
        items = enumerate(obj)
    else:
        return None
    for key, value in items:
        found = non_finite_field(value, f"{where}.{key}" if where else str(key))
        if found is not None:
            return found
    return None


__all__ = ["dumps", "finite_or_null", "non_finite_field"]
