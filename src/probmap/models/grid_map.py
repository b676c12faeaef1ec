"""The map a range-finder model works on: a grid geometry and an occupancy array.

The forward sensor models (:class:`probmap.models.beam.BeamModel`,
:class:`probmap.models.likelihood_field.LikelihoodField`) take a plain ``(spec, occupancy)``
pair, where ``spec`` is anything with ``resolution`` (m), ``origin`` (x0, y0 of the lower-left
corner of cell ``[0, 0]``, m) and ``shape`` (H, W) -- :class:`probmap.grid.spec.GridSpec` fits,
see :class:`GridGeometry` -- and ``occupancy`` is either a boolean ``(H, W)`` array (True =
occupied) or an occupancy probability array with NaN for unknown (:func:`occupied_mask`). This
module holds what they share: the geometry check, the occupied mask, the Euclidean distance
transform, the checks of poses and scans, and their common interface (:class:`ScanLikelihood`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._typing import FloatArray
from probmap.geometry.se2 import pose_batch

__all__ = ["GridGeometry", "ScanLikelihood", "occupied_mask"]


class GridGeometry(Protocol):
    """What the forward models need of a grid spec."""

    @property
    def resolution(self) -> float: ...

    @property
    def origin(self) -> Any: ...

    @property
    def shape(self) -> Any: ...


@dataclass(frozen=True)
class Frame:
    """A checked grid geometry: resolution (m), lower-left corner (m) and shape (H, W)."""

    resolution: float
    x0: float
    y0: float
    shape: tuple[int, int]


def frame_of(spec: GridGeometry) -> Frame:
    """``spec`` checked and copied into a :class:`Frame` (ValueError naming the spec)."""
    try:
        res = float(spec.resolution)
        x0, y0 = (float(v) for v in spec.origin)
        h, w = (int(v) for v in spec.shape)
    except (AttributeError, TypeError, ValueError) as exc:
        raise ValueError(
            f"spec must have resolution, origin=(x0, y0) and shape=(H, W); got {spec!r}"
        ) from exc
    if not (res > 0 and math.isfinite(res)) or not (math.isfinite(x0) and math.isfinite(y0)):
        raise ValueError(f"spec resolution must be positive and origin finite, got {spec!r}")
    if h <= 0 or w <= 0:
        raise ValueError(f"spec shape must be positive, got {(h, w)}")
    return Frame(res, x0, y0, (h, w))


def occupied_mask(occupancy: ArrayLike, threshold: float = 0.65) -> NDArray[np.bool_]:
    """Occupied cells of a map.

    Parameters
    ----------
    occupancy : (H, W) array_like
        Boolean (True = occupied) or occupancy probability in [0, 1] with NaN for unknown.
    threshold : float
        A probability above this is occupied; unknown (NaN) cells are not.

    Returns
    -------
    (H, W) bool ndarray, C-contiguous.
    """
    occ = np.asarray(occupancy)
    if occ.ndim != 2:
        raise ValueError(f"occupancy must be a 2-D (H, W) array, got shape {occ.shape}")
    if occ.dtype == np.bool_:
        return np.ascontiguousarray(occ)
    p = occ.astype(np.float64)
    finite = p[np.isfinite(p)]
    if finite.size and (finite.min() < 0 or finite.max() > 1):
        raise ValueError("occupancy probabilities must lie in [0, 1] (NaN for unknown)")
    with np.errstate(invalid="ignore"):
        return np.ascontiguousarray(np.nan_to_num(p, nan=0.0) > threshold)


def checked_map(
    spec: GridGeometry, occupancy: ArrayLike, threshold: float
) -> tuple[Frame, NDArray[np.bool_]]:
    """The checked geometry of ``spec`` and the occupied mask of ``occupancy`` (see
    :func:`occupied_mask`), which must have the spec's shape."""
    frame = frame_of(spec)
    occupied = occupied_mask(occupancy, threshold)
    if occupied.shape != frame.shape:
        raise ValueError(
            f"occupancy shape {occupied.shape} does not match spec shape {frame.shape}"
        )
    return frame, occupied


