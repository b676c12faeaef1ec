"""Exact loop-closure scan search: branch and bound over multi-resolution max-grids.

A loop closure asks where, within a window around a guess, a scan fits a finished submap
best. The window is large (metres, tens of degrees), so scoring every pose of it, as the
correlative search of :mod:`probmap.slam.laser.scan_matching` does for small windows, is too slow.
Branch and bound finds the *same* best pose (Olson, "Real-time correlative scan matching",
ICRA 2009, its multi-resolution search; Hess, Kohler, Rapp and Andor, "Real-Time Loop Closure
in 2D LIDAR SLAM", ICRA 2016, sec. V):

1. once per submap, :class:`PrecomputedGrids` stores for every depth ``h`` a *max-grid* whose
   cell ``(ix, iy)`` holds the maximum of the match field over the ``2^h x 2^h`` cells starting
   there, so one look-up per point bounds the score of ``4^h`` translations at once;
2. :func:`branch_and_bound_search` scores the coarsest nodes of every heading, then descends
   depth first, best child first, pruning every node whose bound cannot beat the best pose
   found so far;
3. :func:`match_loop_closure` refines the found pose by Gauss-Newton
   (:func:`~probmap.slam.laser.scan_matching.refine`).

The discrete window
-------------------
Around the centre pose ``(x_c, y_c, theta_c)`` the candidates are ``(x_c + kx r, y_c + ky r,
theta_c + ka delta)`` with ``r`` the cell side, integers ``|kx|, |ky| <= floor(W_lin / r)`` and
``|ka| <= floor(W_ang / delta)``. A candidate's score is the mean over the N points of the
field at the cells holding them (nearest cell, 0 outside the grid), with the points' cells
found once per heading from the centre and shifted by whole cells: point ``i`` lies in cell
``floor((x_c + R(theta) p_i - origin) / r) + (kx, ky)``. This is the score of
:func:`~probmap.slam.laser.scan_matching.score_scan` divided by N, up to floating-point rounding for
points lying exactly on a cell edge. :func:`brute_force_search` scores every candidate on the
same lattice; both return the highest score and, among equal scores, the candidate with the
smallest ``(ka, kx, ky)`` (heading, then x, then y, each from the most negative offset, the
order of :func:`~probmap.slam.laser.scan_matching.correlative_search`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.geometry.se2 import wrap_angle
from probmap.slam.laser.scan_matching import MatchField, normal_equations, refine

__all__ = [
    "LoopClosureMatch",
    "PrecomputedGrids",
    "SearchResult",
    "branch_and_bound_search",
    "brute_force_search",
    "default_angular_step",
    "match_loop_closure",
]

_TABLE = np.arange(256, dtype=np.float64) / 255.0  # value of each uint8 code; _TABLE[255] == 1


class PrecomputedGrids:
    """The max-grids of one finished submap's match field (built once, then read only).

    Parameters
    ----------
    values : array_like, shape (H, W)
        Match field ``values[iy, ix]`` in [0, 1] at the cell centres (float64; used without a
        copy when already C-contiguous float64).
    origin : tuple of float
        World position (metres, submap frame) of the lower-left corner of cell (0, 0).
    resolution : float
        Cell side, metres.
    depth : int, default 6
        Number of levels: depth 0 is the field itself, depth ``h`` (``1 <= h < depth``) bounds
        blocks of ``2^h x 2^h`` cells. The default's coarsest blocks are 32 cells (1.6 m at
        0.05 m), about the scale of indoor structure; Hess et al. (2016) use 7, which measured
        up to 3x slower on a simulated building (``benchmarks/bench_loop_closure.py``): 3.2 m
        blocks hold a wall almost everywhere, so their bounds prune little.

    Notes
    -----
    Level ``h`` covers the blocks starting at cells ``-(2^h - 1) .. W - 1`` (and likewise in y),
    the blocks that overlap the grid; the field counts 0 outside the grid. Each level is
    computed from the previous one with two maxima per cell (a sliding-window maximum by
    doubling), O(cells) per level.

    Memory: levels ``1 .. depth - 1`` are stored as one byte per cell (Cartographer stores its
    precomputation grids the same way), the value of code ``c`` being ``c / 255``, rounded *up*
    from the true maximum so that every level stays an upper bound and the search stays exact;
    the bounds are at most 1/255 looser than with floats. Level 0 is ``values`` itself. A
    400 x 400 field with the default depth takes 0.85 MB besides the field (float32 levels
    would take 3.4 MB).

    Examples
    --------
    >>> import numpy as np
    >>> g = PrecomputedGrids(np.eye(4), (0.0, 0.0), 0.5, depth=2)
    >>> g.max_grid(1)[1:, 1:]  # block of 2 x 2 cells starting at each cell
    array([[1., 1., 0., 0.],
           [1., 1., 1., 0.],
           [0., 1., 1., 1.],
           [0., 0., 1., 1.]])
    """

    __slots__ = ("values", "origin", "resolution", "depth", "_buf", "_levels")

    values: NDArray[np.float64]
    origin: tuple[float, float]
    resolution: float
    depth: int
    _buf: NDArray[np.uint8]  # levels 1 .. depth - 1, flat
    _levels: NDArray[np.int64]  # (depth, 4): offset in _buf, rows, columns, pad of each level

    def __init__(
        self,
        values: ArrayLike,
        origin: tuple[float, float],
        resolution: float,
        depth: int = 6,
    ) -> None:
        from probmap.slam.laser import _bnb_kernels as K

        v = np.ascontiguousarray(values, dtype=np.float64)
        if v.ndim != 2 or v.shape[0] < 1 or v.shape[1] < 1:
            raise ValueError(f"values must be a non-empty 2-D array, got shape {v.shape}")
        if not np.isfinite(v).all() or v.min() < 0.0 or v.max() > 1.0:
            raise ValueError("values must be finite and in [0, 1]")
        ox, oy = (float(c) for c in origin)
        if not (math.isfinite(ox) and math.isfinite(oy)):
            raise ValueError(f"origin must be two finite numbers, got {origin!r}")
        res = float(resolution)
        if not (math.isfinite(res) and res > 0):
            raise ValueError(f"resolution must be > 0 m, got {resolution}")
        if isinstance(depth, bool) or not isinstance(depth, (int, np.integer)):
            raise TypeError(f"depth must be an integer, got {depth!r}")
        if not 1 <= int(depth) <= 16:
            raise ValueError(f"depth must be in 1 .. 16, got {depth}")
        depth = int(depth)
        h, w = v.shape
        pads = np.array([(1 << k) - 1 for k in range(depth)], dtype=np.int64)
        sizes = (h + pads) * (w + pads)
        sizes[0] = 0  # level 0 is the field itself
        offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        levels = np.ascontiguousarray(np.column_stack([offsets, h + pads, w + pads, pads]))
        levels = levels.astype(np.int64)
        buf = np.zeros(int(sizes.sum()), dtype=np.uint8)
        if depth > 1:
            codes0 = np.empty((h, w), dtype=np.uint8)
            K.quantize_up(v, _TABLE, codes0)
            tmp = np.empty(int((h + pads[depth - 2]) * (w + pads[depth - 1])), dtype=np.uint8)
            K.max_grids(codes0.reshape(-1), h, w, depth, buf, levels, tmp)
        if v is not values:  # our own copy: nobody may change it under the max-grids
            v.setflags(write=False)
        for name, val in (
            ("values", v), ("origin", (ox, oy)), ("resolution", res), ("depth", depth),
            ("_buf", buf), ("_levels", levels),
        ):  # fmt: skip
            object.__setattr__(self, name, val)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError("PrecomputedGrids is read-only")

    @classmethod
    def from_field(cls, field: MatchField, depth: int = 6) -> PrecomputedGrids:
        """The max-grids of a :class:`~probmap.slam.laser.scan_matching.MatchField` (shares its
        values)."""
        if not isinstance(field, MatchField):
            raise TypeError(f"field must be a MatchField, got {type(field).__name__}")
        return cls(field.values, field.origin, field.resolution, depth)

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the field."""
        return (int(self.values.shape[0]), int(self.values.shape[1]))

    @property
    def nbytes(self) -> int:
        """Bytes held by the max-grids of depth >= 1 (the field itself not counted)."""
        return int(self._buf.nbytes)

    def max_grid(self, h: int) -> NDArray[np.float64]:
        """The max-grid of depth ``h`` as float64, shape ``(H + 2^h - 1, W + 2^h - 1)``.

        Element ``[iy + 2^h - 1, ix + 2^h - 1]`` bounds the field over the cells ``[ix, ix +
        2^h) x [iy, iy + 2^h)`` (``-(2^h - 1) <= ix < W``); depth 0 returns the field.
        """
        if not 0 <= h < self.depth:
            raise ValueError(f"h must be in 0 .. {self.depth - 1}, got {h}")
        if h == 0:
            return self.values.copy()
        off, hh, ww, _ = (int(c) for c in self._levels[h])
        return _TABLE[self._buf[off : off + hh * ww].reshape(hh, ww)]


