"""Ray casting on binary grids: the expected range of each beam (for simulation and beam models)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.grid.spec import GridSpec


def cast_rays(
    occupied: ArrayLike, spec: GridSpec, poses: ArrayLike, angles: ArrayLike, max_range: float
) -> NDArray[np.float64]:
    """Range to the first occupied cell along each beam, by exact grid traversal.

    Parameters
    ----------
    occupied : array_like of bool, shape (H, W)
        Occupied cells, indexed ``[iy, ix]`` as in :class:`GridSpec`.
    spec : GridSpec
        Geometry of ``occupied``.
    poses : array_like, shape (P, 3) or (3,)
        Sensor poses ``(x, y, theta)`` in the world frame.
    angles : array_like, shape (B,)
        Beam angles in the sensor frame, radians.
    max_range : float
        Range returned when no occupied cell is met (also when the beam leaves the grid).

    Returns
    -------
    ndarray, shape (P, B) or (B,)
        Distance in metres to the boundary of the first occupied cell.

    Examples
    --------
    >>> import numpy as np
    >>> occ = np.zeros((10, 10), bool); occ[:, 7] = True
    >>> cast_rays(occ, GridSpec(1.0, (0.0, 0.0), (10, 10)), [0.5, 5.5, 0.0], [0.0], 20.0)
    array([6.5])
    """
    from probmap.grid import _kernels

    occ = np.ascontiguousarray(occupied, dtype=np.bool_)
    if occ.shape != spec.shape:
        raise ValueError(f"occupied shape {occ.shape} does not match spec.shape {spec.shape}")
    P = np.ascontiguousarray(poses, dtype=np.float64)
    single = P.ndim == 1
    P = np.atleast_2d(P)
    if P.shape[-1] != 3:
        raise ValueError(f"poses must have shape (P, 3), got {np.shape(poses)}")
    A = np.ascontiguousarray(angles, dtype=np.float64).ravel()
    if not (np.isfinite(P).all() and np.isfinite(A).all()):
        raise ValueError("poses and angles must be finite")
    if not max_range > 0:
        raise ValueError(f"max_range must be > 0, got {max_range}")
    out = np.empty((P.shape[0], A.shape[0]))
    ox, oy = spec.origin
    _kernels.cast_rays(occ, ox, oy, spec.resolution, P, A, float(max_range), out)
    return out[0] if single else out
