"""Array type aliases shared by the whole package.

One home for the dtype-tagged array types that annotations use, so that every module means the
same thing by ``FloatArray``.  They say nothing about shape; docstrings give the shapes.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["BoolArray", "FloatArray", "IntArray"]

FloatArray = NDArray[np.float64]
"""A float64 array of any shape."""

IntArray = NDArray[np.int64]
"""An int64 array of any shape (indices, ids, counts)."""

BoolArray = NDArray[np.bool_]
"""A boolean mask of any shape."""
