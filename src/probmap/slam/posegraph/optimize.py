"""SE(2) pose-graph optimization: sparse Levenberg-Marquardt with robust costs.

A pose graph has nodes ``x_n = (x, y, theta)`` (world frame, metres and radians) and edges
``(i, j, z_ij, Omega_ij)``: a measured pose ``z_ij`` of node ``j`` in the frame of node ``i``
with a 3x3 information matrix. The optimizer minimises

.. math:: F(x) = \\tfrac12 \\sum_k \\rho_k\\big(e_k^\\top \\Omega_k e_k\\big), \\qquad
          e_k = \\mathrm{Log}\\big(z_{ij}^{-1} (x_i^{-1} x_j)\\big)

with ``rho(s) = s`` for plain edges. The residual is GTSAM's ``BetweenFactor<Pose2>`` error
(``Pose2::Logmap``, its default chart), so ``F`` is exactly GTSAM's ``graph.error`` with a
prior on the first pose (whose term is zero: that pose is held fixed). ``chart="xyt"``
uses g2o's and TORO's ``(dx, dy, dtheta)`` residual instead.

Levenberg-Marquardt (Madsen, Nielsen and Tingleff, "Methods for non-linear least squares
problems", 2004, section 3.2): every iteration linearizes all edges with analytic Jacobians
(a numba kernel writes the 3x3 blocks of ``H = J' W Omega J`` and ``g = J' W Omega e`` straight
into a fixed compressed-column pattern), solves ``(H + lambda D) delta = -g`` by a sparse
block ``L D L'`` factorization (3x3 blocks; the minimum-degree block ordering and the
elimination tree are computed once per graph structure), and accepts the step if the cost
falls. The damping follows the gain ratio (Nielsen's rule). The whole loop is one compiled
call. The gauge is fixed by holding nodes (by default the first) constant.

Robust costs (IRLS weights recomputed at every linearization) down-weight edges whose
Mahalanobis distance is large: Huber, Cauchy, and dynamic covariance scaling (DCS; Agarwal,
Tipaldi, Spinello, Stachniss and Burgard, "Robust map optimization using dynamic covariance
scaling", ICRA 2013). They apply to the edges of a mask, typically the loop closures, so that
odometry stays quadratic.

Far-off starting headings trap any local method in a poor minimum; :func:`lago_initialization`
(Carlone et al. 2014) computes a start from two linear least-squares problems (headings, then
positions) and ``optimize_pose_graph(..., init="lago")`` uses it.

Two tiers: :func:`optimize_pose_graph` and :func:`graph_error` work on arrays;
:class:`PoseGraph2D` grows a graph node by node and re-optimizes it from its current poses.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._checks import require_at_least, require_positive_finite
from probmap._typing import BoolArray, FloatArray, IntArray
from probmap.geometry.se2 import pose_batch
from probmap.slam.posegraph import _kernels as _k

__all__ = [
    "MAX_MEAN_CHI2",
    "OptimizeResult",
    "OptimizerConfig",
    "PoseGraph2D",
    "RobustKernel",
    "edge_residuals",
    "graph_error",
    "lago_initialization",
    "optimize_pose_graph",
]

RobustKernel = Literal["none", "huber", "cauchy", "dcs"]
"""The names ``OptimizerConfig.robust`` takes (for annotating configs that pass one on)."""
_KERNELS = {
    "none": _k.KERNEL_NONE,
    "huber": _k.KERNEL_HUBER,
    "cauchy": _k.KERNEL_CAUCHY,
    "dcs": _k.KERNEL_DCS,
}
# Default scales: Huber and Cauchy at 95 % asymptotic efficiency for a Gaussian residual
# (Mahalanobis-distance units); DCS with Phi = 1 as recommended by Agarwal et al. (2013).
_DEFAULT_SCALE = {"none": 1.0, "huber": 1.345, "cauchy": 2.3849, "dcs": 1.0}
_CHARTS = {"logmap": _k.CHART_LOGMAP, "xyt": _k.CHART_XYT}


@dataclass(frozen=True)
class OptimizerConfig:
    """Parameters of the Levenberg-Marquardt pose-graph optimizer.

    Parameters
    ----------
    max_iterations : int
        Most linearizations (outer iterations); each may try several damping values.
    relative_tolerance : float
        Converged when an accepted step lowers the cost by less than this fraction of it.
    absolute_tolerance : float
        Converged when an accepted step lowers the cost by less than this (cost units).
    initial_lambda : float
        Damping of the first iteration, relative to the largest diagonal entry of ``H``
        (Madsen et al.'s ``tau``).
    max_lambda : float
        Relative damping above which LM gives up on decreasing the cost (a minimum to working
        precision); the result then counts as converged.
    damping : {"identity", "diagonal"}
        ``D`` in ``H + lambda D``: the identity (Levenberg) or ``diag(H)`` (Marquardt).
    robust : {"none", "huber", "cauchy", "dcs"}
        Robust kernel of the edges selected by the robust mask.
    robust_scale : float or None
        Kernel scale: Huber and Cauchy ``k`` in Mahalanobis-distance units (sqrt of
        ``e' Omega e``), DCS ``Phi`` in ``e' Omega e`` units. ``None`` picks the kernel's
        default (Huber 1.345, Cauchy 2.3849, DCS 1.0).
    chart : {"logmap", "xyt"}
        Residual of an edge: GTSAM's ``Log(z^-1 x_i^-1 x_j)`` or g2o/TORO's
        ``(dx, dy, dtheta)`` of ``z^-1 x_i^-1 x_j``.
    """

    max_iterations: int = 100
    relative_tolerance: float = 1e-6
    absolute_tolerance: float = 1e-12
    initial_lambda: float = 1e-9
    max_lambda: float = 1e10
    damping: Literal["identity", "diagonal"] = "identity"
    robust: RobustKernel = "none"
    robust_scale: float | None = None
    chart: Literal["logmap", "xyt"] = "logmap"

    def __post_init__(self) -> None:
        if isinstance(self.max_iterations, bool) or not isinstance(
            self.max_iterations, (int, np.integer)
        ):
            raise ValueError(f"max_iterations must be an integer, got {self.max_iterations!r}")
        require_at_least("max_iterations", self.max_iterations, 0)
        for name in ("relative_tolerance", "absolute_tolerance"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v}")
        for name in ("initial_lambda", "max_lambda"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive finite number, got {v}")
        if self.max_lambda < self.initial_lambda:
            raise ValueError(
                f"max_lambda ({self.max_lambda}) must be >= initial_lambda ({self.initial_lambda})"
            )
        if self.damping not in ("identity", "diagonal"):
            raise ValueError(f"damping must be 'identity' or 'diagonal', got {self.damping!r}")
        if self.robust not in _KERNELS:
            raise ValueError(f"robust must be one of {sorted(_KERNELS)}, got {self.robust!r}")
        if self.chart not in _CHARTS:
            raise ValueError(f"chart must be one of {sorted(_CHARTS)}, got {self.chart!r}")
        if self.robust_scale is None:
            object.__setattr__(self, "robust_scale", _DEFAULT_SCALE[self.robust])
        else:
            require_positive_finite("robust_scale", self.robust_scale)

    @property
    def scale(self) -> float:
        """The resolved robust scale."""
        assert self.robust_scale is not None  # resolved in __post_init__
        return float(self.robust_scale)


_DEFAULT_CONFIG = OptimizerConfig()


@dataclass(frozen=True, eq=False)
class OptimizeResult:
    """What :func:`optimize_pose_graph` and :meth:`PoseGraph2D.optimize` return.

    Attributes
    ----------
    poses : ndarray, shape (N, 3)
        Optimized poses ``(x, y, theta)``, world frame, metres and radians (angles in
        ``[-pi, pi)``).
    initial_error, final_error : float
        Cost ``0.5 * sum rho(e' Omega e)`` before and after (GTSAM's ``graph.error`` with a
        prior on the fixed first pose, for plain edges).
    iterations : int
        Linearizations performed.
    seconds : float
        Wall time of the call.
    converged : bool
        True when a tolerance was met (or no step could lower the cost further) at a minimum
        with a sane cost: a Gauss-Newton step from the result predicts a decrease of at most
        0.1 % of the cost, and the mean ``e' Omega e`` per edge is at most
        :data:`MAX_MEAN_CHI2` (:func:`optimize_pose_graph`; :meth:`PoseGraph2D.optimize`
        with ``verify=True``). False when the iteration cap stopped it, or when those checks
        fail (``message`` says which).
    weights : ndarray, shape (E,)
        Robust (IRLS) weight of every edge at the final poses, in ``(0, 1]``; 1 for
        quadratic edges. A weight near 0 marks an edge the optimizer treated as an outlier.
    chi2 : ndarray, shape (E,)
        ``e' Omega e`` of every edge at the final poses.
    message : str
        Why it stopped.
    """

    poses: FloatArray
    initial_error: float
    final_error: float
    iterations: int
    seconds: float
    converged: bool
    weights: FloatArray
    chi2: FloatArray
    message: str


# --------------------------------------------------------------------------- validation


def _as_edges(
    edges: ArrayLike,
    measurements: ArrayLike,
    information: ArrayLike,
    n_nodes: int,
) -> tuple[IntArray, IntArray, FloatArray, FloatArray]:
    e = np.asarray(edges)
    if e.ndim != 2 or e.shape[1] != 2:
        raise ValueError(f"edges must have shape (E, 2) (i, j), got {e.shape}")
    if e.size and not np.issubdtype(e.dtype, np.integer):
        raise ValueError(f"edges must hold integer node indices, got dtype {e.dtype}")
    E = e.shape[0]
    z = np.ascontiguousarray(measurements, dtype=np.float64)
    if z.shape != (E, 3):
        raise ValueError(f"measurements must have shape ({E}, 3), got {z.shape}")
    om = np.ascontiguousarray(information, dtype=np.float64)
    if om.shape != (E, 3, 3):
        raise ValueError(f"information must have shape ({E}, 3, 3), got {om.shape}")
    ei = np.ascontiguousarray(e[:, 0], dtype=np.int64)
    ej = np.ascontiguousarray(e[:, 1], dtype=np.int64)
    k, code = _k.check_edges(ei, ej, n_nodes, z)
    if code == 1:
        raise ValueError(f"edge {k} ({ei[k]}, {ej[k]}): node indices must lie in [0, {n_nodes})")
    if code == 2:
        raise ValueError(f"edge {k} connects node {ei[k]} to itself")
    if code == 3:
        raise ValueError(f"measurement of edge {k} is not finite")
    _check_information(om)
    return ei, ej, z, om


def _check_information(om: FloatArray) -> None:
    """Raise unless every ``om[k]`` is finite, symmetric and positive semi-definite."""
    k, code = _k.check_information(om, 1e-9)
    if code == 1:
        raise ValueError(f"information matrix of edge {k} is not finite")
    if code == 2:
        raise ValueError(f"information matrix of edge {k} is not symmetric")
    if code == 3:
        raise ValueError(f"information matrix of edge {k} is not positive semi-definite")


def _as_mask(robust_mask: ArrayLike | None, n_edges: int) -> BoolArray:
    if robust_mask is None:
        return np.ones(n_edges, dtype=np.bool_)
    m = np.asarray(robust_mask)
    if m.shape != (n_edges,) or m.dtype != np.bool_:
        raise ValueError(f"robust_mask must be a boolean array of shape ({n_edges},)")
    return np.ascontiguousarray(m)


def _as_fixed(fixed: Sequence[int] | ArrayLike, n_nodes: int) -> IntArray:
    f = np.ascontiguousarray(np.asarray(fixed, dtype=np.int64).ravel())
    if f.size == 0:
        raise ValueError("at least one node must be fixed (the gauge)")
    if f.min() < 0 or f.max() >= n_nodes:
        raise ValueError(f"fixed node indices must lie in [0, {n_nodes}), got {f.tolist()}")
    return f


# --------------------------------------------------------------------------- linear system

# Graphs with more free nodes than this get a fill-reducing block ordering (below it, the
# natural order costs less than computing one)
_ORDERING_MIN_FREE = 48
_MESSAGES = {
    _k.STATUS_CAP: "iteration cap reached",
    _k.STATUS_RELATIVE: "relative decrease below tolerance",
    _k.STATUS_ABSOLUTE: "absolute decrease below tolerance",
    _k.STATUS_NO_DECREASE: "no step lowers the cost (damping at its cap)",
    _k.STATUS_NOTHING: "nothing to optimize",
    _k.STATUS_ZERO: "zero error",
}


class _NormalEquations:
    """What stays fixed while a graph's structure does: the block ordering of the free nodes
    (fill-reducing), the upper-triangular CSC pattern of ``H`` in that order, and the
    elimination tree and column counts of its ``L D L'`` factor.

    Raises ``ValueError`` when some node is not connected to a fixed node through edges: its
    pose would be undetermined.
    """

    def __init__(self, n_nodes: int, ei: IntArray, ej: IntArray, fixed: IntArray) -> None:
        _check_connected(n_nodes, ei, ej, fixed)
        node_index, nf = _k.number_free_nodes(n_nodes, fixed)
        if nf > _ORDERING_MIN_FREE:
            free = node_index >= 0
            node_index[free] = _fill_reducing_order(nf, node_index[ei], node_index[ej])
        (
            self.colptr,
            self.indices,
            self.diag_base,
            self.edge_base,
            self.diag_pos,
            self.blk_colptr,
            self.blk_rows,
        ) = _k.build_structure(ei, ej, node_index)
        self.etree, self.Lp = _k.ldl_symbolic(self.blk_colptr, self.blk_rows)
        self.n_nodes = n_nodes
        self.n_free = int(nf)
        self.node_index = node_index
        self.fixed = fixed
        self.nnz = int(self.colptr[-1])


def _fill_reducing_order(n: int, p: IntArray, q: IntArray) -> IntArray:
    """Elimination position of each of ``n`` blocks joined by edges ``(p, q)`` (-1 = fixed):
    multiple minimum degree on the block graph (SuperLU's ``MMD_AT_PLUS_A``, the ordering
    of a factorization of a diagonally dominant matrix with that pattern)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    m = (p >= 0) & (q >= 0)
    r = np.concatenate([p[m], q[m], np.arange(n)])
    c = np.concatenate([q[m], p[m], np.arange(n)])
    degree = np.bincount(r, minlength=n).astype(np.float64)
    v = np.concatenate([np.full(2 * int(m.sum()), -1.0), degree + 1.0])
    A = sp.csc_matrix((v, (r, c)), shape=(n, n))
    lu = splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    return np.asarray(lu.perm_c, dtype=np.int64)


def _check_connected(n_nodes: int, ei: IntArray, ej: IntArray, fixed: IntArray) -> None:
    """Raise unless every node is connected to a fixed node through edges."""
    theta = np.zeros(n_nodes)
    reached = _k.spanning_tree(n_nodes, ei, ej, np.zeros(ei.shape[0]), fixed, theta)
    if reached < n_nodes:
        loose = np.flatnonzero(np.isnan(theta))
        raise ValueError(
            f"{loose.size} node(s) are not connected to a fixed node (first: node {loose[0]}); "
            "their poses are undetermined"
        )


# --------------------------------------------------------------------------- LM core


# The kernels' ``graph``: edges i and j, measurements, information, chart, robust kernel and
# its scale, and which edges it applies to.
_Graph = tuple[IntArray, IntArray, FloatArray, FloatArray, int, int, float, BoolArray]


def _graph(
    ei: IntArray,
    ej: IntArray,
    meas: FloatArray,
    info: FloatArray,
    robust: BoolArray,
    config: OptimizerConfig,
) -> _Graph:
    """The validated contiguous edge arrays with ``config``'s chart and robust kernel, as the
    kernels take them (:mod:`probmap.slam.posegraph._kernels`)."""
    return ei, ej, meas, info, _CHARTS[config.chart], _KERNELS[config.robust], config.scale, robust


def _cost(poses: FloatArray, graph: _Graph) -> float:
    """The cost at ``poses`` (:func:`_posegraph_kernels.graph_cost`)."""
    E = graph[0].shape[0]
    return float(_k.graph_cost(poses, graph, np.empty(E), np.empty(E)))


def _levenberg_marquardt(
    poses: FloatArray,
    graph: _Graph,
    system: _NormalEquations,
    config: OptimizerConfig,
    max_iterations: int,
    *,
    verify: bool = True,
) -> tuple[FloatArray, float, int, bool, str, FloatArray, FloatArray]:
    """LM on validated contiguous arrays (:func:`_posegraph_kernels.levenberg_marquardt`).

    Returns the poses, final cost, iterations, converged flag, message, and the final
    per-edge ``chi2`` and IRLS weights; ``verify``: a stop by the tolerances counts as
    converged only after :func:`_verify_convergence`.
    """
    E = graph[0].shape[0]
    chi2 = np.empty(E)
    weights = np.empty(E)
    out = np.empty_like(poses)
    s = system
    F, its, status = _k.levenberg_marquardt(
        poses, graph, s.node_index, s.colptr, s.diag_base, s.edge_base, s.blk_colptr, s.blk_rows,
        s.etree, s.Lp, max_iterations, config.relative_tolerance, config.absolute_tolerance,
        config.initial_lambda, config.max_lambda, config.damping == "identity", out, chi2,
        weights,
    )  # fmt: skip
    converged = status != _k.STATUS_CAP
    message = _MESSAGES[int(status)]
    if verify and converged and E and status != _k.STATUS_ZERO and s.n_free:
        converged, message = _verify_convergence(out, float(F), graph, s, config, message)
    return out, float(F), int(its), converged, message, chi2, weights


# A stop by the tolerances counts as converged only when a Gauss-Newton step from the result
# predicts at most this fraction of the cost as further decrease. Measured on the 18 standard
# graphs (pose-graphs/): at most 2.2e-7 where LM converged (M3500b), 0.15 and 0.66 where it
# crawled from a vertex started 1e8 m and 5e4 m away (w100) and stopped on the relative
# decrease alone.
_STATIONARY = 1e-3
#: Largest mean ``e' Omega e`` per edge of a result called converged: 1e4 is a residual of 100
#: standard deviations on every edge (the standard graphs end at 0.004 to 0.6).
MAX_MEAN_CHI2 = 1.0e4


def _verify_convergence(
    x: FloatArray,
    F: float,
    graph: _Graph,
    s: _NormalEquations,
    config: OptimizerConfig,
    message: str,
) -> tuple[bool, str]:
    """Whether a result the tolerances stopped at is a minimum with a sane cost: the
    Gauss-Newton step from it (the damping LM starts with) predicts a decrease of at most
    ``_STATIONARY`` of the cost, and the mean chi2 per edge is at most :data:`MAX_MEAN_CHI2`.
    Returns the flag and the message saying why not."""
    E = graph[0].shape[0]
    if not math.isfinite(F):
        return False, f"{message}, but the cost is not finite"
    n = s.blk_colptr.shape[0] - 1
    data = np.empty(s.colptr[3 * n])
    rhs = np.empty(3 * n)
    _k.accumulate_normal_equations(x, graph, s.node_index, s.colptr, s.diag_base, s.edge_base,
                                   data, rhs)  # fmt: skip
    cols = np.arange(3 * n)
    diag = data[s.colptr[cols] + s.diag_base[cols // 3] + cols % 3]
    dmax = float(diag.max(initial=0.0))
    Li, Lx, Dinv = _k.ldl_storage(s.Lp, n)
    lam = config.initial_lambda * max(dmax, 1e-300)
    ok = dmax > 0 and _k.ldl_factor(
        data, s.colptr, s.diag_base, s.blk_colptr, s.blk_rows, s.etree, s.Lp, lam,
        np.ones(3 * n), Li, Lx, Dinv,
    )  # fmt: skip
    if not ok:
        return False, f"{message}, but the system is singular there (an unconstrained direction)"
    delta = np.empty(3 * n)
    _k.ldl_solve(s.Lp, Li, Lx, Dinv, -rhs, delta)
    remaining = -0.5 * float(delta @ rhs)
    if not remaining <= _STATIONARY * F + config.absolute_tolerance:
        return False, (
            f"{message}, but no minimum: a Gauss-Newton step predicts {remaining:.3g} less "
            f"(a start far off, or a local minimum of the chart)"
        )
    mean = 2.0 * F / E
    if mean > MAX_MEAN_CHI2:
        return False, (
            f"{message}, but the cost is implausible: mean chi2 {mean:.3g} per edge "
            f"(> {MAX_MEAN_CHI2:g}: edges that contradict each other or the start)"
        )
    return True, message


# --------------------------------------------------------------------------- initialization

# Re-solves of LAGO's headings with the multiples of 2 pi rounded from the previous estimate
_LAGO_REROUNDS = 10


def _lago(
    poses: FloatArray,
    ei: IntArray,
    ej: IntArray,
    meas: FloatArray,
    info: FloatArray,
    system: _NormalEquations,
) -> FloatArray:
    """LAGO on validated arrays (:func:`_posegraph_kernels.lago`), in the optimizer's block
    pattern and ordering."""
    s = system
    out = np.empty_like(poses)
    ok = _k.lago(
        poses, ei, ej, meas, info, s.fixed, s.node_index, s.colptr, s.diag_base, s.edge_base,
        s.diag_pos, s.blk_colptr, s.blk_rows, s.etree, s.Lp, _LAGO_REROUNDS, out,
    )  # fmt: skip
    if not ok:  # pragma: no cover - the ridge keeps both systems positive definite
        raise np.linalg.LinAlgError("LAGO's linear system is not positive definite")
    return out


def lago_initialization(
    poses: ArrayLike,
    edges: ArrayLike,
    measurements: ArrayLike,
    information: ArrayLike,
    *,
    fixed: Sequence[int] | ArrayLike = (0,),
) -> FloatArray:
    """Initial guess by the linear approximation of Carlone et al. (LAGO).

    Carlone, Aragues, Castellanos and Bona, "A fast and accurate approximation for planar pose
    graph optimization", IJRR 2014: (1) headings along a breadth-first spanning tree fix the
    multiple of 2 pi of every edge's heading difference; (2) all headings by weighted linear
    least squares; (3) all positions by linear least squares given those headings. Two sparse
    solves, no iteration. It ignores robust kernels: a false loop closure pulls it like any
    other edge, so use it on graphs without outliers (or on their trusted edges).

    Parameters
    ----------
    poses : array_like, shape (N, 3)
        Current poses; only the fixed nodes' poses are used (they anchor the estimate), and
        nodes whose position information is too weak to determine them keep their position.
    edges, measurements, information :
        As for :func:`optimize_pose_graph`.
    fixed : sequence of int
        Nodes that keep their poses (the gauge); every node must be connected to one.

    Returns
    -------
    ndarray, shape (N, 3)
        Poses ``(x, y, theta)``, world frame, metres and radians in ``[-pi, pi)``.

    Examples
    --------
    A square, with the file's guess far off; LAGO gets it exactly (the loop is consistent):

    >>> import numpy as np
    >>> z = np.array([[1.0, 0.0, np.pi / 2]] * 4)
    >>> edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])
    >>> guess = np.zeros((4, 3))
    >>> np.round(lago_initialization(guess, edges, z, np.tile(np.eye(3), (4, 1, 1))), 9) + 0.0
    array([[ 0.        ,  0.        ,  0.        ],
           [ 1.        ,  0.        ,  1.57079633],
           [ 1.        ,  1.        , -3.14159265],
           [ 0.        ,  1.        , -1.57079633]])
    """
    x = pose_batch(poses)
    ei, ej, z, om = _as_edges(edges, measurements, information, len(x))
    f = _as_fixed(fixed, len(x))
    return _lago(x, ei, ej, z, om, _NormalEquations(len(x), ei, ej, f))


# --------------------------------------------------------------------------- function tier


def edge_residuals(
    poses: ArrayLike,
    edges: ArrayLike,
    measurements: ArrayLike,
    *,
    chart: Literal["logmap", "xyt"] = "logmap",
) -> FloatArray:
    """Residual ``e_k`` of every edge (see the module docstring).

    Parameters
    ----------
    poses : array_like, shape (N, 3)
        Node poses ``(x, y, theta)``, world frame, metres and radians.
    edges : array_like, shape (E, 2), int
        Node indices ``(i, j)``.
    measurements : array_like, shape (E, 3)
        Measured pose of ``j`` in ``i``'s frame.
    chart : {"logmap", "xyt"}
        GTSAM's ``Log`` residual or g2o's ``(dx, dy, dtheta)``.

    Returns
    -------
    ndarray, shape (E, 3)
        ``(e_x, e_y, e_theta)`` per edge: metres and radians (angle in ``[-pi, pi)``).
    """
    if chart not in _CHARTS:
        raise ValueError(f"chart must be one of {sorted(_CHARTS)}, got {chart!r}")
    x = pose_batch(poses)
    z = np.ascontiguousarray(measurements, dtype=np.float64)
    n_edges = z.shape[0] if z.ndim == 2 else 0
    ei, ej, z, _ = _as_edges(edges, z, np.tile(np.eye(3), (n_edges, 1, 1)), len(x))
    out = np.empty((ei.shape[0], 3))
    _k.edge_residuals(x, ei, ej, z, _CHARTS[chart], out)
    return out


def graph_error(
    poses: ArrayLike,
    edges: ArrayLike,
    measurements: ArrayLike,
    information: ArrayLike,
    config: OptimizerConfig | None = None,
    *,
    robust_mask: ArrayLike | None = None,
) -> float:
    """Cost ``0.5 * sum_k rho_k(e_k' Omega_k e_k)`` of a pose graph.

    For plain edges this is GTSAM's ``NonlinearFactorGraph.error`` of the same
    ``BetweenFactor<Pose2>`` edges plus a prior on the first pose at its current value.

    Parameters
    ----------
    poses : array_like, shape (N, 3)
        Node poses ``(x, y, theta)``, world frame, metres and radians.
    edges : array_like, shape (E, 2), int
        Node indices ``(i, j)`` of each edge.
    measurements : array_like, shape (E, 3)
        Measured pose of ``j`` in ``i``'s frame.
    information : array_like, shape (E, 3, 3)
        Information matrices (inverse covariances) of the measurements, in the residual's
        coordinates.
    config : OptimizerConfig, optional
        Its ``robust``, ``robust_scale`` and ``chart`` are used.
    robust_mask : array_like of bool, shape (E,), optional
        Edges the robust kernel applies to (default: all).

    Returns
    -------
    float
    """
    cfg = config or OptimizerConfig()
    x = pose_batch(poses)
    ei, ej, z, om = _as_edges(edges, measurements, information, len(x))
    mask = _as_mask(robust_mask, ei.shape[0])
    return _cost(x, _graph(ei, ej, z, om, mask, cfg))


def optimize_pose_graph(
    poses: ArrayLike,
    edges: ArrayLike,
    measurements: ArrayLike,
    information: ArrayLike,
    config: OptimizerConfig | None = None,
    *,
    fixed: Sequence[int] | ArrayLike = (0,),
    robust_mask: ArrayLike | None = None,
    init: Literal["given", "lago"] = "given",
) -> OptimizeResult:
    """Optimize an SE(2) pose graph by sparse Levenberg-Marquardt.

    Parameters
    ----------
    poses : array_like, shape (N, 3)
        Initial node poses ``(x, y, theta)``, world frame, metres and radians.
    edges : array_like, shape (E, 2), int
        Node indices ``(i, j)`` of each edge (0-based rows of ``poses``, ``i != j``).
    measurements : array_like, shape (E, 3)
        Measured pose of node ``j`` in node ``i``'s frame, ``(dx, dy, dtheta)``.
    information : array_like, shape (E, 3, 3)
        Symmetric positive semi-definite information matrices.
    config : OptimizerConfig, optional
        Iterations, tolerances, damping, robust kernel and residual chart.
    fixed : sequence of int
        Nodes held at their initial poses (the gauge); at least one. Every other node must be
        connected to one of them through edges.
    robust_mask : array_like of bool, shape (E,), optional
        Edges the robust kernel applies to, e.g. the loop closures (default: all edges).
    init : {"given", "lago"}
        Start from ``poses`` or from :func:`lago_initialization` (recommended for a batch
        problem whose headings are far off; ``initial_error`` is still that of ``poses``).

    Returns
    -------
    OptimizeResult

    Raises
    ------
    ValueError
        Malformed arrays, edges to unknown nodes, self-loops, information matrices that are
        not symmetric positive semi-definite, or nodes not connected to a fixed node.

    Examples
    --------
    A square whose last edge closes the loop, started from a distorted guess:

    >>> import numpy as np
    >>> z = np.array([[1.0, 0.0, np.pi / 2]] * 4)
    >>> edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])
    >>> guess = np.array([[0, 0, 0], [1.1, 0.1, 1.5], [1.0, 1.2, 3.0], [-0.1, 0.9, -1.4]])
    >>> r = optimize_pose_graph(guess, edges, z, np.tile(np.eye(3), (4, 1, 1)))
    >>> bool(r.converged), round(r.final_error, 12)
    (True, 0.0)
    >>> np.round(r.poses[1], 9) + 0.0
    array([1.        , 0.        , 1.57079633])
    """
    t0 = time.perf_counter()
    cfg = config or _DEFAULT_CONFIG
    if init not in ("given", "lago"):
        raise ValueError(f"init must be 'given' or 'lago', got {init!r}")
    x = pose_batch(poses)
    ei, ej, z, om = _as_edges(edges, measurements, information, len(x))
    mask = _as_mask(robust_mask, ei.shape[0])
    f = _as_fixed(fixed, len(x))
    system = _NormalEquations(len(x), ei, ej, f)
    graph = _graph(ei, ej, z, om, mask, cfg)
    F0 = _cost(x, graph)
    start = _lago(x, ei, ej, z, om, system) if init == "lago" else x
    out, F, its, conv, msg, chi2, w = _levenberg_marquardt(
        start, graph, system, cfg, cfg.max_iterations
    )
    return OptimizeResult(out, F0, F, its, time.perf_counter() - t0, conv, w, chi2, msg)


# --------------------------------------------------------------------------- class tier


class PoseGraph2D:
    """A growing SE(2) pose graph, re-optimized in place from its current poses.

    Built for incremental SLAM back ends: :meth:`add_node` and :meth:`add_edge` append to
    arrays with amortized growth, :meth:`optimize` runs Levenberg-Marquardt warm-started from
    the current poses and keeps the result. The sparsity pattern and the factorization's
    ordering are rebuilt only when nodes or edges were added since the last optimization.

    Parameters
    ----------
    config : OptimizerConfig, optional
        Optimizer settings; its robust kernel applies to the edges added with
        ``robust=True`` (typically loop closures), the others stay quadratic.
    fixed : sequence of int
        Nodes held fixed (the gauge), by default the first node.

    Examples
    --------
    >>> import numpy as np
    >>> g = PoseGraph2D()
    >>> a = g.add_node([0.0, 0.0, 0.0])
    >>> b = g.add_node([0.9, 0.1, 0.0])
    >>> g.add_edge(a, b, [1.0, 0.0, 0.0], np.eye(3))
    0
    >>> r = g.optimize()
    >>> np.round(g.poses[1], 9) + 0.0
    array([1., 0., 0.])
    """

    def __init__(
        self, config: OptimizerConfig | None = None, *, fixed: Sequence[int] = (0,)
    ) -> None:
        self.config = config or OptimizerConfig()
        self._fixed = tuple(int(f) for f in fixed)
        if not self._fixed:
            raise ValueError("at least one node must be fixed (the gauge)")
        self._n = 0
        self._m = 0
        self._poses = np.zeros((16, 3))
        self._ij = np.zeros((16, 2), dtype=np.int64)
        self._z = np.zeros((16, 3))
        self._info = np.zeros((16, 3, 3))
        self._robust = np.zeros(16, dtype=np.bool_)
        self._system: _NormalEquations | None = None
        self._system_key: tuple[int, int] = (-1, -1)

    # ----------------------------------------------------------------- building

    def __len__(self) -> int:
        return self._n

    @property
    def num_nodes(self) -> int:
        """Number of nodes."""
        return self._n

    @property
    def num_edges(self) -> int:
        """Number of edges."""
        return self._m

    def add_node(self, pose: ArrayLike) -> int:
        """Append a node at ``pose (3,)`` ``(x, y, theta)`` (world frame); returns its index."""
        p = np.asarray(pose, dtype=np.float64)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"pose must be 3 finite numbers (x, y, theta), got {pose!r}")
        if self._n == self._poses.shape[0]:
            self._poses = _grow(self._poses, self._n)
        self._poses[self._n] = p
        self._n += 1
        return self._n - 1

    def add_edge(
        self,
        i: int,
        j: int,
        measurement: ArrayLike,
        information: ArrayLike,
        *,
        robust: bool = False,
    ) -> int:
        """Append an edge: ``measurement (3,)`` is node ``j``'s pose in node ``i``'s frame,
        ``information (3, 3)`` its information matrix; ``robust`` puts the edge under the
        config's robust kernel. Returns the edge index."""
        return int(
            self.add_edges(
                [[i, j]],
                np.asarray(measurement, dtype=np.float64)[None],
                np.asarray(information, dtype=np.float64)[None],
                robust=np.array([bool(robust)]),
            )[0]
        )

    def set_robust(self, edges: ArrayLike, robust: bool) -> None:
        """Put edges ``edges`` (indices) under the robust kernel or take them out of it, e.g.
        to let verified loop closures pull a drifted estimate quadratically once, then guard
        them robustly from the next optimization on."""
        idx = np.asarray(edges, dtype=np.int64).reshape(-1)
        if idx.size and (idx.min() < 0 or idx.max() >= self._m):
            raise ValueError(f"edge indices must lie in 0..{self._m - 1}")
        self._robust[idx] = bool(robust)

    def set_information(self, edges: ArrayLike, information: ArrayLike) -> None:
        """Set the information matrix (3, 3) of edges ``edges`` (indices); a zero matrix
        leaves an edge in the graph without effect (a loop closure found inconsistent), a
        later call can restore it."""
        idx = np.asarray(edges, dtype=np.int64).reshape(-1)
        if idx.size and (idx.min() < 0 or idx.max() >= self._m):
            raise ValueError(f"edge indices must lie in 0..{self._m - 1}")
        om = np.asarray(information, dtype=np.float64)
        if om.shape != (3, 3) or not np.isfinite(om).all():
            raise ValueError(f"information must be a finite (3, 3) matrix, got shape {om.shape}")
        self._info[idx] = 0.5 * (om + om.T)

    def add_edges(
        self,
        edges: ArrayLike,
        measurements: ArrayLike,
        information: ArrayLike,
        *,
        robust: bool | ArrayLike = False,
    ) -> IntArray:
        """Append ``K`` edges at once (``edges (K, 2)``, ``measurements (K, 3)``,
        ``information (K, 3, 3)``, ``robust`` a bool or ``(K,)`` bools); returns their
        indices ``(K,)``."""
        e = np.asarray(edges)
        K = e.shape[0] if e.ndim == 2 else -1
        ei, ej, z, om = _as_edges(e, measurements, information, self._n)
        rb = np.broadcast_to(np.asarray(robust, dtype=np.bool_), (K,))
        while self._m + K > self._ij.shape[0]:
            cap = self._m
            self._ij = _grow(self._ij, cap)
            self._z = _grow(self._z, cap)
            self._info = _grow(self._info, cap)
            self._robust = _grow(self._robust, cap)
        s = slice(self._m, self._m + K)
        self._ij[s, 0] = ei
        self._ij[s, 1] = ej
        self._z[s] = z
        self._info[s] = 0.5 * (om + om.transpose(0, 2, 1))
        self._robust[s] = rb
        self._m += K
        return np.arange(s.start, s.stop, dtype=np.int64)

    # ----------------------------------------------------------------- state

    @property
    def poses(self) -> FloatArray:
        """Current poses, ``(N, 3)`` ``(x, y, theta)`` (a copy)."""
        return self._poses[: self._n].copy()

    @poses.setter
    def poses(self, value: ArrayLike) -> None:
        p = pose_batch(value)
        if p.shape[0] != self._n:
            raise ValueError(f"poses must have shape ({self._n}, 3), got {p.shape}")
        self._poses[: self._n] = p

    def pose(self, index: int) -> FloatArray:
        """The current pose ``(3,)`` of one node (a copy; cheaper than ``poses[index]``)."""
        if not -self._n <= index < self._n:
            raise IndexError(f"node {index} out of range for {self._n} nodes")
        return self._poses[index % self._n].copy()

    # One property per edge array (alike but for the array): each has its own shape and type.
    @property
    def edges(self) -> IntArray:
        """Node indices ``(E, 2)`` of the edges (a copy)."""
        return self._ij[: self._m].copy()

    @property
    def measurements(self) -> FloatArray:
        """Edge measurements ``(E, 3)`` (a copy)."""
        return self._z[: self._m].copy()

    @property
    def information(self) -> FloatArray:
        """Edge information matrices ``(E, 3, 3)`` (a copy)."""
        return self._info[: self._m].copy()

    @property
    def robust_mask(self) -> BoolArray:
        """Which edges are under the robust kernel, ``(E,)`` (a copy)."""
        return self._robust[: self._m].copy()

    def _arrays(self) -> tuple[FloatArray, IntArray, IntArray, FloatArray, FloatArray, BoolArray]:
        m = self._m
        return (
            self._poses[: self._n],
            np.ascontiguousarray(self._ij[:m, 0]),
            np.ascontiguousarray(self._ij[:m, 1]),
            self._z[:m],
            self._info[:m],
            self._robust[:m],
        )

    def error(self) -> float:
        """Current cost ``0.5 * sum rho(e' Omega e)`` (GTSAM's convention)."""
        x, ei, ej, z, om, rb = self._arrays()
        return _cost(x, _graph(ei, ej, z, om, rb, self.config))

    # ----------------------------------------------------------------- optimization

    def _normal_equations(self, ei: IntArray, ej: IntArray) -> _NormalEquations:
        key = (self._n, self._m)
        if self._system is None or self._system_key != key:
            fixed = _as_fixed(self._fixed, self._n)
            self._system = _NormalEquations(self._n, ei, ej, fixed)
            self._system_key = key
        return self._system

    def initialize(self) -> None:
        """Replace the poses of the free nodes by :func:`lago_initialization`'s estimate."""
        x, ei, ej, z, om, _ = self._arrays()
        if self._n == 0:
            raise ValueError("the graph has no nodes")
        self._poses[: self._n] = _lago(x, ei, ej, z, om, self._normal_equations(ei, ej))

    def optimize(
        self, max_iterations: int | None = None, *, verify: bool = False
    ) -> OptimizeResult:
        """Levenberg-Marquardt from the current poses; the optimized poses replace them.

        Parameters
        ----------
        max_iterations : int, optional
            Overrides ``config.max_iterations`` for this call.
        verify : bool
            Check a result the tolerances stopped at as :func:`optimize_pose_graph` does (a
            minimum with a sane cost) before calling it converged. Off by default: an
            incremental back end optimizes a few warm-started iterations at a time and does
            not read the flag, and the check costs about one more factorization (10-20 ms on
            M3500).

        Returns
        -------
        OptimizeResult
            ``poses`` is a copy of the new poses.
        """
        t0 = time.perf_counter()
        its = self.config.max_iterations if max_iterations is None else int(max_iterations)
        require_at_least("max_iterations", its, 0)
        x, ei, ej, z, om, rb = self._arrays()
        if self._n == 0:
            raise ValueError("the graph has no nodes")
        system = self._normal_equations(ei, ej)
        graph = _graph(ei, ej, z, om, rb, self.config)
        F0 = _cost(x, graph)
        out, F, n_it, conv, msg, chi2, w = _levenberg_marquardt(
            x, graph, system, self.config, its, verify=verify
        )
        self._poses[: self._n] = out
        return OptimizeResult(out.copy(), F0, F, n_it, time.perf_counter() - t0, conv, w, chi2, msg)


_Arr = TypeVar("_Arr", bound=NDArray[Any])


def _grow(a: _Arr, used: int) -> _Arr:
    """A copy of ``a`` with twice the rows (at least 16), the first ``used`` rows kept."""
    out = np.zeros((max(2 * a.shape[0], 16), *a.shape[1:]), dtype=a.dtype)
    out[:used] = a[:used]
    return out  # type: ignore[return-value]  # same dtype and rank as ``a``
