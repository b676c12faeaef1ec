"""SE(2) pose algebra: angle wrapping, composition, inverse and relative poses.

A pose is ``(x, y, theta)`` in metres and radians: the frame of a body expressed in a parent
frame. Every function is vectorised over leading axes of ``(..., 3)`` arrays (numpy broadcasting),
and the ``*_jacobians`` variants return the analytic derivatives used by the filters (for single
poses and batches alike, with shape ``(..., 3, 3)``).

References: Probabilistic Robotics (Thrun, Burgard, Fox), chapter 5 for the pose conventions;
the composition operator follows Smith, Self and Cheeseman (1990).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from probmap._typing import FloatArray

__all__ = [
    "between",
    "between_jacobians",
    "compose",
    "compose_jacobians",
    "inverse",
    "inverse_jacobian",
    "pose_batch",
    "transform_point",
    "wrap_angle",
]


def wrap_angle(a: ArrayLike) -> FloatArray:
    """Wrap angles to ``[-pi, pi)``.

    Parameters
    ----------
    a : array_like
        Angles in radians, any shape.

    Returns
    -------
    ndarray
        Same shape, wrapped.

    Examples
    --------
    >>> float(wrap_angle(3 * np.pi / 2))
    -1.5707963267948966
    """
    a = np.asarray(a, dtype=np.float64)
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _as_pose(p: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(p, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3) (x, y, theta), got {arr.shape}")
    return arr


def pose_batch(poses: ArrayLike, *, single: bool = False) -> FloatArray:
    """Finite poses checked, as a C-contiguous float64 ``(N, 3)`` array.

    Parameters
    ----------
    poses : array_like, shape (N, 3)
        Poses ``(x, y, theta)`` (m, rad).
    single : bool, optional
        Also take one pose of shape ``(3,)``, returned as ``(1, 3)``.

    Returns
    -------
    ndarray, shape (N, 3)
        ``poses`` itself when it already is such an array, else a copy.

    Raises
    ------
    ValueError
        ``"poses must have shape (N, 3) (x, y, theta), got ..."`` or ``"poses must be finite"``.

    Examples
    --------
    >>> pose_batch([0.0, 1.0, 0.5], single=True).shape
    (1, 3)
    """
    p = np.ascontiguousarray(poses, dtype=np.float64)
    if single and p.ndim == 1:
        p = p.reshape(1, -1)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"poses must have shape (N, 3) (x, y, theta), got {np.shape(poses)}")
    if not np.all(np.isfinite(p)):
        raise ValueError("poses must be finite")
    return p


def compose(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Pose composition ``a ⊕ b``: the pose ``b`` (given in frame ``a``) in ``a``'s parent frame.

    Parameters
    ----------
    a, b : array_like, shape (..., 3)
        Poses ``(x, y, theta)``; leading axes broadcast.

    Returns
    -------
    ndarray, shape (..., 3)
        ``(x_a + cos(t_a) x_b - sin(t_a) y_b, y_a + sin(t_a) x_b + cos(t_a) y_b, t_a + t_b)``
        with the angle wrapped.
    """
    a = _as_pose(a, "a")
    b = _as_pose(b, "b")
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    t = wrap_angle(a[..., 2] + b[..., 2])
    return np.stack(np.broadcast_arrays(x, y, t), axis=-1)


def inverse(a: ArrayLike) -> FloatArray:
    """Pose inverse ``⊖a`` such that ``a ⊕ ⊖a`` is the identity.

    Parameters
    ----------
    a : array_like, shape (..., 3)

    Returns
    -------
    ndarray, shape (..., 3)
    """
    a = _as_pose(a, "a")
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return np.stack([x, y, wrap_angle(-a[..., 2])], axis=-1)


