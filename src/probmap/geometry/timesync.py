"""Time synchronisation of pose streams: nearest-time lookup and pose interpolation.

Two sensors rarely stamp the same instants; these functions put one stream on the other's clock.
Times are seconds on a common clock; poses are ``(x, y, theta)`` in metres and radians.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from probmap._typing import FloatArray, IntArray
from probmap.geometry.se2 import wrap_angle

__all__ = ["interpolate_poses", "nearest_time_index"]


def interpolate_poses(trajectory: ArrayLike, times: ArrayLike) -> FloatArray:
    """Linear interpolation of a ``(T, 4)`` ``time, x, y, theta`` trajectory at ``times``.

    Angles are interpolated along the shortest arc. Times outside the trajectory's span give NaN.

    Examples
    --------
    >>> import numpy as np
    >>> tr = np.array([[0.0, 0.0, 0.0, 0.0], [2.0, 2.0, 0.0, 1.0]])
    >>> interpolate_poses(tr, [1.0, 3.0]).round(3)
    array([[1. , 0. , 0.5],
           [nan, nan, nan]])
    """
    tr = np.asarray(trajectory, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    if tr.ndim != 2 or tr.shape[1] != 4 or tr.shape[0] < 2:
        raise ValueError(f"trajectory must have shape (T>=2, 4), got {tr.shape}")
    if np.any(np.diff(tr[:, 0]) < 0):
        raise ValueError("trajectory times must be non-decreasing")
    x = np.interp(t, tr[:, 0], tr[:, 1])
    y = np.interp(t, tr[:, 0], tr[:, 2])
    th = np.interp(t, tr[:, 0], np.unwrap(tr[:, 3]))
    out = np.stack([x, y, wrap_angle(th)], -1)
    out[(t < tr[0, 0]) | (t > tr[-1, 0])] = np.nan
    return out


def nearest_time_index(times: FloatArray, t: FloatArray, tol: float) -> IntArray:
    """Index into ``times`` of the nearest time to each ``t``, or -1 when none is within ``tol``.

    ``times`` (T,) need not be sorted; on a tie the earlier of the two neighbouring times wins.

    Examples
    --------
    >>> import numpy as np
    >>> nearest_time_index(np.array([0.0, 1.0, 2.0]), np.array([0.5, 1.9, 5.0]), 0.5)
    array([ 0,  2, -1])
    """
    order = np.argsort(times, kind="stable")
    st = times[order]
    k = np.clip(np.searchsorted(st, t), 1, len(st) - 1) if len(st) > 1 else np.zeros(len(t), int)
    if len(st) > 1:
        left = k - 1
        nearer = np.abs(st[left] - t) <= np.abs(st[k] - t)
        k = np.where(nearer, left, k)
    idx = order[k]
    return np.where(np.abs(times[idx] - t) <= tol, idx, -1)
