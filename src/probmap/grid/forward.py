"""Forward sensor models ``p(z | x, m)`` of a range finder on a grid map (chapter 6).

- :class:`LikelihoodField`: the likelihood field model (Probabilistic Robotics Table 6.3).
  The distance from every cell to the nearest occupied cell is computed once per map with
  :func:`scipy.ndimage.distance_transform_edt` and stored as float32; the per-beam
  log-likelihood ``log(z_hit * N(d; 0, sigma_hit^2) + z_rand / z_max)`` is tabulated from it,
  so weighting a particle costs one rotation and one table lookup per beam.
- :class:`BeamModel`: the beam model (Table 6.1) with the expected range found by ray
  casting, by one of three methods (``ray_casting``):

  * ``"sphere"`` (default): sphere tracing on the same Euclidean distance transform (the ray
    advances by the clearance to the nearest occupied cell minus one cell diagonal, at least
    half a cell, and stops in the first occupied cell); overshoots a face by under half a cell.
  * ``"exact"``: exact grid traversal (Amanatides-Woo) on the boolean map, the range to where
    the ray enters the first occupied cell.
  * ``"table"``: a ray-casting lookup table, expected range per cell x heading bin (``K``
    bins over 360 degrees, uint16, ``H * W * K * 2`` bytes of address space), each entry cast
    exactly from the cell centre at the bin's heading when first needed (memory pages are only
    touched for the cells particles visit). A query snaps the sensor to its cell centre (at most
    ``res / sqrt(2)`` away) and its beam heading to the nearest bin (at most ``pi / K`` off), so
    the range error grows with range and incidence: see ``tests/grid/test_forward.py`` for the
    measured error against exact casting.

Both work on a plain ``(spec, occupancy)`` pair, where ``spec`` is anything with
``resolution`` (m), ``origin`` (x0, y0 of the lower-left corner of cell ``[0, 0]``, m) and
``shape`` (H, W) -- :class:`probmap.grid.spec.GridSpec` fits -- and ``occupancy`` is either a
boolean ``(H, W)`` array (True = occupied) or an occupancy probability array with NaN for
unknown. Both return per-beam log-likelihoods vectorised over poses ``(N, 3)`` and beams
``(B,)``; max-range readings contribute 0 in the likelihood field (Table 6.3, line 4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.grid import _forward_kernels as _k

__all__ = ["BeamModel", "GridGeometry", "LikelihoodField", "occupied_mask"]

_RAY_CASTING = ("sphere", "exact", "table")


class GridGeometry(Protocol):
    """What the forward models need of a grid spec."""

    @property
    def resolution(self) -> float: ...

    @property
    def origin(self) -> Any: ...

    @property
    def shape(self) -> Any: ...


@dataclass(frozen=True)
class _Frame:
    resolution: float
    x0: float
    y0: float
    shape: tuple[int, int]


def _frame(spec: GridGeometry) -> _Frame:
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
    return _Frame(res, x0, y0, (h, w))


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


def _distance_field(occupied: NDArray[np.bool_], resolution: float) -> NDArray[np.float32]:
    """Distance (m) from each cell centre to the nearest occupied cell centre, float32."""
    from scipy.ndimage import distance_transform_edt

    if not occupied.any():
        # No obstacle at all: every cell is "infinitely" far; a large finite value keeps
        # the arithmetic in the kernels finite.
        return np.full(occupied.shape, np.float32(1e9), dtype=np.float32)
    d = distance_transform_edt(~occupied) * resolution
    return np.ascontiguousarray(d, dtype=np.float32)


def _poses_array(poses: ArrayLike) -> NDArray[np.float64]:
    p = np.ascontiguousarray(poses, dtype=np.float64)
    if p.ndim == 1:
        p = p.reshape(1, -1)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"poses must have shape (N, 3), got {np.shape(poses)}")
    if not np.all(np.isfinite(p)):
        raise ValueError("poses must be finite")
    return p


def _scan_arrays(
    ranges: ArrayLike, angles: ArrayLike, offset: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
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


class LikelihoodField:
    """Likelihood field range-finder model, Probabilistic Robotics Table 6.3.

    Parameters
    ----------
    spec : GridGeometry
        Grid geometry (resolution m, origin m, shape (H, W)).
    occupancy : (H, W) array_like
        Boolean or probability map (NaN unknown), indexed ``[iy, ix]``.
    max_range : float
        Sensor maximum range ``z_max`` (m); readings at or beyond it are skipped.
    sigma_hit : float
        Standard deviation (m) of the distance-to-obstacle Gaussian.
    z_hit, z_rand : float
        Mixture weights of the hit and random components.
    max_distance : float
        Distances are clipped here (m); endpoints outside the map count as this far.
    occupied_threshold : float
        Probability above which a cell is an obstacle.
    """

    def __init__(
        self,
        spec: GridGeometry,
        occupancy: ArrayLike,
        *,
        max_range: float,
        sigma_hit: float = 0.1,
        z_hit: float = 0.9,
        z_rand: float = 0.1,
        max_distance: float = 2.0,
        occupied_threshold: float = 0.65,
    ) -> None:
        frame = _frame(spec)
        occupied = occupied_mask(occupancy, occupied_threshold)
        if occupied.shape != frame.shape:
            raise ValueError(
                f"occupancy shape {occupied.shape} does not match spec shape {frame.shape}"
            )
        for name, val in (("max_range", max_range), ("sigma_hit", sigma_hit)):
            if not (val > 0 and math.isfinite(val)):
                raise ValueError(f"{name} must be positive, got {val}")
        if z_hit < 0 or z_rand < 0 or z_hit + z_rand <= 0:
            raise ValueError(f"z_hit, z_rand must be non-negative, not both 0: {z_hit}, {z_rand}")
        if not max_distance > 0:
            raise ValueError(f"max_distance must be positive, got {max_distance}")
        self.spec = spec
        self.frame = frame
        self.occupied = occupied
        self.max_range = float(max_range)
        self.sigma_hit = float(sigma_hit)
        self.z_hit = float(z_hit)
        self.z_rand = float(z_rand)
        self.max_distance = float(max_distance)
        self.distance = np.minimum(
            _distance_field(occupied, frame.resolution), np.float32(max_distance)
        )
        self.table = np.ascontiguousarray(
            self.log_likelihood_of_distance(self.distance), dtype=np.float32
        )
        self.outside = float(self.log_likelihood_of_distance(np.array(self.max_distance)))

    def log_likelihood_of_distance(self, d: ArrayLike) -> NDArray[np.float64]:
        """``log(z_hit * prob(d, sigma_hit^2) + z_rand / z_max)`` for distances ``d`` (m)."""
        dd = np.asarray(d, dtype=np.float64)
        s = self.sigma_hit
        hit = np.exp(-0.5 * (dd / s) ** 2) / (math.sqrt(2 * math.pi) * s)
        return np.asarray(np.log(self.z_hit * hit + self.z_rand / self.max_range))

    def endpoints(
        self, ranges: ArrayLike, angles: ArrayLike, sensor_offset: ArrayLike = (0.0, 0.0, 0.0)
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """Beam endpoints in the robot frame, computed once per scan.

        Returns ``(lx, ly, valid)``, each ``(B,)``; ``valid`` is False for max-range readings.
        """
        r, a, o = _scan_arrays(ranges, angles, sensor_offset)
        b = r.shape[0]
        lx = np.empty(b)
        ly = np.empty(b)
        valid = np.empty(b, dtype=np.bool_)
        _k.endpoints_in_robot_frame(r, a, o, self.max_range, lx, ly, valid)
        return lx, ly, valid

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
            Robot poses (x, y, theta) in the map frame (m, rad).
        ranges, angles : (B,) array_like
            Readings (m) and beam angles (rad) in the sensor frame.
        sensor_offset : (3,) array_like
            Sensor pose in the robot frame.

        Returns
        -------
        (N, B) float64 ndarray
            0 for max-range readings.
        """
        p = _poses_array(poses)
        lx, ly, valid = self.endpoints(ranges, angles, sensor_offset)
        out = np.empty((p.shape[0], lx.shape[0]))
        f = self.frame
        _k.likelihood_field_per_beam(
            p, lx, ly, valid, self.table, f.x0, f.y0, 1.0 / f.resolution, self.outside, out
        )
        return out

    def log_likelihood_sum(
        self,
        poses: ArrayLike,
        ranges: ArrayLike,
        angles: ArrayLike,
        sensor_offset: ArrayLike = (0.0, 0.0, 0.0),
    ) -> NDArray[np.float64]:
        """Scan log-likelihood ``sum_b log p(z_b | x_n, m)``, shape ``(N,)``."""
        p = _poses_array(poses)
        lx, ly, valid = self.endpoints(ranges, angles, sensor_offset)
        return self.log_likelihood_sum_prepared(p, lx, ly, valid)

    def log_likelihood_sum_prepared(
        self,
        poses: NDArray[np.float64],
        lx: NDArray[np.float64],
        ly: NDArray[np.float64],
        valid: NDArray[np.bool_],
    ) -> NDArray[np.float64]:
        """As :meth:`log_likelihood_sum` with endpoints from :meth:`endpoints` (no checks)."""
        out = np.empty(poses.shape[0])
        f = self.frame
        _k.likelihood_field_sum(
            poses, lx, ly, valid, self.table, f.x0, f.y0, 1.0 / f.resolution, self.outside, out
        )
        return out


