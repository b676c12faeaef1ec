"""Occupancy grid mapping with known poses: the static binary Bayes filter in log-odds form.

Probabilistic Robotics, Table 4.2 (binary Bayes filter) and Table 9.1 (occupancy grid mapping):
for every cell ``m_i`` in the perceptual field of measurement ``z_t``

    l_t,i = l_{t-1},i + inverse_sensor_model(m_i, x_t, z_t) - l_0

with ``l_0 = logit(p0)`` the prior, and ``p(m_i | z_1:t, x_1:t) = 1 - 1 / (1 + exp(l_t,i))``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._sums import field_sums
from probmap._typing import FloatArray
from probmap.errors import GridBoundsError  # noqa: F401  (re-exported: its old home)
from probmap.grid._storage import (
    _EPOCH,
    MAX_EXTENT_M,
    _ScanGrid,
    filled,
    grid_resolution,
    observed_mask,
    observed_window,
    plan_growth,
    regrid,
    reset_stamps,
)
from probmap.grid.logodds import logit, prob
from probmap.grid.spec import GridSpec


def check_beam_model_fields(model: Any, owner: str) -> None:
    """The checks of the fields every inverse sensor model of a range beam has.

    :class:`InverseSensorModel` and :class:`~probmap.grid.semantic.LabelledInverseModel` share
    ``p_hit``, ``p_miss``, ``thickness`` and ``max_clear_range`` with one meaning, so one set
    of rules.

    Parameters
    ----------
    model : InverseSensorModel or LabelledInverseModel
        The model being built (its ``__post_init__`` calls this).
    owner : str
        The class name the messages start with.

    Raises
    ------
    ValueError
        ``p_hit`` or ``p_miss`` not in (0, 1); ``thickness`` negative, infinite or NaN;
        ``max_clear_range`` neither None nor >= 0 m.
    """
    for name in ("p_hit", "p_miss"):
        v = getattr(model, name)
        if not 0.0 < v < 1.0:
            raise ValueError(f"{owner}.{name} must lie in (0, 1), got {v}")
    if not (model.thickness >= 0.0 and math.isfinite(model.thickness)):
        raise ValueError(f"{owner}.thickness must be >= 0 m, got {model.thickness}")
    if model.max_clear_range is not None and not model.max_clear_range >= 0.0:
        raise ValueError(
            f"{owner}.max_clear_range must be >= 0 m or None, got {model.max_clear_range}"
        )


@dataclass(frozen=True)
class InverseSensorModel:
    """Inverse range-sensor model for laser beams (Probabilistic Robotics, Table 9.2, simplified).

    Parameters
    ----------
    p_hit : float
        ``p(m_i = occupied | z)`` for the cell(s) at a beam's endpoint. Default 0.7.
    p_miss : float
        ``p(m_i = occupied | z)`` for cells the beam crosses before its endpoint. Default 0.4.
    thickness : float
        Depth in metres behind the endpoint that is also marked occupied (the book's alpha);
        0 marks the endpoint cell only.
    max_clear_range : float or None
        A reading at or beyond the sensor's maximum range has no endpoint; it marks free the cells
        up to this distance in metres (never beyond the maximum range). ``None`` clears up to the
        maximum range itself; 0 ignores such readings.
    """

    p_hit: float = 0.7
    p_miss: float = 0.4
    thickness: float = 0.0
    max_clear_range: float | None = None

    def __post_init__(self) -> None:
        check_beam_model_fields(self, "InverseSensorModel")

    @property
    def l_hit(self) -> float:
        """Log odds of an endpoint cell, ``logit(p_hit)``."""
        return float(logit(self.p_hit))

    @property
    def l_miss(self) -> float:
        """Log odds of a traversed cell, ``logit(p_miss)``."""
        return float(logit(self.p_miss))


def effective_clear_range(max_clear_range: float | None, max_range: float) -> float:
    """Distance in metres that a no-return (max-range) reading clears.

    ``None`` means up to the maximum range; a finite setting never reaches past it, since a reading
    that did not return says nothing beyond the sensor's range. An infinite maximum range with no
    setting clears nothing.
    """
    if max_clear_range is None:
        return max_range if math.isfinite(max_range) else 0.0
    return min(max_clear_range, max_range)


@dataclass(frozen=True)
class ScanStats:
    """What one call to :meth:`OccupancyGrid.integrate_scans` did."""

    scans: int
    beams: int
    hits: int
    max_range: int
    dropped: int
    cell_updates: int

    @classmethod
    def from_counts(cls, scans: int, beams: int, counts: NDArray[np.int64]) -> ScanStats:
        """The stats of ``scans`` scans of ``beams`` beams in all from a kernel's ``counts``
        (int64[4]: hits, max-range readings, dropped readings, cell updates)."""
        return cls(
            scans=int(scans),
            beams=int(beams),
            hits=int(counts[0]),
            max_range=int(counts[1]),
            dropped=int(counts[2]),
            cell_updates=int(counts[3]),
        )

    def __add__(self, other: ScanStats) -> ScanStats:
        return field_sums(self, other)


_one_scan_kernel: Any = None  # _kernels.integrate_one_scan, imported on first use (numba is heavy)


def check_one_scan(pose: ArrayLike, ranges: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """``pose`` as float64 (3,) and ``ranges`` as float64 (B,), or :class:`ValueError`."""
    p = np.asarray(pose, dtype=np.float64)
    if p.shape != (3,):
        raise ValueError(f"pose must have shape (3,) = (x, y, theta), got {p.shape}")
    r = np.asarray(ranges, dtype=np.float64)
    if r.ndim != 1:
        raise ValueError(f"ranges must be 1-D, got shape {r.shape}")
    return p, r


def check_finite_poses(P: FloatArray) -> None:
    """Raise :class:`ValueError` naming the first pose (row of ``P`` (S, 3)) that is not
    finite."""
    if not np.isfinite(P).all():
        bad = int(np.nonzero(~np.isfinite(P).all(axis=1))[0][0])
        raise ValueError(f"poses must be finite numbers; pose {bad} is {P[bad].tolist()}")


def check_poses(poses: ArrayLike) -> FloatArray:
    """Sensor poses as contiguous float64 (S, 3), all finite, or :class:`ValueError` naming the
    first bad pose."""
    P = np.ascontiguousarray(poses, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"poses must have shape (S, 3) = (x, y, theta), got {P.shape}")
    check_finite_poses(P)
    return P


def check_poses_and_ranges(poses: ArrayLike, ranges: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """:func:`check_poses` and the ranges as contiguous float64 (S, B), one row per pose."""
    P = check_poses(poses)
    R = np.ascontiguousarray(ranges, dtype=np.float64)
    if R.ndim != 2 or R.shape[0] != P.shape[0]:
        raise ValueError(
            f"ranges must have shape (S, B) with S = {P.shape[0]} poses, got {R.shape}"
        )
    return P, R


def check_angles_and_max_range(
    angles: ArrayLike, ranges: FloatArray, max_range: float
) -> tuple[FloatArray, bool, float]:
    """Beam angles for ``ranges (S, B)`` and the maximum range, checked.

    Returns ``(A, shared, max_range)``: ``A`` contiguous float64 (1, B) when ``angles`` (B,)
    is shared by all scans (``shared`` true), else (S, B); ``max_range`` as a float > 0.
    """
    A = np.asarray(angles, dtype=np.float64)
    shared = A.ndim == 1
    if shared:
        A = A[None, :]
    S, B = ranges.shape
    if A.ndim != 2 or A.shape[-1] != B or (not shared and A.shape[0] != S):
        raise ValueError(f"angles shape {np.shape(angles)} does not match ranges {ranges.shape}")
    if not np.isfinite(A).all():
        raise ValueError("angles must be finite")
    max_range = float(max_range)
    if not max_range > 0.0:
        raise ValueError(f"max_range must be > 0 m, got {max_range}")
    return np.ascontiguousarray(A), shared, max_range


def _load_one_scan_kernel() -> Any:
    """:func:`probmap.grid._kernels.integrate_one_scan`, imported the first time it is needed."""
    global _one_scan_kernel
    from probmap.grid._kernels import integrate_one_scan

    _one_scan_kernel = integrate_one_scan
    return integrate_one_scan


class OccupancyGrid(_ScanGrid):
    """A 2-D occupancy grid holding float32 log odds, updated by the binary Bayes filter.

    Parameters
    ----------
    resolution : float
        Cell side in metres. Default 0.05.
    p0 : float
        Prior probability of occupancy; ``l0 = logit(p0)``. Default 0.5.
    clamp : tuple of float
        ``(p_min, p_max)``: log odds are clamped to ``[logit(p_min), logit(p_max)]`` after every
        update so the map can still change (defaults 0.12 and 0.97, as OctoMap).
    model : InverseSensorModel, optional
        The inverse sensor model (default ``InverseSensorModel()``).
    spec : GridSpec, optional
        Initial geometry. Without it the grid is laid out around the first scan.
    fixed : bool
        If true the grid never grows: a pose or endpoint outside ``spec`` raises
        :class:`GridBoundsError`. Requires ``spec``.
    max_extent : float
        Largest side (metres) a growing grid may reach (default :data:`MAX_EXTENT_M`, 3 km):
        a scan that would need more raises :class:`GridBoundsError` and changes nothing.

    Notes
    -----
    Every cell receives at most one update per scan (one scan is one measurement ``z_t``). Where a
    cell is hit by one beam and crossed by another in the same scan, the hit wins. The grid grows
    geometrically when poses or endpoints leave it (amortised, like a dynamic array).

    Examples
    --------
    >>> import numpy as np
    >>> grid = OccupancyGrid(resolution=0.1)
    >>> angles = np.linspace(-np.pi / 2, np.pi / 2, 181)
    >>> stats = grid.integrate_scan((0.0, 0.0, 0.0), np.full(181, 2.0), angles, max_range=10.0)
    >>> stats.hits
    181
    >>> ix, iy = grid.spec.world_to_cell([2.05, 0.0])
    >>> round(float(grid.probability()[iy, ix]), 2)
    0.7
    >>> ix, iy = grid.spec.world_to_cell([1.0, 0.0])
    >>> round(float(grid.probability()[iy, ix]), 2)
    0.4
    """

    def __init__(
        self,
        resolution: float = 0.05,
        *,
        p0: float = 0.5,
        clamp: tuple[float, float] = (0.12, 0.97),
        model: InverseSensorModel | None = None,
        spec: GridSpec | None = None,
        fixed: bool = False,
        max_extent: float = MAX_EXTENT_M,
    ) -> None:
        if not (math.isfinite(max_extent) and max_extent > 0):
            raise ValueError(f"max_extent must be a positive number of metres, got {max_extent}")
        res = grid_resolution(spec, resolution)
        if not 0.0 < p0 < 1.0:
            raise ValueError(f"p0 must lie in (0, 1), got {p0}")
        if not 0.0 < clamp[0] <= p0 <= clamp[1] < 1.0:
            raise ValueError(f"clamp must satisfy 0 < p_min <= p0 <= p_max < 1, got {clamp}")
        if fixed and spec is None:
            raise ValueError("a fixed-bounds grid needs a spec (GridSpec) giving its bounds")
        self.resolution = res
        self.p0 = float(p0)
        self.l0 = float(logit(p0))
        self.clamp = (float(clamp[0]), float(clamp[1]))
        self.l_min = float(logit(clamp[0]))
        self.l_max = float(logit(clamp[1]))
        self.model = model if model is not None else InverseSensorModel()
        self.fixed = bool(fixed)
        self.max_extent = float(max_extent)
        self._scans = 0
        if spec is None:
            spec = GridSpec(res, (0.0, 0.0), (0, 0))
        self._spec = spec
        self._lo = filled(spec.shape, np.float32(self.l0))
        # stamp[iy, ix]: 0 = never updated, otherwise the epoch-relative id (1..255) of the last
        # scan that updated the cell. One byte per cell: when the ids run out every nonzero
        # stamp is set back to 1 and ids restart at 2 (see _next_ids), so a cell is still
        # changed at most once per scan and ``observed`` is still ``stamp != 0``.
        self._stamp = filled(spec.shape, np.uint8(0))
        self._sid = 1  # last scan id handed out in the current epoch
        self._fast: tuple[tuple[Any, ...], NDArray[np.float64]] | None = None

    # ------------------------------------------------------------------ state
    @property
    def log_odds(self) -> NDArray[np.float32]:
        """Log odds, shape (H, W), float32, indexed ``[iy, ix]`` (row 0 at the smallest y)."""
        return self._lo

    def probability(self) -> NDArray[np.float64]:
        """Posterior occupancy ``p = 1 - 1/(1 + exp(l))`` per cell, shape (H, W)."""
        return np.asarray(prob(self._lo), dtype=np.float64)

    def classify(
        self, occupied_thresh: float = 0.65, free_thresh: float = 0.196
    ) -> NDArray[np.int8]:
        """Trinary map: 1 occupied (``p > occupied_thresh``), 0 free (``p < free_thresh``), -1 unknown.

        Cells never observed are unknown whatever their prior. Thresholds follow the ROS
        map_server convention (defaults 0.65 and 0.196).
        """
        if not 0.0 <= free_thresh <= occupied_thresh <= 1.0:
            raise ValueError(
                f"need 0 <= free_thresh <= occupied_thresh <= 1, got {free_thresh}, {occupied_thresh}"
            )
        p = self.probability()
        out = np.full(p.shape, -1, dtype=np.int8)
        seen = self.observed
        out[seen & (p > occupied_thresh)] = 1
        out[seen & (p < free_thresh)] = 0
        return out

    @classmethod
    def from_log_odds(
        cls,
        spec: GridSpec,
        log_odds: ArrayLike,
        *,
        p0: float = 0.5,
        clamp: tuple[float, float] = (0.12, 0.97),
        observed: ArrayLike | None = None,
        model: InverseSensorModel | None = None,
    ) -> OccupancyGrid:
        """Rebuild a grid from stored log odds (and the mask of observed cells)."""
        lo = np.asarray(log_odds, dtype=np.float32)
        if lo.shape != spec.shape:
            raise ValueError(f"log_odds shape {lo.shape} does not match spec.shape {spec.shape}")
        grid = cls(spec.resolution, p0=p0, clamp=clamp, model=model, spec=spec)
        grid._lo = np.ascontiguousarray(lo).copy()
        seen = observed_mask(observed, spec, lambda: lo != np.float32(grid.l0))
        grid._stamp = seen.astype(np.uint8)
        grid._scans = 1 if seen.any() else 0
        return grid

    def cropped(self, margin: int = 2) -> OccupancyGrid:
        """A copy trimmed to the observed cells plus ``margin`` cells, on the same cell lattice.

        Growth leaves unobserved borders; trimming them before writing keeps map files small.
        World positions of cells are unchanged. A grid with no observed cell is returned as a copy.
        """
        seen = self.observed
        window = observed_window(seen, margin)
        if window is None:
            y0, y1, x0, x1 = 0, self._spec.height, 0, self._spec.width
        else:
            y0, y1, x0, x1 = window
        r = self._spec.resolution
        ox, oy = self._spec.origin
        spec = GridSpec(r, (ox + x0 * r, oy + y0 * r), (y1 - y0, x1 - x0))
        out = OccupancyGrid(
            r,
            p0=self.p0,
            clamp=self.clamp,
            model=self.model,
            spec=spec,
            fixed=self.fixed,
            max_extent=self.max_extent,
        )
        out._lo = self._lo[y0:y1, x0:x1].copy()
        out._stamp = self._stamp[y0:y1, x0:x1].copy()
        out._sid = self._sid
        out._scans = self._scans
        return out

    # ------------------------------------------------------------------ growth
    def _ensure_bounds(self, box: NDArray[np.float64]) -> None:
        if not np.isfinite(box).all():
            raise ValueError("poses must be finite numbers")
        new, off = plan_growth(self._spec, box, fixed=self.fixed, max_extent=self.max_extent)
        if new is self._spec:
            return
        self._lo = regrid(self._lo, new.shape, off, self.l0)
        self._stamp = regrid(self._stamp, new.shape, off, 0)
        self._spec = new

    def _next_ids(self, n: int) -> int:
        """First of ``n`` consecutive scan ids (``n <= 254``) that no cell carries yet.

        Ids live in 2..255 within an epoch; a new epoch marks every updated cell with 1 (still
        observed, never equal to a coming id). This costs one pass over the grid per 254
        scans and keeps the stamp at one byte per cell.
        """
        if self._sid + n > 255:
            reset_stamps(self._stamp)
            self._sid = 1
        first = self._sid + 1
        self._sid += n
        return first

    # ------------------------------------------------------------------ updates
    # integrate_scans' arguments for one scan (public; the batch path shares the kernel).
    def integrate_scan(
        self,
        pose: ArrayLike,
        ranges: ArrayLike,
        angles: ArrayLike,
        *,
        max_range: float = math.inf,
    ) -> ScanStats:
        """Integrate one range scan ``z_t`` taken from a known sensor pose (Table 9.1).

        Parameters
        ----------
        pose : array_like, shape (3,)
            Sensor pose ``(x, y, theta)`` in the world frame (metres, radians).
        ranges : array_like, shape (B,)
            Measured ranges in metres. NaN, inf, zero and negative readings are dropped and
            counted; readings ``>= max_range`` are "no return" (free space only).
        angles : array_like, shape (B,)
            Beam angles in radians in the sensor frame (counter-clockwise, 0 = sensor x axis).
        max_range : float
            The sensor's maximum range in metres.

        Returns
        -------
        ScanStats
            Counts of beams, hits, max-range and dropped readings and cell updates.

        Notes
        -----
        Made for streaming one scan at a time: a single compiled call checks the input and the
        bounds and integrates the scan (a few microseconds of overhead per call). A scan that
        leaves the grid, bad input and the scan that starts a new stamp epoch go through
        :meth:`integrate_scans` instead, which grows the grid or raises; the result is the same
        as ``integrate_scans`` on this one scan, bit for bit.

        Examples
        --------
        >>> import numpy as np
        >>> g = OccupancyGrid(resolution=0.5)
        >>> g.integrate_scan([0, 0, 0], [1.2, np.nan], [0.0, 0.1], max_range=5).dropped
        1
        """
        p, r = check_one_scan(pose, ranges)
        # Fast path: one compiled call validates, checks the bounds and integrates. Anything it
        # declines (bad input, a scan that leaves the grid, the end of a stamp epoch, unusual
        # arguments) goes through integrate_scans, which raises the usual errors or grows the grid.
        if self._sid < 255:
            try:
                a = np.asarray(angles, dtype=np.float64)
                mr = float(max_range)
            except (TypeError, ValueError):
                a = None
            if a is not None and a.ndim == 1:
                kernel = _one_scan_kernel or _load_one_scan_kernel()
                code, hits, n_max, dropped, updates = kernel(
                    self._lo, self._stamp, self._sid + 1, p, r, a, mr, self._fast_params()
                )
                if code == 0:
                    self._sid += 1
                    self._scans += 1
                    return ScanStats(1, r.shape[0], hits, n_max, dropped, updates)
        return self.integrate_scans(p[None, :], r[None, :], angles, max_range=max_range)

    def _fast_params(self) -> NDArray[np.float64]:
        """The float64 parameters of :func:`_kernels.integrate_one_scan`, rebuilt only when the
        geometry, the sensor model, the prior or the clamping bounds change."""
        key = (self._spec, self.model, self.l0, self.l_min, self.l_max)
        cached = self._fast
        if cached is not None and cached[0] == key:
            return cached[1]
        m = self.model
        ox, oy = self._spec.origin
        params = np.array(
            [
                ox,
                oy,
                self._spec.resolution,
                -1.0 if m.max_clear_range is None else m.max_clear_range,
                m.thickness,
                m.l_hit - self.l0,
                m.l_miss - self.l0,
                self.l_min,
                self.l_max,
            ],
            dtype=np.float64,
        )
        self._fast = (key, params)
        return params

    # integrate_scan's arguments stacked per scan: the one-scan and batch entry points.
    def integrate_scans(
        self,
        poses: ArrayLike,
        ranges: ArrayLike,
        angles: ArrayLike,
        *,
        max_range: float = math.inf,
    ) -> ScanStats:
        """Integrate a batch of scans in order, each one measurement ``z_t`` (Table 9.1).

        Parameters
        ----------
        poses : array_like, shape (S, 3)
            Sensor poses ``(x, y, theta)`` in the world frame.
        ranges : array_like, shape (S, B)
            Ranges in metres (see :meth:`integrate_scan`).
        angles : array_like, shape (B,) or (S, B)
            Beam angles in the sensor frame, shared by all scans or per scan.
        max_range : float
            The sensor's maximum range in metres.

        Returns
        -------
        ScanStats

        Examples
        --------
        >>> import numpy as np
        >>> g = OccupancyGrid(resolution=0.1)
        >>> poses = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
        >>> s = g.integrate_scans(poses, np.full((2, 3), 1.0), np.array([-0.1, 0.0, 0.1]))
        >>> ix, iy = g.spec.world_to_cell([1.05, 0.0])
        >>> round(float(g.probability()[iy, ix]), 4)  # two hits: l = 2 logit(0.7)
        0.8448
        """
        from probmap.grid import _kernels

        P, R = check_poses_and_ranges(poses, ranges)
        A, shared, max_range = check_angles_and_max_range(angles, R, max_range)
        clear_range = effective_clear_range(self.model.max_clear_range, max_range)
        if P.shape[0] == 0:
            return ScanStats(0, 0, 0, 0, 0, 0)
        self._fit_scans(P, R, A, shared, max_range, clear_range)
        counts = np.zeros(4, dtype=np.int64)
        ox, oy = self._spec.origin
        res, thickness = self._spec.resolution, self.model.thickness
        for s0 in range(0, P.shape[0], _EPOCH):
            s1 = min(s0 + _EPOCH, P.shape[0])
            a = A if shared else A[s0:s1]
            scan = (ox, oy, res, P[s0:s1], R[s0:s1], a, shared, max_range, clear_range, thickness)
            _kernels.integrate_scans(
                self._lo,
                self._lo,
                self._stamp,
                self._next_ids(s1 - s0),
                scan,
                self.model.l_hit - self.l0,
                self.model.l_miss - self.l0,
                self.l_min,
                self.l_max,
                counts,
            )
        self._scans += P.shape[0]
        return ScanStats.from_counts(P.shape[0], R.size, counts)
