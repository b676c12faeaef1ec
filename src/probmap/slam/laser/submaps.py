"""Submaps for graph SLAM: small occupancy grids of a bounded number of consecutive scans.

A submap is an :class:`~probmap.grid.occupancy.OccupancyGrid` (the once-per-scan kernel of
Table 9.1) expressed in the frame of its *anchor*, the first pose-graph node inserted into it.
The graph-SLAM front end keeps two submaps active at a time, each new node inserted into both,
and starts a new one every ``scans / 2`` nodes, so consecutive submaps overlap by half (Hess et
al., "Real-Time Loop Closure in 2D LIDAR SLAM", ICRA 2016, sec. IV). A submap that holds
``scans`` nodes is *finished*: it never changes again, and keeps only what loop closure needs,
the cells it found occupied, from which its match field (:class:`~probmap.slam.laser.scan_matching.
MatchField`) and the branch-and-bound max-grids are rebuilt on demand (a few megabytes each
instead of the whole grid for every submap of a long log).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.grid.occupancy import InverseSensorModel, OccupancyGrid
from probmap.grid.spec import GridSpec
from probmap.slam.laser.scan_matching import MatchField

__all__ = ["Submap", "match_field_from_occupied_cells"]


def match_field_from_occupied_cells(
    cells: NDArray[np.int64], spec: GridSpec, sigma: float, radius: int
) -> MatchField:
    """The match field ``exp(-d^2 / 2 sigma^2)`` (0 beyond ``radius`` cells) of a grid laid out
    by ``spec`` whose occupied cells are ``cells`` (K,) flat indices ``iy * W + ix``."""
    from probmap.slam.laser import _match_kernels as K

    h, w = spec.shape
    lo = np.zeros((h, w), dtype=np.float32)
    lo.reshape(-1)[cells] = 1.0
    values = np.empty((h, w))
    inv = 0.5 * (spec.resolution / sigma) ** 2
    K.splat_field(lo, 0.0, int(radius), inv, values)
    return MatchField(values, spec.origin, spec.resolution)


class Submap:
    """One submap: a grid in its anchor node's frame and the nodes inserted into it.

    Parameters
    ----------
    index : int
        Submap number (0, 1, ...).
    anchor : int
        Pose-graph node whose frame is the submap frame.
    resolution : float
        Cell side, metres.
    sigma : float
        Width of the match field, metres.
    field_radius : int
        Cells beyond which the match field is 0.
    model : InverseSensorModel
        Inverse sensor model of the grid.
    """

    def __init__(
        self,
        index: int,
        anchor: int,
        resolution: float,
        sigma: float,
        field_radius: int,
        model: InverseSensorModel,
    ) -> None:
        self.index = int(index)
        self.anchor = int(anchor)
        self.sigma = float(sigma)
        self.field_radius = int(field_radius)
        self.grid: OccupancyGrid | None = OccupancyGrid(resolution, model=model)
        self.nodes: list[int] = []
        self.finished = False
        self._field: MatchField | None = None
        self._spec: GridSpec | None = None
        self._cells: NDArray[np.int64] | None = None
        self._points_sum = np.zeros(2)
        self._since_refresh = 0
        self._positions: list[NDArray[np.float64]] = []
        self.radius = 0.0  # largest distance (m) of an inserted pose from the centre

    #: inserts between full recomputations of an active submap's field (cells freed since the
    #: last one keep their old field values until then)
    refresh_every = 10

    def insert(
        self, node: int, pose: ArrayLike, ranges: ArrayLike, angles: ArrayLike, max_range: float
    ) -> None:
        """Integrate a scan taken at ``pose`` (sensor pose in the submap frame).

        The match field, once built, is kept up to date incrementally: the cells that the scan
        made occupied splat their kernel onto it (cost ~ beams x kernel), and every
        ``refresh_every`` inserts it is recomputed whole, which also clears cells freed since.
        """
        if self.finished or self.grid is None:
            raise RuntimeError(f"submap {self.index} is finished")
        p = np.asarray(pose, dtype=np.float64)
        r = np.asarray(ranges, dtype=np.float64)
        a = np.asarray(angles, dtype=np.float64)
        grid = self.grid
        spec0 = grid.spec
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(r) & (r > 0) & (r < max_range)
        ex = p[0] + r[ok] * np.cos(a[ok] + p[2])
        ey = p[1] + r[ok] * np.sin(a[ok] + p[2])
        grid.integrate_scan(p, r, a, max_range=max_range)
        self.nodes.append(int(node))
        self._points_sum += p[:2]
        self._positions.append(p[:2].copy())
        self._since_refresh += 1
        if self._field is None:
            return
        if grid.spec != spec0 or self._since_refresh >= self.refresh_every:
            self._field = None  # grown, or time for a full recomputation
            return
        from probmap.slam.laser import _match_kernels as K

        res = spec0.resolution
        ix = np.floor((ex - spec0.origin[0]) / res).astype(np.int64)
        iy = np.floor((ey - spec0.origin[1]) / res).astype(np.int64)
        # the integration kernel rounds endpoints with its own arithmetic: an endpoint on a
        # cell boundary may be in the neighbouring cell there, so take the 3 x 3 block
        # (re-splatting an occupied cell changes nothing under the max rule)
        ix = (ix[:, None] + np.array([-1, 0, 1, -1, 0, 1, -1, 0, 1])).ravel()
        iy = (iy[:, None] + np.array([-1, -1, -1, 0, 0, 0, 1, 1, 1])).ravel()
        inside = (ix >= 0) & (ix < spec0.width) & (iy >= 0) & (iy < spec0.height)
        ix, iy = ix[inside], iy[inside]
        occ = grid.log_odds[iy, ix] > 0
        inv = 0.5 * (res / self.sigma) ** 2
        K.splat_cells(
            np.ascontiguousarray(iy[occ]), np.ascontiguousarray(ix[occ]), self.field_radius, inv,
            self._field.values,
        )  # fmt: skip

    @property
    def size(self) -> int:
        """Nodes inserted."""
        return len(self.nodes)

    @property
    def centre(self) -> NDArray[np.float64]:
        """Mean position of the inserted sensor poses, submap frame (metres)."""
        return self._points_sum / max(len(self.nodes), 1)

    def field(self) -> MatchField:
        """The submap's match field (cached until the next insertion)."""
        if self._field is not None:
            return self._field
        if self.finished:
            assert self._spec is not None and self._cells is not None
            self._field = match_field_from_occupied_cells(
                self._cells, self._spec, self.sigma, self.field_radius
            )
            return self._field
        assert self.grid is not None
        from probmap.slam.laser import _match_kernels as K

        lo = self.grid.log_odds
        values = np.empty(lo.shape)
        inv = 0.5 * (self.grid.spec.resolution / self.sigma) ** 2
        K.splat_field(lo, 0.0, self.field_radius, inv, values)
        self._field = MatchField(values, self.grid.spec.origin, self.grid.spec.resolution)
        self._since_refresh = 0
        return self._field

    def finish(self) -> None:
        """Freeze the submap: keep its occupied cells (cropped) and drop the grid."""
        if self.finished:
            return
        assert self.grid is not None
        g = self.grid.cropped(margin=self.field_radius + 2)
        occ = g.log_odds > 0
        self._spec = g.spec
        self._cells = np.flatnonzero(occ).astype(np.int64)
        self.radius = float(np.max(np.hypot(*(np.asarray(self._positions) - self.centre).T)))
        self.grid = None
        self._field = None
        self.finished = True

    @property
    def cell_spec(self) -> GridSpec:
        """Layout of a finished submap's cropped grid (submap frame)."""
        if self._spec is None:
            raise RuntimeError(f"submap {self.index} is not finished")
        return self._spec

    def occupied_centres(self) -> NDArray[np.float64]:
        """Centres (K, 2) of a finished submap's occupied cells, submap frame (metres)."""
        spec = self.cell_spec
        assert self._cells is not None
        iy, ix = np.divmod(self._cells, spec.shape[1])
        ox, oy = spec.origin
        r = spec.resolution
        return np.column_stack((ox + (ix + 0.5) * r, oy + (iy + 0.5) * r))

    def release(self) -> None:
        """Drop the cached field of a finished submap (it is rebuilt on demand)."""
        if self.finished:
            self._field = None

    @property
    def nbytes(self) -> int:
        """Bytes held (grid or occupied cells, and the cached field)."""
        n = 0
        if self.grid is not None:
            n += self.grid.log_odds.nbytes + self.grid.spec.height * self.grid.spec.width
        if self._cells is not None:
            n += self._cells.nbytes
        if self._field is not None:
            n += self._field.values.nbytes
        return n

    def occupied_points(self) -> NDArray[np.float64]:
        """Centres (N, 2) of the occupied cells in the submap frame (metres): of the frozen
        cells once finished, of the cells with positive log odds while active."""
        if self.finished:
            assert self._spec is not None and self._cells is not None
            spec, cells = self._spec, self._cells
        else:
            assert self.grid is not None
            spec = self.grid.spec
            cells = np.flatnonzero(self.grid.log_odds > 0)
        rows, cols = np.divmod(cells, spec.width)
        r = spec.resolution
        return np.column_stack(
            [spec.origin[0] + (cols + 0.5) * r, spec.origin[1] + (rows + 0.5) * r]
        )

    def occupied_cells(self) -> int:
        """Occupied cells of a finished submap (0 before)."""
        return 0 if self._cells is None else int(self._cells.size)

    def __repr__(self) -> str:
        state = "finished" if self.finished else "active"
        return f"Submap({self.index}, anchor={self.anchor}, nodes={self.size}, {state})"


def angular_search_step(resolution: float, max_range: float) -> float:
    """Angle step (radians) at which the farthest endpoint moves about one cell (Hess et al.
    2016, eq. 7)."""
    d = max(float(max_range), resolution)
    return math.acos(max(-1.0, 1.0 - resolution**2 / (2.0 * d * d)))