def distance_field(occupied: NDArray[np.bool_], resolution: float) -> NDArray[np.float32]:
    """Distance (m) from each cell centre to the nearest occupied cell centre, float32."""
    from scipy.ndimage import distance_transform_edt

    if not occupied.any():
        # No obstacle at all: every cell is "infinitely" far; a large finite value keeps
        # the arithmetic in the kernels finite.
        return np.full(occupied.shape, np.float32(1e9), dtype=np.float32)
    d = distance_transform_edt(~occupied) * resolution
    return np.ascontiguousarray(d, dtype=np.float32)


def poses_array(poses: ArrayLike) -> NDArray[np.float64]:
    """Finite poses as a contiguous float64 ``(N, 3)`` array (one pose ``(3,)`` -> ``(1, 3)``;
    :func:`probmap.geometry.se2.pose_batch`)."""
    return pose_batch(poses, single=True)


def scan_arrays(
    ranges: ArrayLike, angles: ArrayLike, offset: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A scan checked: ranges and angles ``(B,)`` (ranges >= 0, NaN allowed; angles finite) and
    the sensor pose in the robot frame ``(3,)``, as contiguous float64 arrays."""
    r = np.ascontiguousarray(ranges, dtype=np.float64)
    a = np.ascontiguousarray(angles, dtype=np.float64)
    o = np.ascontiguousarray(offset, dtype=np.float64)
    if r.ndim != 1 or a.shape != r.shape:
        raise ValueError(
            f"ranges and angles must be 1-D arrays of equal length, got {r.shape} and {a.shape}"
        )
    if not np.all(np.isfinite(a)):
        raise ValueError("beam angles must be finite")
    if np.any(r < 0):
        raise ValueError("ranges must be non-negative")
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        raise ValueError(f"sensor_offset must be a finite (x, y, theta), got {o!r}")
    return r, a, o


class ScanLikelihood:
    """The scan likelihoods both range-finder models give, with their input checks, once.

    A model (:class:`~probmap.models.beam.BeamModel`,
    :class:`~probmap.models.likelihood_field.LikelihoodField`) supplies ``_log_likelihood`` on
    checked arrays (poses ``(N, 3)``, ranges and angles ``(B,)``, sensor offset ``(3,)``, all
    contiguous float64), and may supply a faster ``_log_likelihood_sum``.
    """

    # log_likelihood_sum takes the same inputs: one interface, per beam or summed.
    def log_likelihood(
        self,
        poses: ArrayLike,
        ranges: ArrayLike,
        angles: ArrayLike,
        sensor_offset: ArrayLike = (0.0, 0.0, 0.0),
    ) -> NDArray[np.float64]:
        """Per-beam log-likelihoods ``log p(z_b | x_n, m)``.

        Parameters
        ----------
        poses : (N, 3) array_like
            Robot poses (x, y, theta) in the map frame (m, rad); one pose ``(3,)`` is one row.
        ranges, angles : (B,) array_like
            Readings (m, >= 0, NaN allowed) and beam angles (rad) in the sensor frame.
        sensor_offset : (3,) array_like
            Sensor pose in the robot frame.

        Returns
        -------
        (N, B) float64 ndarray
            A max-range reading counts as the model says: the beam model clips readings beyond
            ``max_range`` to it (its max-range component), the likelihood field gives them 0.
        """
        p = poses_array(poses)
        r, a, o = scan_arrays(ranges, angles, sensor_offset)
        return self._log_likelihood(p, r, a, o)

    # the same inputs as log_likelihood: the per-beam terms and their sum are one interface
    def log_likelihood_sum(
        self,
        poses: ArrayLike,
        ranges: ArrayLike,
        angles: ArrayLike,
        sensor_offset: ArrayLike = (0.0, 0.0, 0.0),
    ) -> NDArray[np.float64]:
        """Scan log-likelihood ``sum_b log p(z_b | x_n, m)``, shape ``(N,)`` (arguments as
        :meth:`log_likelihood`)."""
        p = poses_array(poses)
        r, a, o = scan_arrays(ranges, angles, sensor_offset)
        return self._log_likelihood_sum(p, r, a, o)

    def _log_likelihood(
        self, p: FloatArray, r: FloatArray, a: FloatArray, o: FloatArray
    ) -> FloatArray:
        raise NotImplementedError  # pragma: no cover - every model defines it

    def _log_likelihood_sum(
        self, p: FloatArray, r: FloatArray, a: FloatArray, o: FloatArray
    ) -> FloatArray:
        return np.asarray(self._log_likelihood(p, r, a, o).sum(axis=1))