@dataclass(frozen=True)
class SearchResult:
    """The best candidate of a loop-closure search window.

    Attributes
    ----------
    pose : ndarray, shape (3,)
        Best sensor pose ``(x, y, theta)`` in the grid's frame (metres, radians, theta wrapped
        to [-pi, pi)).
    score : float
        Its score: mean field value at the points' cells, in [0, 1].
    angular_step : float
        Heading step of the window, radians (the default rule's value when none was given).
    candidates : int
        Poses in the discrete window.
    evaluated : int
        Scorings made (search-tree nodes and candidates); ``candidates`` for brute force.
    """

    pose: NDArray[np.float64]
    score: float
    angular_step: float
    candidates: int
    evaluated: int


def default_angular_step(points: ArrayLike, resolution: float) -> float:
    """Heading step that moves the farthest point by at most one cell (Hess et al. 2016, eq. 7).

    ``delta = acos(1 - r^2 / (2 d_max^2))`` with ``r`` the cell side (metres) and ``d_max`` the
    largest range of ``points`` (N, 2) in the sensor frame; radians.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] == 0:
        raise ValueError(f"points must have shape (N, 2) with N >= 1, got {pts.shape}")
    d_max = float(np.sqrt((pts**2).sum(axis=1)).max())
    if not d_max > 0:
        raise ValueError("the points all lie at the sensor origin: give angular_step")
    return math.acos(max(1.0 - resolution**2 / (2.0 * d_max**2), -1.0))


def _window(
    grids: PrecomputedGrids,
    points: ArrayLike,
    center: ArrayLike,
    linear_window: float,
    angular_window: float,
    angular_step: float | None,
    min_score: float,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray, int, int, float]:
    """The window both searches scan, from their checked inputs: the points' cells per heading
    ``cx, cy`` (2 na + 1, N), the centre (3,), ``nl``, ``na`` and the heading step."""
    if not isinstance(grids, PrecomputedGrids):
        raise TypeError(f"grids must be PrecomputedGrids, got {type(grids).__name__}")
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] == 0:
        raise ValueError(f"points must have shape (N, 2) with N >= 1, got {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("points must be finite")
    c = np.asarray(center, dtype=np.float64)
    if c.shape != (3,) or not np.isfinite(c).all():
        raise ValueError(f"center must be 3 finite numbers (x, y, theta), got {c.tolist()}")
    lw = float(linear_window)
    aw = float(angular_window)
    if not (math.isfinite(lw) and lw >= 0):
        raise ValueError(f"linear_window must be >= 0 m, got {linear_window}")
    if not (math.isfinite(aw) and 0 <= aw <= math.pi + 1e-9):
        raise ValueError(f"angular_window must be in [0, pi] rad, got {angular_window}")
    if not (math.isfinite(float(min_score))):
        raise ValueError(f"min_score must be a finite number, got {min_score}")
    if angular_step is None:
        if aw > 0 or np.any(pts != 0.0):
            step = default_angular_step(pts, grids.resolution)
        else:  # no rotation searched and none matters
            step = math.pi
    else:
        step = float(angular_step)
        if not (math.isfinite(step) and step > 0):
            raise ValueError(f"angular_step must be > 0 rad, got {angular_step}")
    res = grids.resolution
    nl = int(math.floor(lw / res + 1e-9))
    na = int(math.floor(aw / step + 1e-9))
    # a guard against a window that would not fit in memory or time by mistake
    if (2 * na + 1) * pts.shape[0] > 50_000_000:
        raise ValueError(
            f"the window has {2 * na + 1} headings for {pts.shape[0]} points: too many, "
            "give a larger angular_step"
        )
    cx, cy = _cell_tables(grids, pts, c, na, step)
    return cx, cy, c, nl, na, step


def _cell_tables(
    grids: PrecomputedGrids, pts: NDArray, c: NDArray, na: int, step: float
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    from probmap.slam.laser import _bnb_kernels as K

    n_angles = 2 * na + 1
    cx = np.empty((n_angles, pts.shape[0]), dtype=np.int64)
    cy = np.empty_like(cx)
    ox, oy = grids.origin
    K.cell_tables(pts, c[0], c[1], c[2], step, n_angles, ox, oy, grids.resolution, cx, cy)
    return cx, cy


def _result(
    out: NDArray, c: NDArray, res: float, na: int, nl: int, step: float
) -> SearchResult | None:
    if out[0] == 0.0:
        return None
    ka = int(out[1]) - na
    pose = np.array(
        [c[0] + int(out[2]) * res, c[1] + int(out[3]) * res, float(wrap_angle(c[2] + ka * step))]
    )
    n = (2 * nl + 1) ** 2 * (2 * na + 1)
    return SearchResult(pose, float(out[4]), step, n, int(out[5]))


def branch_and_bound_search(
    grids: PrecomputedGrids,
    points: ArrayLike,
    center: ArrayLike,
    linear_window: float,
    angular_window: float,
    angular_step: float | None = None,
    min_score: float = 0.0,
) -> SearchResult | None:
    """Best pose of the scan in the window around ``center``: exact, by branch and bound.

    Parameters
    ----------
    grids : PrecomputedGrids
        Max-grids of the submap's match field.
    points : array_like, shape (N, 2)
        Scan endpoints in the sensor frame, metres (N >= 1).
    center : array_like, shape (3,)
        Centre of the window: a guess of the sensor pose ``(x, y, theta)`` in the grid's frame
        (metres, radians).
    linear_window : float
        Half-width of the window in x and in y, metres: offsets of whole cells up to it.
    angular_window : float
        Half-width of the window in heading, radians, in [0, pi].
    angular_step : float, optional
        Heading step, radians; default :func:`default_angular_step` (the farthest point moves
        at most one cell per step).
    min_score : float, default 0
        Least score (mean field value, [0, 1]) of an acceptable pose; the search prunes below
        it, so a high threshold also makes it faster.

    Returns
    -------
    SearchResult or None
        The candidate of the highest score (ties: the smallest ``(ka, kx, ky)``, see the module
        notes), the same as :func:`brute_force_search` returns; None when no candidate scores
        ``min_score`` or more.

    Raises
    ------
    ValueError
        Bad shapes, non-finite inputs, negative windows or steps.
    TypeError
        If ``grids`` is not :class:`PrecomputedGrids`.

    Notes
    -----
    Hess et al. (2016), sec. V (depth-first search, bounds of sec. V-C): the roots are the
    nodes of every heading at the coarsest depth whose blocks tile the window at least twice
    per axis (at most ``grids.depth - 1``), scored and sorted once (with ``min_score > 0``,
    headings in groups as wide as a root's block first get one bound per group from the
    neighbouring blocks, so most roots of a wide window are ruled out without being scored
    one by one); the depth-first search then expands the best child first, so a good pose is
    found early and most of the window is pruned at coarse depths. The points are rotated once per heading; memory is
    O(headings x points + roots).
    """
    from probmap.slam.laser import _bnb_kernels as K

    cx, cy, c, nl, na, step = _window(
        grids, points, center, linear_window, angular_window, angular_step, min_score
    )
    # start where the window holds at least two blocks per axis: a coarser start sorts its
    # roots on loose bounds, so the depth-first descent meets a good pose late
    top = max(0, min(grids.depth - 1, nl.bit_length() - 1))
    out = np.zeros(6)
    K.branch_and_bound(
        grids.values, grids._buf, grids._levels, _TABLE, cx, cy, nl, top, float(min_score), out
    )
    return _result(out, c, grids.resolution, na, nl, step)


# The parameters of branch_and_bound_search, on purpose: the reference takes what it checks.
def brute_force_search(
    grids: PrecomputedGrids,
    points: ArrayLike,
    center: ArrayLike,
    linear_window: float,
    angular_window: float,
    angular_step: float | None = None,
    min_score: float = 0.0,
) -> SearchResult | None:
    """Best pose of the scan in the window by scoring every candidate (the reference).

    The same window, score and tie rule as :func:`branch_and_bound_search`, whose parameters
    and result it shares; it costs ``(2 nl + 1)^2 (2 na + 1) N`` look-ups, so it serves tests,
    benchmarks and small windows.
    """
    from probmap.slam.laser import _bnb_kernels as K

    cx, cy, c, nl, na, step = _window(
        grids, points, center, linear_window, angular_window, angular_step, min_score
    )
    out = np.zeros(6)
    K.brute_force(grids.values, cx, cy, nl, float(min_score), out)
    return _result(out, c, grids.resolution, na, nl, step)


@dataclass(frozen=True)
class LoopClosureMatch:
    """A loop-closure match: the branch-and-bound pose refined by Gauss-Newton.

    Attributes
    ----------
    pose : ndarray, shape (3,)
        Refined sensor pose ``(x, y, theta)`` in the grid's frame (metres, radians).
    covariance : ndarray, shape (3, 3)
        Its covariance from the final normal equations (m^2, m rad, rad^2).
    search_score : float
        Branch-and-bound score (nearest cell) of the pose before refinement.
    score : float
        Mean bilinear field value of the points at ``pose``.
    search : SearchResult
        The search's result.
    iterations : int
        Gauss-Newton iterations taken.
    """

    pose: NDArray[np.float64]
    covariance: NDArray[np.float64]
    search_score: float
    score: float
    search: SearchResult
    iterations: int


def match_loop_closure(
    grids: PrecomputedGrids,
    field: MatchField,
    points: ArrayLike,
    center: ArrayLike,
    linear_window: float,
    angular_window: float,
    angular_step: float | None = None,
    min_score: float = 0.0,
    iterations: int = 10,
    max_step: tuple[float, float] | None = None,
) -> LoopClosureMatch | None:
    """Branch-and-bound search, then Gauss-Newton refinement on ``field``.

    Parameters
    ----------
    grids : PrecomputedGrids
        Max-grids of ``field`` (:meth:`PrecomputedGrids.from_field`).
    field : MatchField
        The submap's match field, refined on with :func:`~probmap.slam.laser.scan_matching.refine`.
    points, center, linear_window, angular_window, angular_step, min_score
        As in :func:`branch_and_bound_search`.
    iterations : int, default 10
        Most Gauss-Newton iterations.
    max_step : tuple of float, optional
        Longest Gauss-Newton step ``(metres, radians)``; default one cell and one heading step
        of the search, the distance to the continuous optimum from the search's pose.

    Returns
    -------
    LoopClosureMatch or None
        None when the search finds nothing scoring ``min_score`` or more.
    """
    if not isinstance(field, MatchField):
        raise TypeError(f"field must be a MatchField, got {type(field).__name__}")
    found = branch_and_bound_search(
        grids, points, center, linear_window, angular_window, angular_step, min_score
    )
    if found is None:
        return None
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if max_step is None:
        max_step = (grids.resolution, found.angular_step)
    pose, cov, it = refine(field, pts, found.pose, iterations, max_step)
    total, _, _ = normal_equations(field, pts, pose)
    return LoopClosureMatch(pose, cov, found.score, total / pts.shape[0], found, it)
