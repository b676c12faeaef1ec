"""Loop closures of submap graph SLAM: where to search, how a match is verified, and when it
joins the pose graph (Hess et al., "Real-Time Loop Closure in 2D LIDAR SLAM", ICRA 2016, for the
search; the consensus and drift rules are probmap's).

Per node (:meth:`LoopClosing.search`), the node's scan is searched against the finished submaps
near its current estimate, each within a window that grows with the travel between the node and
the submap along the shortest chain of local-SLAM links and accepted closures. The search is
exact over the window (branch and bound over multi-resolution max-grids,
:mod:`probmap.slam.laser.loop_closure`) and refined by Gauss-Newton.

- A *near* match (small window) scoring at least ``min_score`` is added as an edge under the
  robust cost, so that a wrong one is down-weighted instead of bending the map.
- A *far* match (wide window) must be **verified**: earlier nodes, moved by the correction it
  implies, must match the same part of the map within a small window (``consensus``). A
  low-scoring far match is believed only for a correction a plausible drift explains
  (``trust_drift``). The confirmed closures act quadratically for one optimization, and stay
  quadratic afterwards when the correction is within that drift, robust otherwise.

The class holds the submap graph (travel between submaps), the finished submaps that are
candidates, their cached match fields and max-grids, and every count the summary reports. It
reads the pose graph, the submaps and the nodes' travel of :class:`~probmap.slam.laser.
submap_slam.SubmapSlam`, which owns them, and adds closure edges to the pose graph.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from probmap._checks import require_at_least, require_nonnegative_finite, require_positive_finite
from probmap.geometry.se2 import between, compose, inverse, wrap_angle
from probmap.slam.laser.scan_matching import MatcherConfig, normal_equations, refine
from probmap.slam.laser.submaps import Submap

__all__ = ["ClosureConfig", "LoopClosing", "LoopClosure", "edge_information", "require_pair"]


def edge_information(sd: tuple[float, float]) -> NDArray[np.float64]:
    """Information matrix (3, 3) of an SE(2) edge with standard deviations ``(metres,
    radians)``, the same in x and y."""
    return np.diag([1.0 / sd[0] ** 2, 1.0 / sd[0] ** 2, 1.0 / sd[1] ** 2])


def require_pair(name: str, value: Any, *, positive: bool) -> None:
    """Raise unless ``value`` is a tuple of two finite numbers, each > 0 (``positive``) or
    >= 0: the ``(metres, radians)`` pairs of the submap SLAM configuration."""
    if (
        not isinstance(value, tuple)
        or len(value) != 2
        or not all(math.isfinite(x) and (x > 0 if positive else x >= 0) for x in value)
    ):
        kind = "two positive numbers" if positive else "two numbers >= 0"
        raise ValueError(f"{name} must be {kind}, got {value}")


def _loop_errors(
    la: NDArray[np.float64],
    lk: NDArray[np.float64],
    zc: NDArray[np.float64],
    da: NDArray[np.float64],
    dk: NDArray[np.float64],
    z: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Errors (m, 3) of the loops a closure ``zc`` (its node's pose in its anchor's frame; the
    local poses of both ``la``, ``lk``, each (3,)) closes with each of ``m`` others (``z``,
    their anchors' and nodes' local poses ``da``, ``dk``, each (m, 3)):
    ``zc^-1 (la^-1 da) z (dk^-1 lk)``, the SE(2) algebra of :mod:`probmap.geometry.se2`
    written out for the closure search's inner loop."""

    def rel(p: NDArray, q: NDArray) -> tuple[NDArray, NDArray, NDArray]:  # p^-1 q
        c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
        dx, dy = q[..., 0] - p[..., 0], q[..., 1] - p[..., 1]
        return c * dx + s * dy, -s * dx + c * dy, q[..., 2] - p[..., 2]

    def comp(a: tuple, b: tuple) -> tuple[NDArray, NDArray, NDArray]:  # a b
        c, s = np.cos(a[2]), np.sin(a[2])
        return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]

    via = comp(comp(rel(la, da), (z[:, 0], z[:, 1], z[:, 2])), rel(dk, lk))
    ex, ey, et = rel(zc, np.stack(via, axis=1))
    return np.stack([ex, ey, np.arctan2(np.sin(et), np.cos(et))], axis=1)


