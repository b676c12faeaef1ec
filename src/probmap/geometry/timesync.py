"""Time synchronisation of pose streams: nearest-time lookup and pose interpolation.

Two sensors rarely stamp the same instants; these functions put one stream on the other's clock.
Times are seconds on a common clock; poses are ``(x, y, theta)`` in metres and radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from probmap._typing import FloatArray, IntArray
from probmap.geometry.se2 import wrap_angle

__all__ = ["TimeOffset", "find_time_offset", "interpolate_poses", "nearest_time_index"]


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


@dataclass(frozen=True)
class TimeOffset:
    """What :func:`find_time_offset` found.

    Attributes
    ----------
    offset : float
        Seconds to add to the second stream's times to put them on the first's clock.
    correlation : float
        Normalized correlation (-1..1) of the two motion profiles at that offset: near 1 for
        two recordings of the same run.
    matched : float
        Share (0..1) of the second stream's times within ``tol`` of one of the first's after
        the shift (1 when one log's stamps are the other's, shifted).
    """

    offset: float
    correlation: float
    matched: float


def _motion_profile(times: FloatArray, poses: FloatArray, step: float) -> FloatArray:
    """Speed and turn rate (2, K) on a grid of ``step`` seconds from the first time, each
    scaled to zero mean and unit variance (flat: zeros)."""
    order = np.argsort(times, kind="stable")
    t, p = times[order], poses[order]
    keep = np.r_[True, np.diff(t) > 0]
    t, p = t[keep], p[keep]
    grid = t[0] + step * np.arange(max(int((t[-1] - t[0]) / step), 1) + 1)
    x, y = np.interp(grid, t, p[:, 0]), np.interp(grid, t, p[:, 1])
    th = np.interp(grid, t, np.unwrap(p[:, 2]))
    prof = np.stack([np.hypot(np.diff(x), np.diff(y)), np.abs(np.diff(th))]) / step
    prof = prof - prof.mean(axis=1, keepdims=True)
    sd = prof.std(axis=1, keepdims=True)
    return np.where(sd > 0, prof / np.where(sd > 0, sd, 1.0), 0.0)


def find_time_offset(
    times_a: ArrayLike,
    poses_a: ArrayLike,
    times_b: ArrayLike,
    poses_b: ArrayLike,
    *,
    step: float = 0.1,
    tol: float = 0.02,
) -> TimeOffset:
    """The clock offset between two recordings of one run (a raw log's odometry and a
    corrected log, a SLAM trajectory, a bag): the shift of ``b``'s times that best lines up
    the two motion profiles (speed and turn rate, sampled every ``step`` seconds and
    cross-correlated over every overlap), then refined to the stamps: when most of ``b``'s
    shifted times lie within ``step`` of ``a``'s, the median of those residuals is added, so
    that stamps one log copied from the other match exactly.

    Parameters
    ----------
    times_a, poses_a : (N,), (N, 3) array_like
        The first stream (seconds; x, y, theta). Times need not be sorted.
    times_b, poses_b : (M,), (M, 3) array_like
        The second stream, on another clock. Poses in any fixed frame (speeds and turn
        rates are compared, not positions).
    step : float
        Resolution of the profiles (s).
    tol : float
        Stamps within ``tol`` seconds count as matched.

    Returns
    -------
    TimeOffset

    Raises
    ------
    ValueError
        A stream of fewer than two distinct times, or shapes that disagree.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(0.0, 300.0, 0.5)
    >>> poses = np.column_stack([np.cumsum(np.abs(np.sin(t / 7))), np.sin(t / 3), np.cos(t / 11)])
    >>> found = find_time_offset(t, poses, t[40:500:3] - 1000.0, poses[40:500:3])
    >>> round(found.offset, 6), found.matched
    (1000.0, 1.0)
    """
    ta, tb = (np.asarray(v, dtype=np.float64).reshape(-1) for v in (times_a, times_b))
    pa = np.asarray(poses_a, dtype=np.float64).reshape(-1, 3)
    pb = np.asarray(poses_b, dtype=np.float64).reshape(-1, 3)
    if pa.shape[0] != ta.size or pb.shape[0] != tb.size:
        raise ValueError("each stream needs one pose per time")
    if np.unique(ta).size < 2 or np.unique(tb).size < 2:
        raise ValueError("each stream needs at least two distinct times")
    if not step > 0:
        raise ValueError(f"step must be > 0 s, got {step}")
    a, b = _motion_profile(ta, pa, step), _motion_profile(tb, pb, step)
    n = a.shape[1] + b.shape[1]
    size = 1 << (n - 1).bit_length()
    fa, fb = np.fft.rfft(a, size), np.fft.rfft(b, size)
    corr = np.fft.irfft(fa * np.conj(fb), size).sum(axis=0)  # corr[k]: a[i + k] with b[i]
    lags = np.r_[np.arange(a.shape[1]), np.arange(-b.shape[1] + 1, 0)]
    vals = np.r_[corr[: a.shape[1]], corr[size - b.shape[1] + 1 :]]
    overlap = np.minimum(a.shape[1] - lags, b.shape[1]) - np.maximum(-lags, 0)
    # the sum over the overlap per sample of the shorter profile: the correlation where one
    # recording covers the other, less where they overlap in part (a short overlap cannot
    # win by chance); lags that overlap by under a quarter of it do not compete
    shorter = min(a.shape[1], b.shape[1])
    ok = overlap >= max(2, shorter // 4)
    score = np.where(ok, vals / shorter, -np.inf)
    k = int(np.argmax(score))
    offset = (ta.min() - tb.min()) + lags[k] * step
    shifted = tb + offset
    near = np.sort(ta)[np.clip(np.searchsorted(np.sort(ta), shifted), 0, ta.size - 1)]
    before = np.sort(ta)[np.clip(np.searchsorted(np.sort(ta), shifted) - 1, 0, ta.size - 1)]
    resid = np.where(np.abs(near - shifted) < np.abs(before - shifted), near, before) - shifted
    close = np.abs(resid) <= step
    if close.mean() > 0.5:
        offset += float(np.median(resid[close]))
    idx = nearest_time_index(ta, tb + offset, tol)
    return TimeOffset(float(offset), float(score[k] / 2.0), float(np.mean(idx >= 0)))
