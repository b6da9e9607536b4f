"""The array types every module annotates with (numpy's ``NDArray`` of one dtype)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

#: float64 arrays: metres, seconds, radians, ...
FloatArray = NDArray[np.float64]
#: int64 arrays: nanosecond stamps, indices, counts.
IntArray = NDArray[np.int64]
#: Boolean masks.
BoolArray = NDArray[np.bool_]
#: Floating arrays of any precision (the simulator keeps some grids in float32).
AnyFloatArray = NDArray[np.floating[Any]]

__all__ = ["AnyFloatArray", "BoolArray", "FloatArray", "IntArray"]