def between(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Relative pose ``⊖a ⊕ b``: the pose ``b`` expressed in the frame of ``a``.

    Parameters
    ----------
    a, b : array_like, shape (..., 3)

    Returns
    -------
    ndarray, shape (..., 3)
    """
    a = _as_pose(a, "a")
    b = _as_pose(b, "b")
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx = b[..., 0] - a[..., 0]
    dy = b[..., 1] - a[..., 1]
    x = c * dx + s * dy
    y = -s * dx + c * dy
    t = wrap_angle(b[..., 2] - a[..., 2])
    return np.stack(np.broadcast_arrays(x, y, t), axis=-1)


def transform_point(a: ArrayLike, p: ArrayLike) -> FloatArray:
    """Map points ``p`` (..., 2) given in frame ``a`` to ``a``'s parent frame."""
    a = _as_pose(a, "a")
    p = np.asarray(p, dtype=np.float64)
    if p.ndim == 0 or p.shape[-1] != 2:
        raise ValueError(f"p must have shape (..., 2), got {p.shape}")
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * p[..., 0] - s * p[..., 1]
    y = a[..., 1] + s * p[..., 0] + c * p[..., 1]
    return np.stack(np.broadcast_arrays(x, y), axis=-1)


def compose_jacobians(a: ArrayLike, b: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Jacobians of :func:`compose` with respect to ``a`` and ``b``.

    Returns
    -------
    J_a, J_b : ndarray, shape (..., 3, 3)
        ``d(a ⊕ b)/da`` and ``d(a ⊕ b)/db``.
    """
    a = _as_pose(a, "a")
    b = _as_pose(b, "b")
    shape = np.broadcast_shapes(a.shape, b.shape)[:-1]
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    J_a = np.zeros((*shape, 3, 3))
    J_a[..., 0, 0] = 1.0
    J_a[..., 1, 1] = 1.0
    J_a[..., 2, 2] = 1.0
    J_a[..., 0, 2] = -s * b[..., 0] - c * b[..., 1]
    J_a[..., 1, 2] = c * b[..., 0] - s * b[..., 1]
    J_b = np.zeros((*shape, 3, 3))
    J_b[..., 0, 0] = c
    J_b[..., 0, 1] = -s
    J_b[..., 1, 0] = s
    J_b[..., 1, 1] = c
    J_b[..., 2, 2] = 1.0
    return J_a, J_b


def inverse_jacobian(a: ArrayLike) -> FloatArray:
    """Jacobian of :func:`inverse`, shape (..., 3, 3)."""
    a = _as_pose(a, "a")
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    J = np.zeros((*a.shape[:-1], 3, 3))
    J[..., 0, 0] = -c
    J[..., 0, 1] = -s
    J[..., 0, 2] = s * a[..., 0] - c * a[..., 1]
    J[..., 1, 0] = s
    J[..., 1, 1] = -c
    J[..., 1, 2] = c * a[..., 0] + s * a[..., 1]
    J[..., 2, 2] = -1.0
    return J


def between_jacobians(a: ArrayLike, b: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Jacobians of :func:`between` with respect to ``a`` and ``b``, each (..., 3, 3)."""
    a = _as_pose(a, "a")
    b = _as_pose(b, "b")
    shape = np.broadcast_shapes(a.shape, b.shape)[:-1]
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx = b[..., 0] - a[..., 0]
    dy = b[..., 1] - a[..., 1]
    J_a = np.zeros((*shape, 3, 3))
    J_a[..., 0, 0] = -c
    J_a[..., 0, 1] = -s
    J_a[..., 0, 2] = -s * dx + c * dy
    J_a[..., 1, 0] = s
    J_a[..., 1, 1] = -c
    J_a[..., 1, 2] = -c * dx - s * dy
    J_a[..., 2, 2] = -1.0
    J_b = np.zeros((*shape, 3, 3))
    J_b[..., 0, 0] = c
    J_b[..., 0, 1] = s
    J_b[..., 1, 0] = -s
    J_b[..., 1, 1] = c
    J_b[..., 2, 2] = 1.0
    return J_a, J_b
