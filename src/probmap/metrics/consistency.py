"""Self-consistency of a map built from a trajectory: do the robot's visits agree?

A trajectory that is right lays every visit of a place on the same cells. A wrong loop closure
or a fold lays two visits of one place on different cells, or two look-alike places on the
same cells: then walls that one visit saw are crossed by the beams of another. No ground truth
is needed to see that, only the scans and the poses:

1. the scans are cut into *visits*, consecutive stretches of ``visit_length`` metres of travel;
2. each visit gets its own occupancy grid (Table 9.1) at the estimated poses;
3. a cell is *occupied* in a visit when its log odds say so (at least one net hit), *free*
   when at least ``free_hits`` more beams crossed it than ended in it, shrunk by ``margin``
   cells so that a wall seen one cell off is not counted;
4. a visit's *conflict share* is the fraction of its occupied cells that another visit saw
   free, far (``tolerance``) from any wall another visit saw, in stretches at least
   ``min_length`` long. A fold puts walls of one visit in the open space of another. Doors,
   glass, people and loose loops give every log a share too. Measured with the defaults on
   graph SLAM's whole-log results: 0.27 % on Intel, 1.3 % on Freiburg 079 (which folds
   between look-alike offices), 2.3 % on the hospital (loose loops, no fold); 0.07 % and
   0.22 % at the corrected Intel and Freiburg 079 logs' poses; 4.7 % on Intel's first 400 s
   alone (few visits: doors and people weigh more). So the figure is reported
   (``probmap slam grid`` writes it to ``PREFIX.report.json``) and no threshold turns it into
   a verdict yet: it does not tell a fold from an unsteady building.

:func:`map_consistency` returns the figures per visit and in all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import label, maximum_filter

from probmap.grid.occupancy import InverseSensorModel, OccupancyGrid

__all__ = [
    "MapConsistency",
    "VisitConflict",
    "VisitPair",
    "map_consistency",
    "visits_by_travel",
]


@dataclass(frozen=True)
class VisitConflict:
    """One visit: scans ``first .. last`` (inclusive), times ``start .. end`` (seconds); of its
    ``occupied`` cells, ``contradicted`` were seen free by another visit."""

    first: int
    last: int
    start: float
    end: float
    occupied: int
    contradicted: int

    @property
    def share(self) -> float:
        """``contradicted / occupied`` (0 for a visit that saw nothing occupied)."""
        return self.contradicted / self.occupied if self.occupied else 0.0


@dataclass(frozen=True)
class VisitPair:
    """Visit ``wall`` saw ``cells`` of its contradicted walls where visit ``open`` saw open
    space; ``box`` bounds those cells, ``(x_min, y_min, x_max, y_max)`` in metres, map frame."""

    wall: int
    open: int
    cells: int
    box: tuple[float, float, float, float]


@dataclass(frozen=True)
class MapConsistency:
    """The visits of a run and how much they contradict each other; ``pairs`` are the pairs of
    visits where one saw at least ``pair_cells`` of the other's walls as open space (largest
    first)."""

    visits: tuple[VisitConflict, ...]
    resolution: float
    pairs: tuple[VisitPair, ...] = ()

    @property
    def occupied(self) -> int:
        """Occupied cells summed over the visits."""
        return sum(v.occupied for v in self.visits)

    @property
    def share(self) -> float:
        """Contradicted over occupied cells, summed over the visits."""
        occ = self.occupied
        return sum(v.contradicted for v in self.visits) / occ if occ else 0.0

    def worst(self, min_occupied: int = 200) -> VisitConflict | None:
        """The visit with the largest share among those with at least ``min_occupied``
        occupied cells (None when there is none)."""
        big = [v for v in self.visits if v.occupied >= min_occupied]
        return max(big, key=lambda v: v.share) if big else None


def visits_by_travel(poses: ArrayLike, visit_length: float) -> NDArray[np.int64]:
    """Visit index of every pose: ``floor(travel / visit_length)`` with ``travel`` the path
    length (metres) from the first pose, renumbered to consecutive integers."""
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"poses must have shape (S, 3), got {p.shape}")
    if not visit_length > 0:
        raise ValueError(f"visit_length must be > 0 m, got {visit_length}")
    step = np.hypot(np.diff(p[:, 0]), np.diff(p[:, 1]))
    travel = np.concatenate([[0.0], np.cumsum(step)])
    raw = np.floor(travel / visit_length).astype(np.int64)
    return np.unique(raw, return_inverse=True)[1].astype(np.int64)


def _erode(mask: NDArray[np.bool_], margin: int) -> NDArray[np.bool_]:
    if margin <= 0:
        return mask
    from scipy.ndimage import binary_erosion

    return binary_erosion(mask, iterations=margin, border_value=0)


def map_consistency(
    times: ArrayLike,
    poses: ArrayLike,
    ranges: ArrayLike,
    angles: ArrayLike,
    max_range: float,
    *,
    resolution: float = 0.1,
    visit_length: float = 10.0,
    usable_range: float = 20.0,
    free_hits: int = 3,
    margin: int = 1,
    tolerance: float = 0.3,
    min_length: float = 0.5,
    pair_cells: int = 10,
) -> MapConsistency:
    """How much the visits of a trajectory contradict each other (module docstring).

    Parameters
    ----------
    times : array_like, shape (S,)
        Scan times, seconds.
    poses : array_like, shape (S, 3)
        Sensor poses at the scans, map frame (metres, radians): the trajectory to judge.
    ranges : array_like, shape (S, B)
        Ranges, metres (NaN, zero and negative readings are dropped).
    angles : array_like, shape (B,) or (S, B)
        Beam angles in the sensor frame, radians.
    max_range : float
        The sensor's maximum range, metres (readings at or beyond it are no return).
    resolution : float
        Cell side of the visits' grids, metres (coarser than a map: the test is for misplaced
        walls, not for centimetres).
    visit_length : float
        Travel per visit, metres.
    usable_range : float
        Returns beyond this are left out (far returns are the least accurate).
    free_hits : int
        Net beams through a cell (more crossings than endpoints) that make it free.
    margin : int
        Cells by which each visit's free space is shrunk before the comparison.
    tolerance : float
        An occupied cell is not contradicted when another visit saw a wall within this many
        metres of it (a wall seen a little off, or crossed by beams at a grazing angle).
    min_length : float
        Contradicted cells count only in connected groups this long (metres, as cells along
        one side): a misplaced wall is a stretch, a person walking by is a blob.
    pair_cells : int
        Least contradicted cells of one visit inside one other visit's open space for the
        pair to be listed (``MapConsistency.pairs``).

    Returns
    -------
    MapConsistency
    """
    t = np.asarray(times, dtype=np.float64)
    p = np.asarray(poses, dtype=np.float64)
    r = np.asarray(ranges, dtype=np.float64)
    a = np.asarray(angles, dtype=np.float64)
    if p.shape != (len(t), 3) or r.ndim != 2 or len(r) != len(t):
        raise ValueError(
            f"times (S,), poses (S, 3) and ranges (S, B) must agree, got {t.shape}, {p.shape} "
            f"and {r.shape}"
        )
    if not (max_range > 0 and resolution > 0 and usable_range > 0):
        raise ValueError("max_range, resolution and usable_range must be > 0")
    visit = visits_by_travel(p, visit_length)
    with np.errstate(invalid="ignore"):
        r = np.where(r < usable_range, r, max_range)  # far returns: no return (clear only)
    reach = min(usable_range, max_range)
    model = InverseSensorModel(0.7, 0.4, max_clear_range=reach)
    l_free = free_hits * math.log(0.4 / 0.6)  # log odds after free_hits net crossings
    # one lattice through (0, 0) for all visits, covering every pose plus the reach
    lo_xy = np.floor((p[:, :2].min(axis=0) - reach) / resolution).astype(np.int64) - 2
    hi_xy = np.floor((p[:, :2].max(axis=0) + reach) / resolution).astype(np.int64) + 2
    shape = (int(hi_xy[1] - lo_xy[1] + 1), int(hi_xy[0] - lo_xy[0] + 1))
    occ_count = np.zeros(shape, np.int16)  # visits that saw each cell occupied
    free_count = np.zeros(shape, np.int16)  # ... and free
    occupied: list[tuple[NDArray[np.int64], NDArray[np.int64]]] = []
    # each visit's free cells, sorted flat indices (32-bit where they fit: a large building's
    # visits hold millions of them)
    frees: list[NDArray[np.signedinteger]] = []
    index_type = np.int32 if shape[0] * shape[1] < 2**31 else np.int64
    spans: list[tuple[int, int]] = []
    n_visits = int(visit.max()) + 1 if len(visit) else 0
    for v in range(n_visits):
        idx = np.flatnonzero(visit == v)
        grid = OccupancyGrid(resolution, model=model)
        grid.integrate_scans(p[idx], r[idx], a if a.ndim == 1 else a[idx], max_range=max_range)
        lo = grid.log_odds
        ox = round(grid.spec.origin[0] / resolution) - int(lo_xy[0])
        oy = round(grid.spec.origin[1] / resolution) - int(lo_xy[1])
        occ_iy, occ_ix = np.nonzero(lo > 1e-6)
        free_iy, free_ix = np.nonzero(_erode(lo <= l_free + 1e-6, margin))
        gy, gx = occ_iy + oy, occ_ix + ox
        occ_count[gy, gx] += 1
        free_count[free_iy + oy, free_ix + ox] += 1
        flat_free = (free_iy + oy).astype(np.int64) * shape[1] + (free_ix + ox)
        frees.append(np.sort(flat_free.astype(index_type)))
        occupied.append((gy, gx))
        spans.append((int(idx[0]), int(idx[-1])))
    k = max(int(math.ceil(tolerance / resolution)), 0)
    out = []
    walls: list[NDArray[np.int64]] = []  # each visit's contradicted cells, sorted flat indices
    for (first, last), (gy, gx) in zip(spans, occupied, strict=True):
        hit = 0
        flat = np.zeros(0, np.int64)
        if len(gy):
            # the visit's window, widened by the tolerance
            y0, y1 = max(int(gy.min()) - k, 0), min(int(gy.max()) + k + 1, shape[0])
            x0, x1 = max(int(gx.min()) - k, 0), min(int(gx.max()) + k + 1, shape[1])
            own = np.zeros((y1 - y0, x1 - x0), np.int16)
            own[gy - y0, gx - x0] = 1
            others = (occ_count[y0:y1, x0:x1] - own) > 0
            near = maximum_filter(others, size=2 * k + 1) if k else others
            # free in another visit (a cell is never both in one), and no other visit saw a
            # wall within the tolerance (a wall seen a little off, or at a grazing angle)
            bad = (free_count[gy, gx] > 0) & ~near[gy - y0, gx - x0]
            if min_length > 0 and bad.any():
                # only stretches of wall: a person's legs or a chair leg is a cell or two
                mask = np.zeros((y1 - y0, x1 - x0), bool)
                mask[gy[bad] - y0, gx[bad] - x0] = True
                lab, n_lab = label(mask, structure=np.ones((3, 3), bool))
                sizes = np.bincount(lab.ravel(), minlength=n_lab + 1)
                keep = sizes >= max(int(round(min_length / resolution)), 1)
                keep[0] = False
                kept = keep[lab[gy[bad] - y0, gx[bad] - x0]]
                hit = int(kept.sum())
                flat = np.sort(gy[bad][kept] * shape[1] + gx[bad][kept])
            else:
                hit = int(bad.sum())
                flat = np.sort(gy[bad] * shape[1] + gx[bad])
        out.append(VisitConflict(first, last, float(t[first]), float(t[last]), len(gy), hit))
        walls.append(flat)
    pairs = []
    for i, wall in enumerate(walls):
        if len(wall) < pair_cells:
            continue
        for j, free in enumerate(frees):
            if j == i or not len(free):
                continue
            at = np.minimum(np.searchsorted(free, wall), len(free) - 1)
            inside = wall[free[at] == wall]
            if len(inside) < pair_cells:
                continue
            iy, ix = np.divmod(inside, shape[1])
            x = (ix + lo_xy[0]) * resolution
            y = (iy + lo_xy[1]) * resolution
            box = (float(x.min()), float(y.min()), float(x.max() + resolution),
                   float(y.max() + resolution))  # fmt: skip
            pairs.append(VisitPair(i, j, len(inside), box))
    pairs.sort(key=lambda q: -q.cells)
    return MapConsistency(tuple(out), float(resolution), tuple(pairs))