@dataclass(frozen=True)
class ClosureConfig:
    """Loop-closure search and verification of :class:`~probmap.slam.laser.submap_slam.
    SubmapSlam` (the ``closures`` section of its configuration).

    Parameters
    ----------
    sd : tuple of float
        Standard deviations ``(metres, radians)`` of a loop-closure edge.
    min_score : float
        Least branch-and-bound score (mean match field over the scan's endpoints) of a closure.
    wide_min_score : float
        Least score of a closure searched in a window wider than ``near_window``.
    window : tuple of float
        ``(metres, radians)``: half-widths of the search window against a submap the node is
        tied to by local SLAM or a closure (no accumulated travel between them).
    window_growth : tuple of float
        Growth of those half-widths per metre of travel between the node and the submap along
        the shortest chain of local-SLAM links and accepted closures (the uncertainty the
        odometry and scan matching accumulate). Near searches count a closure as no travel
        between its submap and the node's; far searches and the trust bound count the
        closure's distance from its submap's anchor too, because a chain of closures each
        against the submap just behind it (local SLAM handing the robot from one submap to
        the next) is no shortcut: drift grows along it as it does along the trajectory.
    max_window : tuple of float
        Largest half-widths of that window. 25 m is reached after 163 m of travel; a cap of
        20 m left the hospital log at every second scan unjoined after a 10 degree drift
        (1.45 m instead of 0.15), and 30 m gave no more on the hospital's or the campus's
        perturbed copies (BENCHMARKS.md).
    wide_window : tuple of float
        Half-widths of the periodic wide search (at least the submap's own window).
    wide_search_every : int
        Nodes between wide searches (0 = never).
    near_window : float
        Windows up to this half-width (metres) are *near* searches: run for up to
        ``candidates`` submaps per node and accepted on their score alone. Wider
        (*far*) searches run for one submap every ``far_every`` nodes (the one searched least
        recently) and must be confirmed by consensus.
    far_every : int
        Nodes between far searches (their windows reach ``max_window`` after a long stretch
        without a loop, so each is a costly search; 4 keeps every log at 40x real time or
        more).
    far_neighbours : int
        A far search, and the consensus checks of what it finds, match the node against its
        submap merged with up to this many finished submaps before and after it (the same
        pass, placed in the submap's frame by the current estimate). A robot that comes back
        the other way sees, from one place, what the first pass saw from several: with a 180
        degree laser it looks at what the first pass had behind it. On the hospital's last
        stretch (4,600-4,702 s, driven west along the corridor the first pass drove east) the
        best single first-pass submap scores 0.33-0.52 at the estimate, the first pass's 12
        submaps merged 0.56-0.68 (one-off script). With 1, the hospital's copy with odometry
        5 % too long goes from 0.378 to 0.123 m and the Freiburg campus from 0.159 to 0.105 m
        (loop relations 0.355 to 0.193 m); the searches cost more (the campus's SLAM 1.4 times
        as long, peak memory +16 MiB). Only the newest merged submap is cached. 2 gave the
        hospital as logged a wrong closure (0.237 m) when the consensus checks still matched
        single submaps. Near searches match single submaps. 0 merges none.
    consensus : tuple of float
        ``(metres, radians)``: a far closure is accepted once ``consensus_checks`` earlier
        nodes, moved by the correction it implies (the rigid motion from the current estimate
        to the closure's pose), match the same submap or its neighbours within this window
        (the submap merged with them, as the far search matched it, when ``far_neighbours``).
    consensus_nodes : int
        The earlier nodes checked lie up to this many nodes back.
    consensus_checks : int
        Confirmations a far closure needs. 3 since far matches down to ``drift_min_score``
        count: a weaker match needs more evidence. With 2 the hospital's last loop stayed
        open (0.215 m against 0.118 m); Intel scores 0.0180 m with 3, as it did with 2, and
        the simulated ring accepts no false closure with either.
    trust_drift : float
        A confirmed far closure whose correction (how far it moves the node's current
        estimate, metres) is at most ``window[0] + trust_drift * travel`` (``travel``
        as for the windows) is *trusted*: it and its confirmations stay quadratic for good. A
        drift of a few percent of the distance is what local SLAM and odometry plausibly
        accumulate (a scale the laser and the wheels disagree on); a robust cost would weigh
        such a correction against the stiffness of the whole loop, which independent edges
        overstate, and drop it. A larger correction (the wide search or a long window found
        it) is taken quadratically for one optimization and then guarded by the robust cost.
        0 trusts none. 0.05 is a third of ``window_growth``: the search windows allow for the
        worst drift, the trust bound for a plausible one. ``travel`` is the far searches'.
    drift_min_score : float
        Least score of a far match whose implied correction lies within that trust bound;
        such a match needs ``consensus_checks`` confirmations at this score too. A far match
        scoring below ``wide_min_score`` whose correction is larger is dropped at once. A
        revisit after a long loop often scores low (the place changed, it is seen from
        elsewhere: 0.45-0.56 on the hospital's last re-entry), while an aliased stretch of a
        repetitive corridor can score as well but implies a jump of whole corridor periods
        (8.6 m at 0.53 in the simulated ring); the prior on drift tells them apart. A value
        at or above ``wide_min_score`` turns the rule off.
    every : int
        Search closures for every ``every``-th node.
    candidates : int
        Finished submaps searched per node: the nearest ones whose extent the window reaches.
    points : int
        Endpoints used by the closure search (the scan is subsampled evenly to this many).
    ambiguity : float
        A far match is *ambiguous*, and dropped, when the window holds another pose at least
        ``ambiguity_distance`` away that scores at least this fraction of its score (a
        repetitive place: look-alike offices, a corridor seen along its length). 0 turns the
        test off.
    ambiguity_distance : float
        Metres between two poses for them to be distinct places.
    pairwise : tuple of float
        ``(metres, radians)``: pairwise consistency (PCM, Mangelson et al., ICRA 2018). Two
        accepted closures agree when the loop they close with the local-SLAM chains between
        their two submap anchors and between their two nodes (chains that never saw a
        closure) closes within this tolerance plus ``pairwise_growth`` times the chains'
        length. Before each optimization the largest set of closures without a disagreeing
        pair is kept (greedily: the closure in the most disagreements leaves first, ties the
        one with the fewest agreements, then the newer) and the others are left out of the
        graph, so that a group of matches that fit one another but not the trajectory, the
        look-alike place, cannot bend it unless it outnumbers the right ones. 0.3 m is the
        consensus window; 0.05 rad five closure deviations.
    pairwise_growth : tuple of float
        Growth of that tolerance per metre of the two chains together: the drift local SLAM
        plausibly accumulates (the metres as ``trust_drift``).
    pairwise_reach : float
        Longest pair of chains compared, metres (longer ones tolerate nearly anything and are
        skipped). 0 turns the check off.
    """

    sd: tuple[float, float] = (0.05, 0.01)
    min_score: float = 0.55
    wide_min_score: float = 0.55
    window: tuple[float, float] = (0.5, 0.1)
    window_growth: tuple[float, float] = (0.15, 0.005)
    max_window: tuple[float, float] = (25.0, 0.5)
    wide_window: tuple[float, float] = (20.0, 0.5)
    wide_search_every: int = 50
    near_window: float = 2.0
    far_every: int = 4
    far_neighbours: int = 1
    consensus: tuple[float, float] = (0.3, 0.05)
    consensus_nodes: int = 10
    consensus_checks: int = 3
    trust_drift: float = 0.05
    drift_min_score: float = 0.45
    every: int = 1
    candidates: int = 3
    points: int = 90
    ambiguity: float = 0.9
    ambiguity_distance: float = 0.5
    pairwise: tuple[float, float] = (0.3, 0.05)
    pairwise_growth: tuple[float, float] = (0.05, 0.003)
    pairwise_reach: float = 30.0

    def __post_init__(self) -> None:
        require_nonnegative_finite("pairwise_reach", self.pairwise_reach)
        require_positive_finite("near_window", self.near_window)
        require_positive_finite("ambiguity_distance", self.ambiguity_distance)
        if not 0.0 <= self.ambiguity <= 1.0:
            raise ValueError(f"ambiguity must lie in [0, 1], got {self.ambiguity}")
        require_nonnegative_finite("trust_drift", self.trust_drift)
        for name in ("min_score", "wide_min_score", "drift_min_score"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{name} must lie in [0, 1], got {v}")
        require_pair("sd", self.sd, positive=True)
        for name in (
            "window", "window_growth", "max_window", "wide_window", "consensus", "pairwise",
            "pairwise_growth",
        ):  # fmt: skip
            require_pair(name, getattr(self, name), positive=False)
        require_at_least("wide_search_every", self.wide_search_every, 0)
        require_at_least("far_neighbours", self.far_neighbours, 0)
        for name in (
            "far_every", "consensus_nodes", "consensus_checks", "every", "candidates", "points",
        ):  # fmt: skip
            require_at_least(name, getattr(self, name), 1)


@dataclass(frozen=True)
class LoopClosure:
    """An accepted loop closure: node ``node`` seen in submap ``submap`` (anchor node
    ``anchor``) at ``pose`` (sensor pose in the submap frame) with branch-and-bound ``score``;
    ``far`` when a far search found it (accepted after consensus)."""

    node: int
    submap: int
    anchor: int
    pose: tuple[float, float, float]
    score: float
    far: bool


class LoopClosing:
    """Closure search, verification and acceptance for one submap graph SLAM run.

    Parameters
    ----------
    config : ClosureConfig
    graph : PoseGraph2D
        The run's pose graph (closure edges are added to it).
    submaps, active : list of Submap
        Every submap of the run and the active ones (the run appends to them).
    travel : list of float
        Cumulative path length at each node, metres (the run appends to it).
    matcher : MatcherConfig
        Gauss-Newton settings and usable range of the refinement on the full scan.
    min_match_score : float
        Least mean match score of that refinement.
    grid_cache : int
        Finished submaps whose match field and max-grids stay in memory.
    full_points : callable
        ``full_points(k)``: node ``k``'s scan endpoints (M, 2), sensor frame.
    local : list of ndarray, optional
        Each node's local-SLAM pose (3,), the chain the pairwise check compares closures
        along (the run appends to it); without it the check is off.
    """

    def __init__(
        self,
        config: ClosureConfig,
        *,
        graph: Any,
        submaps: list[Submap],
        active: list[Submap],
        travel: list[float],
        matcher: MatcherConfig,
        min_match_score: float,
        grid_cache: int,
        full_points: Callable[[int], NDArray[np.float64]],
        local: list[NDArray[np.float64]] | None = None,
    ) -> None:
        self.config = config
        self._local = local if local is not None else []
        self.graph = graph
        self.submaps = submaps
        self.active = active
        self._travel = travel
        self.matcher = matcher
        self.min_match_score = min_match_score
        self.grid_cache = grid_cache
        self._full_points = full_points
        self._closure_info = edge_information(config.sd)
        self.closures: list[LoopClosure] = []
        self.searched = 0
        self.search_seconds = 0.0
        self._node_points: list[NDArray[np.float64]] = []  # closure endpoints, sensor frame
        self._node_range: list[float] = []
        self._sub_links: list[dict[int, float]] = []  # submap graph: neighbour -> travel
        self._sub_dist: NDArray[np.float64] | None = None  # travel from the newest submap
        self._sub_dist_at = 0.0  # node travel when _sub_dist was computed
        # the same graph for far searches and the trust bound: a closure link also counts
        # the closure's distance from its submap's anchor (see window_growth)
        self._far_links: list[dict[int, float]] = []
        self._far_dist: NDArray[np.float64] | None = None
        self._far_dist_at = 0.0
        self._last_searched: list[int] = []  # per submap, the last node that searched it
        self.far_searched = 0  # far searches run
        self.far_found = 0  # far searches that found a match (before consensus)
        self.rejected = 0  # far matches that earlier nodes did not confirm
        self.drift_rejected = 0  # low-scoring far matches beyond the trust bound
        self.trusted = 0  # confirmed far closures kept quadratic (trust_drift)
        self.ambiguous = 0  # far matches dropped: another place scored nearly as well
        self._trusted_edges: set[int] = set()  # their edge indices
        self._unguarded: list[int] = []  # confirmed closures awaiting their first optimization
        self._closure_edges: list[int] = []  # edge index of each accepted closure
        self.pending_correction = False  # a closure moved the estimate: optimize now
        # pairwise consistency (ClosureConfig.pairwise): disagreeing pairs of closures (their
        # indices in self.closures), agreements per closure, and the closures left out
        self._conflict_a: list[int] = []
        self._conflict_b: list[int] = []
        self._agreements: list[int] = []
        self._pc = np.zeros((0, 11))  # per closure: what the comparison needs (_compare_pairs)
        self._left_out: set[int] = set()
        self._conflicts_checked = 0  # conflicts the last selection saw
        self.pairs_checked = 0  # pairs of closures compared
        self._cache: OrderedDict[int, Any] = OrderedDict()
        self._finished: list[Submap] = []
        self._fin_anchor: list[int] = []
        self._fin_centre: list[NDArray[np.float64]] = []
        self._fin_radius: list[float] = []

    # ------------------------------------------------------------------ what the run reports
    def add_node(self, points: NDArray[np.float64]) -> None:
        """Keep a new node's closure endpoints: an even subsample of ``points`` (sensor frame)
        of at most ``points`` rows."""
        step = max(1, math.ceil(len(points) / self.config.points))
        cpts = np.ascontiguousarray(points[::step])
        self._node_points.append(cpts)
        self._node_range.append(float(np.hypot(cpts[:, 0], cpts[:, 1]).max(initial=0.0)))

    def new_submap(self, sm: Submap) -> None:
        """Enter a submap the run is about to append (anchored at the newest node) into the
        submap graph, linked to the one before it by the travel between their anchors."""
        self._sub_links.append({})
        self._far_links.append({})
        self._last_searched.append(-1)
        if self.submaps:
            last = self.submaps[-1]
            self._link(last.index, sm.index, self._travel[sm.anchor] - self._travel[last.anchor])

    def add_candidate(self, sm: Submap) -> None:
        """A finished submap becomes a closure-search candidate."""
        self._finished.append(sm)
        self._fin_anchor.append(sm.anchor)
        self._fin_centre.append(sm.centre)
        self._fin_radius.append(sm.radius)

    @property
    def unguarded(self) -> bool:
        """Whether confirmed closures await their first (quadratic) optimization."""
        return bool(self._unguarded)

    def reguard(self) -> None:
        """After an optimization: confirmed closures beyond the trust bound go back under the
        robust cost; trusted ones stay quadratic."""
        if self._unguarded:
            guard = [e for e in self._unguarded if e not in self._trusted_edges]
            if guard:
                self.graph.set_robust(guard, True)
            self._unguarded = []

    def edge_indices(self) -> NDArray[np.int64]:
        """Pose-graph edge index of every accepted closure, in acceptance order."""
        return np.asarray(self._closure_edges, dtype=np.int64)

    def release(self) -> None:
        """Drop every cached match field and max-grid."""
        self._cache.clear()

    def cache_bytes(self) -> int:
        """Bytes held by the cached match fields and max-grids."""
        n = 0
        for fld, grids in self._cache.values():
            n += fld.values.nbytes + int(getattr(grids, "nbytes", 0))
        return n

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_cache"] = OrderedDict()  # match fields and max-grids: rebuilt on demand
        return state

    # ------------------------------------------------------------------ search and verification
    def _grids(self, sm: Submap, merged: bool = False) -> tuple[Any, Any]:
        """The finished submap's match field and max-grids (LRU cache); ``merged``: of the
        submap merged with its finished neighbours (``far_neighbours``), in its frame."""
        from probmap.slam.laser.loop_closure import PrecomputedGrids

        key = -1 - sm.index if merged else sm.index
        hit = self._cache.get(key)
        if hit is not None:
            self._cache.move_to_end(key)
            return hit
        if merged:
            fld = self._merged_field(sm)
        else:
            fld = sm.field()
            sm.release()
        grids = PrecomputedGrids.from_field(fld)
        self._cache[key] = (fld, grids)
        while len(self._cache) > self.grid_cache:
            self._cache.popitem(last=False)
        # a merged submap is several submaps' area: keep only the newest one (its far search's
        # consensus checks follow at once; the next far search is for another submap)
        for old in [k for k in self._cache if k < 0 and k != key]:
            del self._cache[old]
        return fld, grids

    def _merged_field(self, sm: Submap) -> Any:
        """The match field of ``sm``'s occupied cells and those of the finished submaps up to
        ``far_neighbours`` before and after it, placed in ``sm``'s frame by the current
        estimate of their anchors (``sm``'s own field when it has no finished neighbour)."""
        from probmap.grid.spec import GridSpec
        from probmap.slam.laser.submaps import match_field_from_occupied_cells

        n = self.config.far_neighbours
        near = [
            self.submaps[i]
            for i in range(sm.index - n, sm.index + n + 1)
            if i != sm.index and 0 <= i < len(self.submaps) and self.submaps[i].finished
        ]
        if not near:
            fld = sm.field()
            sm.release()
            return fld
        base = self.graph.pose(sm.anchor)
        res = sm.cell_spec.resolution
        xy = [sm.occupied_centres()]
        for other in near:
            rel = between(base, self.graph.pose(other.anchor))
            pts = other.occupied_centres()
            c, s_ = math.cos(rel[2]), math.sin(rel[2])
            xy.append(np.column_stack((
                rel[0] + c * pts[:, 0] - s_ * pts[:, 1], rel[1] + s_ * pts[:, 0] + c * pts[:, 1],
            )))  # fmt: skip
        allxy = np.concatenate(xy)
        # cell centres lie half a cell inside the new cells: no centre falls on a boundary
        margin = (sm.field_radius + 2.5) * res
        lo = allxy.min(axis=0) - margin
        w, h = (int(v) + 1 for v in np.ceil((allxy.max(axis=0) + margin - lo) / res))
        spec = GridSpec(res, (float(lo[0]), float(lo[1])), (h, w))
        ix = np.floor((allxy - lo) / res).astype(np.int64)
        cells = np.unique(ix[:, 1] * w + ix[:, 0])
        return match_field_from_occupied_cells(cells, spec, sm.sigma, sm.field_radius)

    def _link(self, a: int, b: int, travel: float, extent: float = 0.0) -> None:
        """Link submaps ``a`` and ``b`` in the submap graphs with the travel between them;
        the far graph adds ``extent`` (a closure's distance from its submap's anchor)."""
        for links, t in ((self._sub_links, travel), (self._far_links, travel + extent)):
            t = max(float(t), 0.0)
            if t < links[a].get(b, math.inf):
                links[a][b] = t
                links[b][a] = t
        self._sub_dist = None
        self._far_dist = None

    def _submap_travel(self, k: int, far: bool = False) -> NDArray[np.float64]:
        """Travel (metres) from node ``k`` to each submap along the shortest chain of local
        links and accepted closures (Dijkstra on the submap graph, cached until it changes);
        ``far``: on the far searches' graph (closures count their extent)."""
        import heapq

        newest = self.active[-1]
        links = self._far_links if far else self._sub_links
        dist = self._far_dist if far else self._sub_dist
        if dist is None or len(dist) != len(self.submaps):
            dist = np.full(len(self.submaps), np.inf)
            dist[newest.index] = 0.0
            heap = [(0.0, newest.index)]
            while heap:
                d, a = heapq.heappop(heap)
                if d > dist[a]:
                    continue
                for b, w in links[a].items():
                    if d + w < dist[b]:
                        dist[b] = d + w
                        heapq.heappush(heap, (d + w, b))
            if far:
                self._far_dist, self._far_dist_at = dist, self._travel[newest.anchor]
            else:
                self._sub_dist, self._sub_dist_at = dist, self._travel[newest.anchor]
        at = self._far_dist_at if far else self._sub_dist_at
        return dist + (self._travel[k] - at)

    def _windows(
        self, travel: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Search half-widths (metres, radians) after ``travel`` metres: ``window``
        grown by ``window_growth`` per metre, capped at ``max_window``."""
        cfg = self.config
        lin = np.minimum(cfg.window[0] + cfg.window_growth[0] * travel, cfg.max_window[0])
        ang = np.minimum(cfg.window[1] + cfg.window_growth[1] * travel, cfg.max_window[1])
        return lin, ang

    def search(self, k: int) -> None:
        """Search node ``k``'s scan against finished submaps (near every node, far every
        ``far_every`` nodes) and add the closures that pass (far ones after consensus)."""
        cfg = self.config
        finished = self._finished
        if not finished or self._node_points[k].shape[0] < 10:
            return
        t0 = time.perf_counter()
        poses = self.graph.poses
        xk = poses[k]
        idx = np.asarray([sm.index for sm in finished], dtype=np.int64)
        anchors = np.asarray(self._fin_anchor, dtype=np.int64)
        local_c = np.asarray(self._fin_centre).reshape(-1, 2)
        radius = np.asarray(self._fin_radius)
        pa = poses[anchors]
        c, s_ = np.cos(pa[:, 2]), np.sin(pa[:, 2])
        cx = pa[:, 0] + c * local_c[:, 0] - s_ * local_c[:, 1]
        cy = pa[:, 1] + s_ * local_c[:, 0] + c * local_c[:, 1]
        dist = np.hypot(cx - xk[0], cy - xk[1])
        lin, ang = self._windows(self._submap_travel(k)[idx])
        wide = bool(cfg.wide_search_every) and k % cfg.wide_search_every == 0
        if wide:
            lin = np.maximum(lin, cfg.wide_window[0])
            ang = np.maximum(ang, cfg.wide_window[1])
        reach = dist <= lin + radius
        near = np.flatnonzero(reach & (lin <= cfg.near_window))
        near = near[np.argsort(dist[near], kind="stable")][: cfg.candidates]
        jobs = [(int(i), False) for i in near]
        if wide or k % cfg.far_every == 0:
            # far searches: windows from the far graph's travel (never smaller)
            beyond = lin > cfg.near_window
            lin_f, ang_f = self._windows(self._submap_travel(k, far=True)[idx])
            lin = np.where(beyond, np.maximum(lin, lin_f), lin)
            ang = np.where(beyond, np.maximum(ang, ang_f), ang)
            reach = dist <= lin + radius
            far = np.flatnonzero(reach & beyond)
            if far.size:
                last = np.asarray(self._last_searched)[idx[far]]
                jobs.append((int(far[np.argmin(last)]), True))
        for i, is_far in jobs:
            sm = finished[i]
            self._last_searched[sm.index] = k
            min_score = cfg.min_score
            if is_far:
                min_score = min(cfg.wide_min_score, cfg.drift_min_score)
            found = self._match_submap(
                k, sm, xk, float(lin[i]), float(ang[i]), min_score, unique=is_far, merged=is_far
            )
            self.far_searched += is_far
            if found is None:
                continue
            self.far_found += is_far
            pose, score = found
            if not is_far:
                self._accept(k, sm, pose, score, False)
                continue
            # far: the correction it implies, as a rigid motion of the current estimate
            implied = compose(poses[sm.anchor], pose)
            delta = compose(implied, inverse(xk))
            passed = cfg.wide_min_score
            if score < passed:
                # a low score is believed only for a correction a drift explains
                shift = math.hypot(implied[0] - xk[0], implied[1] - xk[1])
                if shift > self._trust_bound(k, sm):
                    self.drift_rejected += 1
                    continue
                passed = min_score
            self._confirm(k, sm, pose, score, delta, passed)
        self.search_seconds += time.perf_counter() - t0

    def _match_submap(
        self,
        k: int,
        sm: Submap,
        xk: NDArray,
        lin: float,
        ang: float,
        min_score: float,
        unique: bool = False,
        merged: bool = False,
    ) -> tuple[NDArray[np.float64], float] | None:
        """Branch and bound of node ``k`` in submap ``sm`` around the current estimate, then
        Gauss-Newton on the full scan; the pose in the submap frame and the search score.
        ``unique``: None also when the match is ambiguous (:meth:`_ambiguous`); ``merged``:
        against the submap merged with its neighbours (``far_neighbours``)."""
        from probmap.slam.laser.loop_closure import branch_and_bound_search

        if self._node_points[k].shape[0] < 10:  # a blind scan (a consensus check may pick one)
            return None
        fld, grids = self._grids(sm, merged and self.config.far_neighbours > 0)
        self.searched += 1
        guess = between(self.graph.pose(sm.anchor), xk)
        found = branch_and_bound_search(
            grids,
            self._node_points[k],
            guess,
            linear_window=lin,
            angular_window=ang,
            min_score=min_score,
        )
        if found is None:
            return None
        if unique and self._ambiguous(grids, self._node_points[k], guess, found, lin, ang):
            self.ambiguous += 1
            return None
        full = self._full_points(k)
        m = self.matcher
        pose, _, _ = refine(fld, full, found.pose, m.iterations, (m.linear_step, m.angular_step))
        score, _, _ = normal_equations(fld, full, pose)
        if score / max(full.shape[0], 1) < self.min_match_score:
            return None
        return pose, float(found.score)

    def _ambiguous(
        self, grids: Any, points: NDArray, guess: NDArray, found: Any, lin: float, ang: float
    ) -> bool:
        """Whether another pose, at least ``ambiguity_distance`` from the best one, scores at
        least ``ambiguity`` times its score. Four more searches, each as wide as the first,
        cover the window outside the square of that half-width around the best pose: left
        and right of it over the window's height, below and above it over its own width."""
        from probmap.slam.laser.loop_closure import branch_and_bound_search

        cfg = self.config
        if cfg.ambiguity <= 0.0 or lin <= cfg.ambiguity_distance:
            return False
        d = cfg.ambiguity_distance
        bx, by = float(found.pose[0]), float(found.pose[1])
        gx, gy, gt = (float(v) for v in guess)
        half = lin  # each sub-window is as wide as the window
        centres = (
            (bx - d - half, gy), (bx + d + half, gy), (bx, by - d - half), (bx, by + d + half),
        )  # fmt: skip
        for cx, cy in centres:
            other = branch_and_bound_search(
                grids, points, (cx, cy, gt), linear_window=half, angular_window=ang,
                min_score=cfg.ambiguity * found.score,
            )  # fmt: skip
            if other is not None:
                return True
        return False

    def _confirm(
        self,
        k: int,
        sm: Submap,
        pose: NDArray,
        score: float,
        delta: NDArray[np.float64],
        min_score: float,
    ) -> None:
        """Accept a far closure when earlier nodes confirm it: each is moved by the same
        correction ``delta`` and searched in ``sm`` (and its neighbours: merged with them
        when ``far_neighbours``, as the far search matched, else one by one) within the small
        ``consensus`` window; every one that matches there at ``min_score`` (the threshold
        the closure itself passed) is added too. Without ``consensus_checks`` confirmations
        the closure is dropped."""
        cfg = self.config
        poses = self.graph.poses
        step = max(1, cfg.consensus_nodes // max(cfg.consensus_checks, 1))
        confirmed: list[tuple[int, Submap, NDArray, float]] = []
        for n in range(1, cfg.consensus_checks + 1):
            j = k - n * step
            if j < 0:
                break
            moved = compose(delta, poses[j])
            merged = cfg.far_neighbours > 0  # the far search's merged submap holds them all
            for cand in (sm,) if merged else (sm, *self._neighbours(sm)):
                guess = between(poses[cand.anchor], moved)
                found = self._match_submap(
                    j, cand, moved, cfg.consensus[0], cfg.consensus[1], min_score, merged=merged
                )
                if found is None:
                    continue
                d = between(guess, found[0])
                if math.hypot(d[0], d[1]) <= cfg.consensus[0] and abs(d[2]) <= cfg.consensus[1]:
                    confirmed.append((j, cand, found[0], found[1]))
                    break
        if len(confirmed) < cfg.consensus_checks:
            self.rejected += 1
            return
        # confirmed: the next optimization takes these closures quadratically, so that a
        # large drift is corrected (a robust kernel would discount them by their size). A
        # correction within a plausible drift (trust_drift) keeps them quadratic for good;
        # a larger one is guarded by the robust cost again from the optimization after it on
        implied = compose(poses[sm.anchor], pose)
        shift = math.hypot(implied[0] - poses[k][0], implied[1] - poses[k][1])
        rate = cfg.trust_drift
        trusted = rate > 0 and shift <= self._trust_bound(k, sm)
        # an untrusted cluster does not shorten the submap graph's travel: if it is a wrong
        # (aliased) match, a shortcut through it would make every later window and trust
        # bound too small
        added = [self._accept(k, sm, pose, score, True, link=trusted)]
        for j, cand, pj, sj in confirmed:
            added.append(self._accept(j, cand, pj, sj, True, link=trusted))
        self.graph.set_robust(added, False)
        if trusted:
            self.trusted += len(added)
            self._trusted_edges.update(added)
        self._unguarded.extend(added)
        self.pending_correction = True

    def _trust_bound(self, k: int, sm: Submap) -> float:
        """The largest correction (metres) of node ``k``'s estimate that a drift plausibly
        explains since submap ``sm``: ``window[0] + trust_drift * travel`` on the far
        graph."""
        cfg = self.config
        travel = float(self._submap_travel(k, far=True)[sm.index])
        return cfg.window[0] + cfg.trust_drift * travel

    def _neighbours(self, sm: Submap) -> list[Submap]:
        """The finished submaps just before and after ``sm``."""
        out = []
        for i in (sm.index - 1, sm.index + 1):
            if 0 <= i < len(self.submaps) and self.submaps[i].finished:
                out.append(self.submaps[i])
        return out

    def _accept(
        self, k: int, sm: Submap, pose: NDArray, score: float, far: bool, link: bool = True
    ) -> int:
        """Add the closure edge (robust) and, with ``link``, link the submaps it ties together
        (the travel that sizes later search windows and the trust bound then runs through
        it); returns the edge index."""
        cfg = self.config
        edge = self.graph.add_edge(sm.anchor, k, pose, self._closure_info, robust=True)
        self._closure_edges.append(edge)
        self.closures.append(
            LoopClosure(
                k, sm.index, sm.anchor, (float(pose[0]), float(pose[1]), float(pose[2])), score, far
            )
        )
        self._compare_pairs()
        for other in self.submaps[-2:] if link else ():
            if k in other.nodes:
                self._link(
                    sm.index,
                    other.index,
                    self._travel[k] - self._travel[other.anchor],
                    math.hypot(pose[0], pose[1]),
                )
        # optimize now only when the closure moves the estimate by a good part of the
        # near window; smaller corrections wait for the next periodic optimization
        implied = compose(self.graph.pose(sm.anchor), pose)
        xk = self.graph.pose(k)
        moved = math.hypot(implied[0] - xk[0], implied[1] - xk[1])
        turned = abs(float(wrap_angle(implied[2] - xk[2])))
        if moved > 0.5 * cfg.window[0] or turned > 0.5 * cfg.window[1]:
            self.pending_correction = True
        return edge

    # ------------------------------------------------------------------ pairwise consistency
    def _compare_pairs(self) -> None:
        """Compare the newest closure with every earlier one whose chains to it are shorter
        than ``pairwise_reach`` (:class:`ClosureConfig` ``pairwise``) and record the pairs
        that disagree."""
        cfg = self.config
        c = len(self.closures) - 1
        new = self.closures[c]
        self._agreements.append(0)
        if cfg.pairwise_reach <= 0 or len(self._local) <= new.node:
            return
        # per closure: travel at its anchor and at its node, their local poses, its pose
        if c >= len(self._pc):
            grown = np.zeros((max(64, 2 * len(self._pc)), 11))
            grown[: len(self._pc)] = self._pc
            self._pc = grown
        row = self._pc[c]
        row[0], row[1] = self._travel[new.anchor], self._travel[new.node]
        row[2:5], row[5:8], row[8:11] = self._local[new.anchor], self._local[new.node], new.pose
        if c == 0:
            return
        length = np.abs(row[0] - self._pc[:c, 0]) + np.abs(row[1] - self._pc[:c, 1])
        near = np.flatnonzero(length < cfg.pairwise_reach)
        if near.size == 0:
            return
        self.pairs_checked += int(near.size)
        other = self._pc[near]
        da, dk, z = other[:, 2:5], other[:, 5:8], other[:, 8:11]
        # node `new.node` in the frame of `new.anchor`, through the other closure and the two
        # local chains (anchor -> other anchor -> other closure -> other node -> node), against
        # the new closure's own pose
        e = _loop_errors(row[2:5], row[5:8], row[8:11], da, dk, z)
        tol_m = cfg.pairwise[0] + cfg.pairwise_growth[0] * length[near]
        tol_r = cfg.pairwise[1] + cfg.pairwise_growth[1] * length[near]
        bad = (np.hypot(e[:, 0], e[:, 1]) > tol_m) | (np.abs(wrap_angle(e[:, 2])) > tol_r)
        if bad.any():
            self._conflict_a.extend(near[bad].tolist())
            self._conflict_b.extend([c] * int(bad.sum()))
        good = near[~bad].tolist()
        self._agreements[c] += len(good)
        agreements = self._agreements
        for i in good:
            agreements[i] += 1

    def select_consistent(self) -> None:
        """Keep the largest set of closures without a disagreeing pair (greedy, see
        :class:`ClosureConfig` ``pairwise``) and leave the others out of the pose graph (their
        edges' information is set to zero; one that rejoins the set gets it back). Called
        before each optimization; cheap when no new disagreement was recorded."""
        n_conf = len(self._conflict_a)
        if n_conf == self._conflicts_checked:
            return
        self._conflicts_checked = n_conf
        n = len(self.closures)
        ca = np.asarray(self._conflict_a, dtype=np.int64)
        cb = np.asarray(self._conflict_b, dtype=np.int64)
        agree = np.asarray(self._agreements, dtype=np.int64)
        alive = np.ones(n, dtype=bool)
        while True:
            live = alive[ca] & alive[cb]
            if not live.any():
                break
            deg = np.bincount(ca[live], minlength=n) + np.bincount(cb[live], minlength=n)
            # most disagreements, then fewest agreements, then the newest
            worst = np.lexsort((np.arange(n), -agree, deg))[-1]
            alive[worst] = False
        out = set(np.flatnonzero(~alive).tolist())
        edges = np.asarray(self._closure_edges, dtype=np.int64)
        leave = sorted(out - self._left_out)
        back = sorted(self._left_out - out)
        if leave:
            self.graph.set_information(edges[leave], np.zeros((3, 3)))
        if back:
            self.graph.set_information(edges[back], self._closure_info)
        self._left_out = out

    @property
    def left_out(self) -> NDArray[np.bool_]:
        """Per accepted closure, whether the pairwise check leaves it out of the graph."""
        mask = np.zeros(len(self.closures), dtype=bool)
        mask[sorted(self._left_out)] = True
        return mask

    @property
    def conflicts(self) -> int:
        """Pairs of closures found to disagree."""
        return len(self._conflict_a)
