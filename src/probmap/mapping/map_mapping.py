"""MAP occupancy grid mapping with a forward sensor model (Probabilistic Robotics 9.4, Table 9.3).

The per-cell binary Bayes filter (Table 9.1) treats cells as independent and so can build maps
that contradict the data (a wide sonar cone through an open door). The MAP map instead
maximises the posterior of the whole binary map (eq. 9.25)::

    m* = argmax_m  sum_t log p(z_t | x_t, m) + l0 * sum_i m_i

with the beam model (Table 6.1) as ``p(z | x, m)``. It is found by hill climbing (Table 9.3):
start from the all-free map (or a thresholded log-odds map), visit every cell and flip it when
the flip raises the objective; sweep until no flip does, or ``max_sweeps``.

Incremental evaluation: every beam (a laser ray, or a sonar cone made of sub-rays) has a
*window*, the cells it crosses up to ``z + window`` metres, sorted by the range at which the
beam meets them. The beam's expected range ``z*`` is the range of its first occupied window
cell, so its likelihood depends on those cells only. An index from each cell to the beams that
cross it means a candidate flip recomputes only those beams, each in O(1) for free -> occupied
and by a scan of its window for occupied -> free. Per-entry log-likelihoods are tabulated once.

Truncation: when no window cell is occupied, the beam is evaluated with ``z* = z + window``
(the obstacle is taken to lie just beyond the window), so cells further away never matter.
Max-range readings have the constant likelihood ``z_max`` in the beam model (the point mass
does not depend on ``z*``) and enter the objective as a constant.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._checks import require_at_least
from probmap.grid.logodds import logit
from probmap.grid.spec import GridSpec
from probmap.models.beam import BeamModelParams

if TYPE_CHECKING:  # pragma: no cover
    from probmap.grid.occupancy import InverseSensorModel, OccupancyGrid

# grid/map_mapping.py (the one-release shim) names these again: it must not import this module.
__all__ = [
    "BeamIndex",
    "MapMapper",
    "MapMappingConfig",
    "MapMappingResult",
    "SweepRecord",
    "cone_log_odds_grid",
    "cone_offsets",
    "map_mapping",
]


@dataclass(frozen=True)
class MapMappingConfig:
    """Parameters of MAP occupancy grid mapping.

    Parameters
    ----------
    resolution : float
        Cell size in metres.
    model : BeamModelParams
        The forward sensor model.
    p0 : float
        Prior occupancy ``p(m)``; ``l0 = logit(p0)`` is the per-cell prior term of eq. 9.25.
        Below 0.5 it penalises every occupied cell, so cells the data do not support stay free.
    window : float or None
        Metres past each reading that the beam's window extends (None: ``3 * sigma_hit``).
    max_sweeps : int
        Stop after this many sweeps even if some flip still improves the objective.
    init : str
        ``"free"`` (the all-free map of Table 9.3) or ``"log-odds"`` (the log-odds map of the
        same data thresholded at p = 0.5).
    opening : float
        Full opening angle of the beam cone in radians; 0 for a laser.
    subrays : int
        Rays that sample a cone (1 for a laser).
    tol : float
        A flip must raise the objective by more than this to be taken (guards against cycling
        on round-off).
    order : str
        ``"gain"`` (default: in each sweep, cells whose flip helps, greatest gain first) or
        ``"raster"`` (every cell row by row, as Table 9.3 is written); see
        :meth:`MapMapper.sweep`.
    """

    resolution: float = 0.1
    model: BeamModelParams = field(default_factory=BeamModelParams)
    p0: float = 0.3
    window: float | None = None
    max_sweeps: int = 50
    init: str = "free"
    opening: float = 0.0
    subrays: int = 1
    tol: float = 1e-9
    order: str = "gain"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f"resolution must be > 0 m, got {self.resolution}")
        if not 0.0 < self.p0 < 1.0:
            raise ValueError(f"p0 must lie in (0, 1), got {self.p0}")
        if self.window is not None and not (math.isfinite(self.window) and self.window >= 0):
            raise ValueError(f"window must be >= 0 m, got {self.window}")
        require_at_least("max_sweeps", self.max_sweeps, 1)
        if self.init not in ("free", "log-odds"):
            raise ValueError(f"init must be 'free' or 'log-odds', got {self.init!r}")
        if not (0.0 <= self.opening < math.pi):
            raise ValueError(f"opening must lie in [0, pi) radians, got {self.opening}")
        if self.subrays < 1 or (self.opening == 0.0 and self.subrays != 1):
            raise ValueError(
                f"subrays must be >= 1, and 1 when opening is 0; got {self.subrays} "
                f"with opening {self.opening}"
            )
        if self.order not in ("gain", "raster"):
            raise ValueError(f"order must be 'gain' or 'raster', got {self.order!r}")
        require_at_least("tol", self.tol, 0)

    @property
    def l0(self) -> float:
        """Prior log odds ``logit(p0)``."""
        return float(logit(self.p0))

    @property
    def window_m(self) -> float:
        """The window in metres (``3 * sigma_hit`` unless set)."""
        return 3.0 * self.model.sigma_hit if self.window is None else float(self.window)


def cone_offsets(opening: float, subrays: int) -> NDArray[np.float64]:
    """Angles (rad) of the sub-rays of a cone about its axis: evenly spaced over the opening.

    Examples
    --------
    >>> cone_offsets(0.0, 1).tolist()
    [0.0]
    >>> [round(v, 3) for v in cone_offsets(0.5, 3).tolist()]
    [-0.25, 0.0, 0.25]
    """
    if subrays == 1:
        return np.zeros(1)
    return np.linspace(-0.5 * opening, 0.5 * opening, subrays)


def cone_log_odds_grid(
    poses: ArrayLike,
    ranges: ArrayLike,
    angles: ArrayLike,
    max_range: float,
    spec: GridSpec,
    *,
    opening: float = 0.0,
    subrays: int = 1,
    model: InverseSensorModel | None = None,
    p0: float = 0.5,
) -> OccupancyGrid:
    """The log-odds map (Table 9.1) of cone readings on a fixed grid.

    Each cone is one measurement: its sub-rays all carry the cone's reading, so the cells of
    the cone before the reading are marked free and those at the reading occupied, each at
    most once per cone. With ``subrays = 1`` this is the ordinary laser log-odds map.

    Returns
    -------
    OccupancyGrid
        On ``spec``; the parts of beams that leave it are cropped away.
    """
    from probmap.grid.occupancy import OccupancyGrid

    P = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    R = np.asarray(ranges, dtype=np.float64)
    A = np.asarray(angles, dtype=np.float64)
    if A.ndim == 1:
        A = np.broadcast_to(A[None, :], R.shape)
    offs = cone_offsets(opening, subrays)
    s, b = R.shape
    cone_poses = np.repeat(P, b, axis=0)
    cone_angles = (A.reshape(s * b, 1) + offs[None, :]).copy()
    cone_ranges = np.repeat(R.reshape(s * b, 1), offs.shape[0], axis=1)
    grid = OccupancyGrid(spec.resolution, p0=p0, model=model, spec=spec)
    grid.integrate_scans(cone_poses, cone_ranges, cone_angles, max_range=max_range)
    if grid.spec == spec:
        return grid
    # the grid grew on the same lattice for beams that leave ``spec``: crop it back
    ox = round((spec.origin[0] - grid.spec.origin[0]) / spec.resolution)
    oy = round((spec.origin[1] - grid.spec.origin[1]) / spec.resolution)
    h, w = spec.shape
    return OccupancyGrid.from_log_odds(
        spec,
        grid.log_odds[oy : oy + h, ox : ox + w],
        p0=p0,
        clamp=grid.clamp,
        observed=grid.observed[oy : oy + h, ox : ox + w],
        model=grid.model,
    )


def _scan_inputs(
    poses: ArrayLike, ranges: ArrayLike, angles: ArrayLike, max_range: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]:
    from probmap.grid.occupancy import check_poses_and_ranges

    P, R = check_poses_and_ranges(poses, ranges)
    A = np.asarray(angles, dtype=np.float64)
    if A.ndim == 1 and A.shape[0] == R.shape[1]:
        A = np.broadcast_to(A[None, :], R.shape)
    if A.shape != R.shape:
        raise ValueError(f"angles shape {np.shape(angles)} does not match ranges {R.shape}")
    if not np.isfinite(A).all():
        raise ValueError("beam angles must be finite")
    mr = float(max_range)
    if not (math.isfinite(mr) and mr > 0):
        raise ValueError(f"max_range must be a finite number > 0 m, got {max_range}")
    return P, R, np.asarray(A), mr


class BeamIndex:
    """The beams of a data set, their windows and the cell -> beams index (see module notes).

    Build with :meth:`build`. Arrays follow :mod:`probmap.mapping._map_kernels`.

    Attributes
    ----------
    spec : GridSpec
        Geometry of the map.
    beams : int
        Beams with a window (valid readings below the maximum range).
    max_range_beams : int
        Readings at or beyond the maximum range (constant likelihood ``z_max``).
    dropped : int
        Readings that are NaN, infinite or not positive (ignored).
    constant : float
        Sum of the constant log-likelihoods of the max-range readings.
    """

    def __init__(
        self,
        spec: GridSpec,
        f_ptr: NDArray[np.int64],
        f_cell: NDArray[np.int32],
        f_dist: NDArray[np.float64],
        f_ll: NDArray[np.float64],
        far_ll: NDArray[np.float64],
        *,
        max_range_beams: int = 0,
        dropped: int = 0,
        constant: float = 0.0,
    ) -> None:
        from probmap.mapping import _map_kernels as _k

        self.spec = spec
        self.f_ptr, self.f_cell, self.f_dist, self.f_ll = f_ptr, f_cell, f_dist, f_ll
        self.far_ll = far_ll
        n_cells = spec.shape[0] * spec.shape[1]
        self.i_ptr, self.i_entry, self.e_beam = _k.invert_entries(f_ptr, f_cell, n_cells)
        self.beams = int(f_ptr.shape[0] - 1)
        self.max_range_beams = int(max_range_beams)
        self.dropped = int(dropped)
        self.constant = float(constant)

    # map_mapping's scan arguments (it builds its index with them): both are public.
    @classmethod
    def build(
        cls,
        poses: ArrayLike,
        ranges: ArrayLike,
        angles: ArrayLike,
        max_range: float,
        config: MapMappingConfig | None = None,
        *,
        spec: GridSpec | None = None,
    ) -> BeamIndex:
        """Index the beams of a batch of scans.

        Parameters
        ----------
        poses : array_like, shape (S, 3)
            Sensor poses ``(x, y, theta)`` in the world frame (m, rad).
        ranges : array_like, shape (S, B)
            Readings in metres; NaN, inf and non-positive readings are dropped (counted),
            readings ``>= max_range`` are max-range readings.
        angles : array_like, shape (B,) or (S, B)
            Beam (cone axis) angles in the sensor frame, radians.
        max_range : float
            The sensor's maximum range ``z_max`` in metres.
        config : MapMappingConfig, optional
            Resolution, model, window and cone.
        spec : GridSpec, optional
            Map geometry; default: the smallest grid on the lattice through (0, 0) holding
            every window, plus 2 cells. Windows are clipped to it.
        """
        from probmap.mapping import _map_kernels as _k

        cfg = config or MapMappingConfig()
        P, R, A, mr = _scan_inputs(poses, ranges, angles, max_range)
        valid = np.isfinite(R) & (R > 0.0)
        hit = valid & (R < mr)
        dropped = int(R.size - valid.sum())
        n_max = int((valid & ~hit).sum())
        si, bi = np.nonzero(hit)
        z = np.ascontiguousarray(R[si, bi])
        theta = np.ascontiguousarray(P[si, 2] + A[si, bi])
        sx = np.ascontiguousarray(P[si, 0])
        sy = np.ascontiguousarray(P[si, 1])
        length = np.minimum(z + cfg.window_m, mr)
        offsets = cone_offsets(cfg.opening, cfg.subrays)
        if spec is None:
            if z.size:
                ends_x = sx[:, None] + length[:, None] * np.cos(theta[:, None] + offsets)
                ends_y = sy[:, None] + length[:, None] * np.sin(theta[:, None] + offsets)
                xs = np.concatenate([P[:, 0], ends_x.ravel()])
                ys = np.concatenate([P[:, 1], ends_y.ravel()])
            else:
                xs, ys = P[:, 0], P[:, 1]
            if xs.size == 0:
                raise ValueError("no scans to map")
            spec = GridSpec.around(cfg.resolution, xs.min(), xs.max(), ys.min(), ys.max(), margin=2)
        res = spec.resolution
        h, w = spec.shape
        if h * w == 0:
            raise ValueError("the map has no cells")
        capacity = int(np.sum(len(offsets) * (np.floor(length / res * math.sqrt(2.0)) + 3)))
        f_ptr, f_cell, f_dist, f_ll = _k.build_entries(
            sx, sy, theta, z, length, offsets, spec.origin[0], spec.origin[1], res,
            h, w, mr, cfg.model.as_array(), max(capacity, 1),
        )  # fmt: skip
        far_ll = cfg.model.log_likelihood(z, length, mr)
        constant = n_max * math.log(cfg.model.z_max)
        return cls(
            spec, f_ptr, f_cell, f_dist, f_ll, np.ascontiguousarray(far_ll),
            max_range_beams=n_max, dropped=dropped, constant=constant,
        )  # fmt: skip

    @property
    def entries(self) -> int:
        """Total (beam, cell) dependencies."""
        return int(self.f_cell.shape[0])

    @property
    def observed(self) -> NDArray[np.bool_]:
        """Cells some beam depends on, shape (H, W)."""
        return np.asarray(np.diff(self.i_ptr) > 0).reshape(self.spec.shape)

    def _occ(self, occupied: ArrayLike) -> NDArray[np.uint8]:
        occ = np.asarray(occupied)
        if occ.shape != self.spec.shape:
            raise ValueError(f"map shape {occ.shape} does not match the grid {self.spec.shape}")
        return np.ascontiguousarray(occ.astype(np.uint8).ravel())

    def beam_log_likelihoods(self, occupied: ArrayLike) -> NDArray[np.float64]:
        """``log p(z_b | x_b, m)`` of every windowed beam on a binary map (H, W), shape (beams,)."""
        from probmap.mapping import _map_kernels as _k

        first = np.empty(self.beams, dtype=np.int64)
        ll = np.empty(self.beams)
        _k.evaluate_beams(self._occ(occupied), self.f_ptr, self.f_cell, self.f_ll, self.far_ll,
                          first, ll)  # fmt: skip
        return ll

    def objective(self, occupied: ArrayLike, l0: float) -> float:
        """Eq. 9.25 from scratch: ``sum_t log p(z_t | x_t, m) + l0 * sum_i m_i``."""
        occ = self._occ(occupied)
        return float(
            self.beam_log_likelihoods(occ.reshape(self.spec.shape)).sum()
            + self.constant
            + l0 * int(occ.sum())
        )


@dataclass(frozen=True)
class SweepRecord:
    """One sweep of Table 9.3: flips taken and the objective (eq. 9.25) after it."""

    sweep: int
    flips: int
    objective: float
    seconds: float


class MapMapper:
    """Hill climbing on the MAP objective (Table 9.3) over a :class:`BeamIndex`.

    Parameters
    ----------
    index : BeamIndex
        The beams and their dependencies.
    l0 : float
        Prior log odds of occupancy (eq. 9.24).
    init : array_like of bool, shape (H, W), optional
        Starting map (default all free, Table 9.3 line 2).
    tol : float
        Minimum gain of an accepted flip.
    order : str
        ``"gain"`` or ``"raster"``: the order cells are visited in a sweep (see :meth:`sweep`).
    """

    def __init__(
        self,
        index: BeamIndex,
        l0: float,
        init: ArrayLike | None = None,
        *,
        tol: float = 1e-9,
        order: str = "gain",
    ) -> None:
        from probmap.mapping import _map_kernels as _k

        if order not in ("gain", "raster"):
            raise ValueError(f"order must be 'gain' or 'raster', got {order!r}")
        self.order = order
        self.index = index
        self.l0 = float(l0)
        self.tol = float(tol)
        shape = index.spec.shape
        self._occ = (
            np.zeros(shape[0] * shape[1], dtype=np.uint8)
            if init is None
            else index._occ(init).copy()
        )
        self._first = np.empty(index.beams, dtype=np.int64)
        self._ll = np.empty(index.beams)
        _k.evaluate_beams(self._occ, index.f_ptr, index.f_cell, index.f_ll, index.far_ll,
                          self._first, self._ll)  # fmt: skip
        self._objective = self.recompute_objective()
        # cells no beam depends on change the objective by l0 alone: decide them once
        counts = np.diff(index.i_ptr)
        self._cells = np.ascontiguousarray(np.nonzero(counts > 0)[0])
        idle = counts == 0
        if self.l0 > self.tol:
            self._occ[idle] = 1
        elif -self.l0 > self.tol:
            self._occ[idle] = 0
        self._objective = self.recompute_objective()
        self.history: list[SweepRecord] = [SweepRecord(0, 0, self._objective, 0.0)]

    @property
    def occupied(self) -> NDArray[np.bool_]:
        """The current binary map, shape (H, W), True = occupied."""
        return self._occ.reshape(self.index.spec.shape).astype(bool)

    @property
    def objective(self) -> float:
        """The objective (eq. 9.25) maintained incrementally."""
        return self._objective

    def recompute_objective(self) -> float:
        """The objective from scratch (checks the incremental bookkeeping)."""
        return self.index.objective(self._occ.reshape(self.index.spec.shape), self.l0)

    def _args(self) -> tuple[Any, ...]:
        ix = self.index
        return (self._occ, ix.i_ptr, ix.i_entry, ix.e_beam, ix.f_ptr, ix.f_cell, ix.f_ll,
                ix.far_ll, self._first, self._ll)  # fmt: skip

    def flip_gains(self) -> NDArray[np.float64]:
        """Gain of flipping each cell alone, shape (H, W) (0 for cells no beam depends on)."""
        from probmap.mapping import _map_kernels as _k

        out = np.zeros(self._occ.shape[0])
        gains: Any = _k.all_gains
        out[self._cells] = gains(self._cells, *self._args(), self.l0)
        idle = np.ones(self._occ.shape[0], dtype=bool)
        idle[self._cells] = False
        out[idle] = np.where(self._occ[idle] == 1, -self.l0, self.l0)
        return out.reshape(self.index.spec.shape)

    def sweep(self) -> SweepRecord:
        """One sweep of Table 9.3: visit the cells, flipping each one whose flip (given the
        flips made so far) raises the objective.

        ``order="gain"`` visits only the cells whose flip gain is positive at the start of the
        sweep, largest gain first; ``order="raster"`` visits every cell row by row, the
        book's literal loop. Both accept a flip only when it raises the objective, and a sweep
        that flips nothing certifies a local optimum. Greatest gain first matters with wide
        hit Gaussians: in raster order, a cell a little short of a wall (which explains the
        beams better than no obstacle at all) can be taken before the wall cell behind it,
        and then shadows it for good.
        """
        from probmap.mapping import _map_kernels as _k

        t0 = time.perf_counter()
        kernel: Any = _k.sweep
        if self.order == "gain":
            gains: Any = _k.all_gains
            g = gains(self._cells, *self._args(), self.l0)
            good = np.nonzero(g > self.tol)[0]
            cells = np.ascontiguousarray(self._cells[good[np.argsort(-g[good], kind="stable")]])
        else:
            cells = self._cells
        flips, gain = kernel(cells, *self._args(), self.l0, self.tol)
        self._objective += gain
        rec = SweepRecord(len(self.history), int(flips), self._objective, time.perf_counter() - t0)
        self.history.append(rec)
        return rec

    def run(
        self, max_sweeps: int = 50, progress: Callable[[SweepRecord], None] | None = None
    ) -> bool:
        """Sweep until a sweep flips nothing (converged: returns True) or ``max_sweeps``."""
        for _ in range(max_sweeps):
            rec = self.sweep()
            if progress is not None:
                progress(rec)
            if rec.flips == 0:
                return True
        return False


@dataclass(frozen=True, eq=False)
class MapMappingResult:
    """A MAP map and how it was found.

    Attributes
    ----------
    occupied : ndarray of bool, shape (H, W)
        The MAP map, True = occupied.
    observed : ndarray of bool, shape (H, W)
        Cells some beam depends on (the others are at their prior).
    spec : GridSpec
        Geometry.
    history : tuple of SweepRecord
        Sweep 0 is the starting map; the objective never decreases.
    converged : bool
        The last sweep flipped nothing: no single flip improves the map.
    objective : float
        Final objective recomputed from scratch.
    index_seconds : float
        Time to build the beam index.
    index : BeamIndex
        The index (for evaluating other maps on the same data).
    """

    occupied: NDArray[np.bool_]
    observed: NDArray[np.bool_]
    spec: GridSpec
    history: tuple[SweepRecord, ...]
    converged: bool
    objective: float
    index_seconds: float
    index: BeamIndex

    @property
    def sweep_seconds(self) -> float:
        """Total time spent sweeping."""
        return float(sum(r.seconds for r in self.history))


# BeamIndex.build's arguments first, which it hands on, then the sweep's own.
def map_mapping(
    poses: ArrayLike,
    ranges: ArrayLike,
    angles: ArrayLike,
    max_range: float,
    config: MapMappingConfig | None = None,
    *,
    spec: GridSpec | None = None,
    init: ArrayLike | None = None,
    progress: Callable[[SweepRecord], None] | None = None,
) -> MapMappingResult:
    """MAP occupancy grid mapping with known poses (eq. 9.25, Table 9.3).

    Parameters
    ----------
    poses, ranges, angles, max_range
        As :meth:`BeamIndex.build`.
    config : MapMappingConfig, optional
        Resolution, model, prior, cone and stopping rule.
    spec : GridSpec, optional
        Map geometry (default: fitted around the data).
    init : array_like of bool, shape (H, W), optional
        Starting map on ``spec``; overrides ``config.init``.
    progress : callable, optional
        Called with each :class:`SweepRecord`.

    Returns
    -------
    MapMappingResult

    Examples
    --------
    >>> import numpy as np
    >>> angles = np.linspace(-0.5, 0.5, 11)
    >>> poses = np.array([[0.0, 0.0, 0.0], [0.5, 0.2, 0.0]])
    >>> ranges = 2.0 / np.cos(angles) - poses[:, :1]  # a wall at x = 2 m
    >>> res = map_mapping(poses, ranges, angles, 8.0, MapMappingConfig(resolution=0.1))
    >>> ix, iy = res.spec.world_to_cell([2.05, 0.0])
    >>> res.converged, bool(res.occupied[iy, ix]), bool(res.occupied[iy, ix - 5])
    (True, True, False)
    """
    from probmap.mapping import _map_kernels  # noqa: F401  (compile before timing)

    cfg = config or MapMappingConfig()
    t0 = time.perf_counter()
    index = BeamIndex.build(poses, ranges, angles, max_range, cfg, spec=spec)
    t1 = time.perf_counter()
    if init is None and cfg.init == "log-odds":
        grid = cone_log_odds_grid(
            poses, ranges, angles, max_range, index.spec, opening=cfg.opening,
            subrays=cfg.subrays,
        )  # fmt: skip
        init = grid.classify(0.5, 0.5) == 1
    mapper = MapMapper(index, cfg.l0, init, tol=cfg.tol, order=cfg.order)
    if progress is not None:
        progress(mapper.history[0])
    converged = mapper.run(cfg.max_sweeps, progress)
    occ = mapper.occupied
    final = index.objective(occ, cfg.l0)
    if not math.isfinite(final):  # pragma: no cover - impossible with z_rand, z_max > 0
        raise FloatingPointError("the MAP objective is not finite")
    return MapMappingResult(
        occupied=occ,
        observed=index.observed,
        spec=index.spec,
        history=tuple(mapper.history),
        converged=converged,
        objective=final,
        index_seconds=t1 - t0,
        index=index,
    )
