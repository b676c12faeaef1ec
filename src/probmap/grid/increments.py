"""Occupancy updates as sums: per-cell counts of a share of the scans, exact to add in any order.

The log-odds update of Table 9.1 adds ``inverse_sensor_model - l0`` to a cell for every scan that
sees it, so without clamping the map is ``l0`` plus a sum over scans, and sums split across
machines. For every share of the scans (a log, or a chunk of one long log: one task each in
:mod:`probmap.pipelines.distributed`) :func:`integrate_increments` counts, per cell, how many
scans hit it and how many crossed it, on a tile-aligned window of the common cell lattice (cell ``(i, j)`` covers ``[i r, (i+1) r) x [j r, (j+1) r)`` for every task).
Counts are integers, so the tree reduction that sums them is exact and independent of the order
in which the partial sums meet. The prior and the clamping are applied once, at the end:

    l_i = clip(l0 + n_hit,i (l_hit - l0) + n_free,i (l_miss - l0), l_min, l_max)

Where this differs from sequential mapping
------------------------------------------
Sequential mapping (:class:`~probmap.grid.occupancy.OccupancyGrid`) clamps after *every* update.
Clamping at the end gives the same value in a cell whenever no prefix of its updates, in any
order, can leave ``[l_min, l_max]``: that holds when the cell received updates of one sign only
(clipping a monotone sequence once or at every step is the same), or when
``l0 + n_hit (l_hit - l0) <= l_max`` and ``l0 + n_free (l_miss - l0) >= l_min`` (every partial
sum lies between those two). Elsewhere both values lie in ``[l_min, l_max]`` and differ by at
most ``l_max - l_min``; :func:`clamping_bound` gives this bound per cell (0 where the map is
exact). Apart from clamping, the two differ only by float32 rounding (the sequential grid rounds
to float32 after every update, the distributed one once) and, as any two grids with different
origins do, in the cell of a point lying within rounding error (about 1e-15 cells) of a cell
boundary: ``floor((x - origin) / r)`` is evaluated with each window's own origin, as it is with
the sequential grid's origin after each growth. Recorded poses practically never fall there;
simulated ones on round coordinates do.

These are the core objects of distributed mapping; the Dask pipeline that reads logs, submits
tasks and reduces their sums is :mod:`probmap.pipelines.distributed`.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from probmap.grid._storage import observed_window
from probmap.grid.occupancy import (
    InverseSensorModel,
    OccupancyGrid,
    ScanStats,
    check_finite_poses,
    effective_clear_range,
)
from probmap.grid.spec import GridSpec

__all__ = [
    "IncrementGrid",
    "MappingParams",
    "SemanticIncrements",
    "clamping_bound",
    "integrate_increments",
    "integrate_semantic_increments",
    "tree_sum",
]


class MappingParams(Protocol):
    """What increments need of a mapping configuration (satisfied by
    :class:`probmap.pipelines.MappingConfig`): the resolution, the inverse sensor model and,
    for the final log odds, the prior and the clamp."""

    @property
    def resolution(self) -> float: ...
    @property
    def p_hit(self) -> float: ...
    @property
    def p_miss(self) -> float: ...
    @property
    def thickness(self) -> float: ...
    @property
    def max_clear_range(self) -> float | None: ...
    @property
    def p0(self) -> float: ...
    @property
    def clamp(self) -> tuple[float, float]: ...


@dataclass(frozen=True)
class IncrementGrid:
    """Update counts of a share of the scans on a window of the common cell lattice.

    Parameters
    ----------
    resolution : float
        Cell side in metres.
    cell0 : tuple of int
        ``(ix0, iy0)``: lattice index of the window's cell ``[0, 0]``; its lower-left corner is
        at ``(ix0 r, iy0 r)`` metres in the world frame.
    hits, frees : ndarray of uint16 or int32, shape (H, W)
        Scans that hit the cell (endpoint or obstacle thickness) and scans whose beams crossed
        it, indexed ``[iy, ix]``. A task's own counts are uint16 when it integrated fewer than
        65,536 scans (a cell changes at most once per scan, so they cannot overflow; half the
        bytes to ship), int32 otherwise and in every sum. The log-odds increment is
        ``hits (l_hit - l0) + frees (l_miss - l0)``.
    stats : ScanStats
        Counts of the scans integrated.
    skipped_lines : int
        Malformed log lines skipped while reading them (``skip_bad_lines``).
    """

    resolution: float
    cell0: tuple[int, int]
    hits: NDArray[np.integer[Any]]
    frees: NDArray[np.integer[Any]]
    stats: ScanStats
    skipped_lines: int = 0

    @property
    def spec(self) -> GridSpec:
        """Geometry of the window (origin on the common lattice)."""
        r = self.resolution
        return GridSpec(r, (self.cell0[0] * r, self.cell0[1] * r), self.hits.shape)

    @classmethod
    def empty(cls, resolution: float) -> IncrementGrid:
        """No scans, no cells."""
        z = np.zeros((0, 0), dtype=np.int32)
        return cls(float(resolution), (0, 0), z, z.copy(), ScanStats(0, 0, 0, 0, 0, 0))

    def merge(self, other: IncrementGrid) -> IncrementGrid:
        """The sum of two increment grids on the union of their windows (exact: integers)."""
        if self.resolution != other.resolution:
            raise ValueError(
                f"cannot merge grids of resolution {self.resolution} and {other.resolution}"
            )
        parts = [g for g in (self, other) if g.hits.size]
        if not parts:
            return IncrementGrid(
                self.resolution,
                self.cell0,
                self.hits,
                self.frees,
                self.stats + other.stats,
                self.skipped_lines + other.skipped_lines,
            )
        x0 = min(g.cell0[0] for g in parts)
        y0 = min(g.cell0[1] for g in parts)
        x1 = max(g.cell0[0] + g.hits.shape[1] for g in parts)
        y1 = max(g.cell0[1] + g.hits.shape[0] for g in parts)
        hits = np.zeros((y1 - y0, x1 - x0), dtype=np.int32)
        frees = np.zeros_like(hits)
        for g in parts:
            oy, ox = g.cell0[1] - y0, g.cell0[0] - x0
            h, w = g.hits.shape
            hits[oy : oy + h, ox : ox + w] += g.hits
            frees[oy : oy + h, ox : ox + w] += g.frees
        return IncrementGrid(
            self.resolution,
            (x0, y0),
            hits,
            frees,
            self.stats + other.stats,
            self.skipped_lines + other.skipped_lines,
        )

    def cropped(self, margin: int = 2) -> IncrementGrid:
        """The counts trimmed to the observed cells plus ``margin`` cells (as
        :meth:`OccupancyGrid.cropped`), on the same lattice; a window without observed cells is
        returned as is."""
        window = observed_window((self.hits > 0) | (self.frees > 0), margin)
        if window is None:
            return self
        y0, y1, x0, x1 = window
        return replace(
            self,
            cell0=(self.cell0[0] + x0, self.cell0[1] + y0),
            hits=self.hits[y0:y1, x0:x1].copy(),
            frees=self.frees[y0:y1, x0:x1].copy(),
        )

    def log_odds(self, config: MappingParams) -> NDArray[np.float32]:
        """Final log odds: prior plus increments, clamped once (see the module notes), (H, W)."""
        return self._final(config)[0]

    def _final(self, config: MappingParams) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
        from probmap.grid import _kernels

        l0, d_hit, d_free, l_min, l_max = _levels(config)
        lo = np.empty(self.hits.shape, dtype=np.float32)
        seen = np.empty(self.hits.shape, dtype=np.bool_)
        if lo.size:
            _kernels.counts_to_log_odds(
                self.hits, self.frees, l0, d_hit, d_free, l_min, l_max, lo, seen
            )
        return lo, seen

    def to_grid(self, config: MappingParams) -> OccupancyGrid:
        """The occupancy grid these counts describe, cropped to the observed cells."""
        lo, seen = self._final(config)
        grid = OccupancyGrid.from_log_odds(
            self.spec, lo, p0=config.p0, clamp=config.clamp, observed=seen, model=_model(config)
        )
        return grid.cropped()


def _model(config: MappingParams) -> InverseSensorModel:
    return InverseSensorModel(config.p_hit, config.p_miss, config.thickness, config.max_clear_range)


def _levels(config: MappingParams) -> tuple[float, float, float, float, float]:
    from probmap.grid.logodds import logit

    l0 = float(logit(config.p0))
    model = _model(config)
    return (
        l0,
        model.l_hit - l0,
        model.l_miss - l0,
        float(logit(config.clamp[0])),
        float(logit(config.clamp[1])),
    )


def clamping_bound(increments: IncrementGrid, config: MappingParams) -> NDArray[np.float64]:
    """Per-cell bound on ``|distributed - sequential|`` log odds due to the clamping order.

    0 where no ordering of the cell's updates can reach a clamp (updates of one sign only, or
    ``l0 + n_hit d_hit <= l_max`` and ``l0 + n_free d_free >= l_min``); ``l_max - l_min``
    elsewhere (both maps lie in the clamp interval). Float32 rounding is not included: it adds
    at most a few units in the last place per update. Shape (H, W) of ``increments``.
    """
    l0, d_hit, d_free, l_min, l_max = _levels(config)
    hi = l0 + increments.hits * max(d_hit, 0.0) + increments.frees * max(d_free, 0.0)
    lo = l0 + increments.hits * min(d_hit, 0.0) + increments.frees * min(d_free, 0.0)
    one_sign = (increments.hits == 0) | (increments.frees == 0)
    if d_hit * d_free >= 0:  # both updates push the same way: monotone sequences
        one_sign = np.ones_like(one_sign)
    exact = one_sign | ((hi <= l_max) & (lo >= l_min))
    return np.where(exact, 0.0, l_max - l_min)


_STAMPS = threading.local()


def _scratch_stamps(shape: tuple[int, int], n_scans: int) -> tuple[NDArray[np.int32], int]:
    """A per-thread stamp array of ``shape`` reused across tasks, and the first of ``n_scans``
    fresh stamp ids.

    The once-per-scan rule needs a stamp per cell that no earlier scan left equal to the current
    scan's id. Ids only grow within a process, so the buffer never needs clearing between tasks
    (it is cleared only when the ids would overflow int32): a worker touches warm memory instead
    of faulting in a new array per task, which measured 7 % of a task's time.
    """
    size = shape[0] * shape[1]
    buf: NDArray[np.int32] | None = getattr(_STAMPS, "buf", None)
    nxt: int = getattr(_STAMPS, "next", 1)
    if buf is None or buf.size < size:
        buf = np.zeros(max(size, 0 if buf is None else 2 * buf.size), dtype=np.int32)
        nxt = 1
    if nxt + n_scans >= np.iinfo(np.int32).max:
        buf[:] = 0
        nxt = 1
    _STAMPS.buf, _STAMPS.next = buf, nxt + n_scans
    return buf[:size].reshape(shape), nxt


def _tile_window(box: NDArray[np.float64], res: float, tile: int) -> tuple[int, int, int, int]:
    """Cells ``(ix0, iy0, ix1, iy1)`` of the common lattice (cell ``i`` spans ``[i res, (i + 1)
    res)``) around the world box ``[xmin, xmax, ymin, ymax]``: every point of it plus one cell,
    rounded out to multiples of ``tile`` (the window of a binary or a semantic task)."""
    ix0 = (math.floor(box[0] / res) - 1) // tile * tile
    iy0 = (math.floor(box[2] / res) - 1) // tile * tile
    ix1 = -((-(math.floor(box[1] / res) + 2)) // tile) * tile
    iy1 = -((-(math.floor(box[3] / res) + 2)) // tile) * tile
    return ix0, iy0, ix1, iy1


def integrate_increments(
    poses: NDArray[np.float64],
    ranges: NDArray[np.floating[Any]],
    angles: NDArray[np.float64],
    max_range: float,
    config: MappingParams,
    *,
    tile: int = 64,
) -> IncrementGrid:
    """Count the updates of a batch of scans (Table 9.1 without prior or clamping).

    Parameters
    ----------
    poses : ndarray, shape (S, 3)
        Sensor poses ``(x, y, theta)`` in the world frame (metres, radians).
    ranges : ndarray, shape (S, B)
        Ranges in metres; NaN/inf/non-positive readings are dropped, ``>= max_range`` means no
        return.
    angles : ndarray, shape (B,) or (S, B)
        Beam angles in the sensor frame, radians.
    max_range : float
        The sensor's maximum range in metres.
    config : MappingParams
        Resolution and inverse sensor model (prior and clamp are not used here).
    tile : int
        The window is aligned to multiples of ``tile`` cells of the common lattice.

    Returns
    -------
    IncrementGrid
        Exactly the updates :meth:`OccupancyGrid.integrate_scans` would apply, one per cell
        and scan, with the hit winning over free space within a scan.
    """
    from probmap.grid import _kernels

    P = np.ascontiguousarray(poses, dtype=np.float64)
    R = np.ascontiguousarray(ranges, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or R.ndim != 2 or R.shape[0] != P.shape[0]:
        raise ValueError(f"poses must be (S, 3) and ranges (S, B), got {P.shape} and {R.shape}")
    check_finite_poses(P)
    A = np.asarray(angles, dtype=np.float64)
    shared = A.ndim == 1
    A = np.ascontiguousarray(A[None, :] if shared else A)
    if A.shape[-1] != R.shape[1] or (not shared and A.shape[0] != R.shape[0]):
        raise ValueError(f"angles shape {np.shape(angles)} does not match ranges {R.shape}")
    if not np.isfinite(A).all():
        raise ValueError("angles must be finite")
    if not max_range > 0.0:
        raise ValueError(f"max_range must be > 0 m, got {max_range}")
    res = float(config.resolution)
    if P.shape[0] == 0:
        return IncrementGrid.empty(res)
    model = _model(config)
    clear = model.max_clear_range
    clear_range = effective_clear_range(clear, max_range)
    # window: every pose and endpoint plus one cell, rounded out to whole tiles
    box = np.empty(4)
    _kernels.scan_bounds(P, R, A, shared, float(max_range), clear_range, model.thickness, box)
    ix0, iy0, ix1, iy1 = _tile_window(box, res, tile)
    shape = (iy1 - iy0, ix1 - ix0)
    n = P.shape[0]
    dtype = np.uint16 if n <= np.iinfo(np.uint16).max else np.int32
    hits = np.zeros(shape, dtype=dtype)
    frees = np.zeros(shape, dtype=dtype)
    stamp, sid0 = _scratch_stamps(shape, n)
    counts = np.zeros(4, dtype=np.int64)
    # counting is the grid's own integration with unit increments and no clamping
    big = np.iinfo(np.int64).max
    ox, oy, mr = ix0 * res, iy0 * res, float(max_range)
    scan = (ox, oy, res, P, R, A, shared, mr, clear_range, model.thickness)
    _kernels.integrate_scans(hits, frees, stamp, sid0, scan, 1, 1, -big, big, counts)
    stats = ScanStats.from_counts(n, R.size, counts)
    return IncrementGrid(res, (int(ix0), int(iy0)), hits, frees, stats)


def tree_sum(parts: Sequence[IncrementGrid], fan_in: int = 4) -> IncrementGrid:
    """Sum increment grids level by level, ``fan_in`` at a time, as the cluster's reduction does
    (the sums are integers, so any order gives the same result)."""
    if not parts:
        raise ValueError("nothing to sum")
    if fan_in < 2:
        raise ValueError(f"fan_in must be >= 2, got {fan_in}")
    level = list(parts)
    while len(level) > 1:
        nxt = []
        for i in range(0, len(level), fan_in):
            out = level[i]
            for p in level[i + 1 : i + fan_in]:
                out = out.merge(p)
            nxt.append(out)
        level = nxt
    return level[0]


@dataclass(frozen=True)
class SemanticIncrements:
    """Summed log-odds increments of a semantic grid's updates on a window of the lattice.

    Parameters
    ----------
    resolution : float
        Cell side in metres.
    cell0 : tuple of int
        Lattice index ``(ix0, iy0)`` of the window's cell ``[0, 0]``.
    delta : ndarray of float64, shape (H, W, K)
        Sum over the scans of each update ``inverse term - prior term`` (no clamping).
    observed : ndarray of bool, shape (H, W)
        Cells updated at least once.
    stats : ScanStats
        Counts of the scans integrated.

    Notes
    -----
    The evidence of a semantic update is a real number (class distributions, pooled endpoints),
    so the increments are float64 sums rather than counts: the tree sum is exact up to float64
    rounding (about 1e-13 of the magnitude), far below the final float32 storage. Clamping is
    per class: the result lies within ``l_max[k] - l_min[k]`` of the sequential grid in every
    cell and class and equals it (to rounding) wherever no partial sum reaches a clamp.
    """

    resolution: float
    cell0: tuple[int, int]
    delta: NDArray[np.float64]
    observed: NDArray[np.bool_]
    stats: ScanStats

    @property
    def spec(self) -> GridSpec:
        """Geometry of the window (origin on the common lattice)."""
        r = self.resolution
        return GridSpec(r, (self.cell0[0] * r, self.cell0[1] * r), self.observed.shape)

    def merge(self, other: SemanticIncrements) -> SemanticIncrements:
        """The sum of two increment grids on the union of their windows."""
        if self.resolution != other.resolution or self.delta.shape[2] != other.delta.shape[2]:
            raise ValueError("cannot merge semantic increments of different resolution or classes")
        parts = [g for g in (self, other) if g.observed.size]
        if not parts:
            return replace(self, stats=self.stats + other.stats)
        x0 = min(g.cell0[0] for g in parts)
        y0 = min(g.cell0[1] for g in parts)
        x1 = max(g.cell0[0] + g.observed.shape[1] for g in parts)
        y1 = max(g.cell0[1] + g.observed.shape[0] for g in parts)
        delta = np.zeros((y1 - y0, x1 - x0, self.delta.shape[2]))
        seen = np.zeros((y1 - y0, x1 - x0), dtype=bool)
        for g in parts:
            oy, ox = g.cell0[1] - y0, g.cell0[0] - x0
            h, w = g.observed.shape
            delta[oy : oy + h, ox : ox + w] += g.delta
            seen[oy : oy + h, ox : ox + w] |= g.observed
        return SemanticIncrements(self.resolution, (x0, y0), delta, seen, self.stats + other.stats)

    def to_grid(self, classes: Sequence[str], **grid_kwargs: Any) -> Any:
        """The :class:`~probmap.grid.semantic.SemanticGrid` (``grid_kwargs``: its prior, clamp,
        model, colors): prior plus increments, clamped once per class."""
        from probmap.grid.semantic import SemanticGrid

        ref = SemanticGrid(classes, resolution=self.resolution, **grid_kwargs)
        lo = np.clip(ref.l_prior + self.delta, ref.l_min, ref.l_max)
        return SemanticGrid.from_log_odds(
            classes,
            self.spec,
            lo.astype(np.float32),
            observed=self.observed,
            scans=self.stats.scans,
            **grid_kwargs,
        )


def integrate_semantic_increments(
    scans: Any,
    *,
    resolution: float,
    tile: int = 64,
    start: int = 0,
    stop: int | None = None,
    **grid_kwargs: Any,
) -> SemanticIncrements:
    """Sum the updates of labelled scans ``start:stop`` without prior or clamping.

    Parameters
    ----------
    scans : probmap.grid.semantic_io.LabelledScans
        Poses (S, 3), ranges (S, B), angles, labels (S, B) or probabilities (S, B, K).
    resolution : float
        Cell side in metres.
    tile : int
        The window is aligned to multiples of ``tile`` cells of the common lattice.
    grid_kwargs
        :class:`~probmap.grid.semantic.SemanticGrid` arguments (prior, model; a clamp is
        accepted and ignored here).

    Returns
    -------
    SemanticIncrements
        The updates :meth:`SemanticGrid.integrate_scans` applies (same kernel, same
        once-per-scan rule and endpoint pooling), accumulated in float64 without clamping.
    """
    from probmap.grid import _kernels
    from probmap.grid.semantic import SemanticGrid

    sl = slice(start, stop)
    poses = np.ascontiguousarray(scans.poses[sl], dtype=np.float64)
    ranges = np.ascontiguousarray(scans.ranges[sl], dtype=np.float64)
    angles = np.asarray(scans.angles, dtype=np.float64)
    angles = angles if angles.ndim == 1 else angles[sl]
    kwargs = {k: v for k, v in grid_kwargs.items() if k != "clamp"}
    K = len(scans.classes) - 1
    if poses.shape[0] == 0:
        z = np.zeros((0, 0), dtype=bool)
        return SemanticIncrements(
            float(resolution), (0, 0), np.zeros((0, 0, K)), z, ScanStats(0, 0, 0, 0, 0, 0)
        )
    probe = SemanticGrid(scans.classes, resolution=resolution, **kwargs)
    model = probe.model
    clear = model.max_clear_range
    mr = float(scans.max_range)
    clear_range = effective_clear_range(clear, mr)
    A = np.ascontiguousarray(angles[None, :] if angles.ndim == 1 else angles)
    if not np.isfinite(poses).all():
        raise ValueError("poses must be finite numbers")
    if ranges.ndim != 2 or A.shape[-1] != ranges.shape[1]:
        raise ValueError(f"angles shape {angles.shape} does not match ranges {ranges.shape}")
    box = np.empty(4)
    _kernels.scan_bounds(poses, ranges, A, angles.ndim == 1, mr, clear_range, model.thickness, box)
    res = float(resolution)
    ix0, iy0, ix1, iy1 = _tile_window(box, res, tile)
    spec = GridSpec(res, (ix0 * res, iy0 * res), (iy1 - iy0, ix1 - ix0))
    grid = SemanticGrid(scans.classes, resolution=res, spec=spec, fixed=True, **kwargs)
    # the grid's own validation, evidence and kernel, on float64 zeros with no clamping: the
    # cells then hold the sums of the increments
    grid._lo = np.zeros((*spec.shape, K), dtype=np.float64)
    grid.l_min = np.full(K, -math.inf)
    grid.l_max = np.full(K, math.inf)
    stats = grid.integrate_scans(
        poses,
        ranges,
        angles,
        labels=None if scans.labels is None else scans.labels[sl],
        probabilities=None if scans.probabilities is None else scans.probabilities[sl],
        max_range=mr,
    )
    delta = np.asarray(grid._lo, dtype=np.float64)
    return SemanticIncrements(res, (int(ix0), int(iy0)), delta, grid.observed, stats)