class BeamModel:
    """Beam model of range finders, Probabilistic Robotics Table 6.1, with ray casting.

    Parameters
    ----------
    spec : GridGeometry
        Grid geometry.
    occupancy : (H, W) array_like
        Boolean or probability map (NaN unknown, treated as free for ray casting).
    max_range : float
        ``z_max`` (m).
    z_hit, z_short, z_max, z_rand : float
        Mixture weights (equation 6.12).
    sigma_hit : float
        Standard deviation (m) of the hit component.
    lambda_short : float
        Rate (1/m) of the exponential short-reading component.
    occupied_threshold : float
        Probability above which a cell is an obstacle.
    ray_casting : {"sphere", "exact", "table"}
        How expected ranges are found (see the module docstring): sphere tracing on the
        distance transform, exact grid traversal, or the lookup table of exact casts.
    heading_bins : int
        Heading bins ``K`` of the lookup table (``"table"`` only); the bin width is
        ``2 pi / K``.
    """

    def __init__(
        self,
        spec: GridGeometry,
        occupancy: ArrayLike,
        *,
        max_range: float,
        z_hit: float = 0.8,
        z_short: float = 0.1,
        z_max: float = 0.05,
        z_rand: float = 0.05,
        sigma_hit: float = 0.2,
        lambda_short: float = 0.1,
        occupied_threshold: float = 0.65,
        ray_casting: str = "sphere",
        heading_bins: int = 360,
    ) -> None:
        frame = _frame(spec)
        occupied = occupied_mask(occupancy, occupied_threshold)
        if occupied.shape != frame.shape:
            raise ValueError(
                f"occupancy shape {occupied.shape} does not match spec shape {frame.shape}"
            )
        if ray_casting not in _RAY_CASTING:
            raise ValueError(f"ray_casting must be one of {_RAY_CASTING}, got {ray_casting!r}")
        if not (isinstance(heading_bins, int) and 4 <= heading_bins <= 65536):
            raise ValueError(f"heading_bins must be an integer in [4, 65536], got {heading_bins!r}")
        weights = (z_hit, z_short, z_max, z_rand)
        if any(w < 0 for w in weights) or sum(weights) <= 0:
            raise ValueError(f"mixture weights must be non-negative, not all 0: {weights}")
        for name, val in (
            ("max_range", max_range),
            ("sigma_hit", sigma_hit),
            ("lambda_short", lambda_short),
        ):
            if not (val > 0 and math.isfinite(val)):
                raise ValueError(f"{name} must be positive, got {val}")
        self.spec = spec
        self.frame = frame
        self.occupied = occupied
        self.max_range = float(max_range)
        self.distance = _distance_field(occupied, frame.resolution)
        self.params = np.array(
            [z_hit, z_short, z_max, z_rand, sigma_hit, lambda_short], dtype=np.float64
        )
        self.ray_casting = ray_casting
        self.heading_bins = heading_bins
        # table entries store 1 + round(range / quantum) in uint16 (0 = not cast yet)
        self.range_quantum = self.max_range / 65534.0
        self._table: NDArray[np.uint16] | None = None
        self._normalisers: NDArray[np.float64] | None = None

    @property
    def range_table(self) -> NDArray[np.uint16]:
        """The ``(H, W, K)`` lookup table of ``ray_casting="table"`` (0 = not cast yet).

        Allocated zeroed on first use; the operating system maps its pages only when written,
        so memory grows with the cells visited, up to ``H * W * K * 2`` bytes.
        """
        if self._table is None:
            h, w = self.frame.shape
            self._table = np.zeros((h, w, self.heading_bins), dtype=np.uint16)
        return self._table

    def expected_ranges(
        self, poses: ArrayLike, angles: ArrayLike, sensor_offset: ArrayLike = (0.0, 0.0, 0.0)
    ) -> NDArray[np.float64]:
        """Ray-cast ranges ``z*`` (m) for every pose and beam, shape ``(N, B)``.

        Parameters
        ----------
        poses : (N, 3) array_like
            Robot poses (x, y, theta) in the map frame (m, rad).
        angles : (B,) array_like
            Beam angles (rad) in the sensor frame.
        sensor_offset : (3,) array_like
            Sensor pose in the robot frame.
        """
        p = _poses_array(poses)
        a = np.ascontiguousarray(angles, dtype=np.float64)
        _, a, o = _scan_arrays(np.zeros_like(a), a, sensor_offset)
        return self._expected_ranges(p, a, o)

    def _expected_ranges(
        self, p: NDArray[np.float64], a: NDArray[np.float64], o: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        out = np.empty((p.shape[0], a.shape[0]))
        f = self.frame
        if self.ray_casting == "sphere":
            _k.cast_rays(p, a, o, self.distance, f.x0, f.y0, f.resolution, self.max_range, out)
        elif self.ray_casting == "exact":
            _k.exact_ranges(p, a, o, self.occupied, f.x0, f.y0, f.resolution, self.max_range, out)
        else:
            _k.table_ranges(
                p,
                a,
                o,
                self.occupied,
                self.range_table,
                f.x0,
                f.y0,
                f.resolution,
                self.max_range,
                self.range_quantum,
                out,
            )
        return out

    def log_likelihood(
        self,
        poses: ArrayLike,
        ranges: ArrayLike,
        angles: ArrayLike,
        sensor_offset: ArrayLike = (0.0, 0.0, 0.0),
    ) -> NDArray[np.float64]:
        """Per-beam log-likelihoods ``log p(z_b | x_n, m)``, shape ``(N, B)``.

        Readings beyond ``max_range`` are clipped to it (the max-range component).
        """
        p = _poses_array(poses)
        r, a, o = _scan_arrays(ranges, angles, sensor_offset)
        if self.ray_casting == "table":
            scales = self._table_normalisers()
            out = np.empty((p.shape[0], r.shape[0]))
            f = self.frame
            _k.table_beam_model(
                p,
                r,
                a,
                o,
                self.occupied,
                self.range_table,
                scales,
                f.x0,
                f.y0,
                f.resolution,
                self.max_range,
                self.range_quantum,
                self.params,
                out,
            )
            return out
        zs = self._expected_ranges(p, a, o)
        out = np.empty_like(zs)
        _k.beam_mixture(zs, r, self.max_range, self.params, out)
        return out

    def _table_normalisers(self) -> NDArray[np.float64]:
        """Factors of Table 6.1 that depend on the expected range alone, per table value."""
        if self._normalisers is None:
            scales = np.empty((65536, 2))
            _k.table_normalisers(self.range_quantum, self.max_range, self.params, scales)
            self._normalisers = scales
        return self._normalisers

    def log_likelihood_sum(
        self,
        poses: ArrayLike,
        ranges: ArrayLike,
        angles: ArrayLike,
        sensor_offset: ArrayLike = (0.0, 0.0, 0.0),
    ) -> NDArray[np.float64]:
        """Scan log-likelihood, shape ``(N,)``."""
        return np.asarray(self.log_likelihood(poses, ranges, angles, sensor_offset).sum(axis=1))
