"""Optimizing a pose graph read from a file (``probmap optimize``): the settings of a run and
the run itself.

The optimizer is :func:`probmap.slam.posegraph.optimize.optimize_pose_graph` (sparse
Levenberg-Marquardt with robust kernels); the files are read and written by
:mod:`probmap.datasets.g2o`. This module holds what the command adds: which edges the robust
kernel applies to, where the optimization starts, and the gauge (the file's ``FIX`` nodes, else
the first node).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from probmap.datasets.g2o import PoseGraph, PoseGraphArrays, pose_graph_arrays
from probmap.slam.posegraph.optimize import (
    OptimizerConfig,
    OptimizeResult,
    optimize_pose_graph,
)

__all__ = ["PoseGraphConfig", "PoseGraphRun", "check_determined", "optimize_graph"]


@dataclass(frozen=True)
class PoseGraphConfig(OptimizerConfig):
    """Settings of ``probmap optimize``: the optimizer's (inherited from
    :class:`OptimizerConfig`, the one home of their fields and defaults) and the command's own;
    loadable from and dumpable to YAML with :mod:`probmap.config`::

        robust: huber
        max_iterations: 50
        robust_edges: closures

    Attributes
    ----------
    max_iterations, relative_tolerance, absolute_tolerance, initial_lambda, max_lambda, damping
        Levenberg-Marquardt's iterations, tolerances and damping (see :class:`OptimizerConfig`).
    robust : {"none", "huber", "cauchy", "dcs"}
        Robust kernel of the edges :attr:`robust_edges` selects.
    robust_scale : float or None
        Kernel scale (Huber/Cauchy ``k`` in Mahalanobis-distance units, DCS ``Phi`` in chi2
        units); ``None``: the kernel's default, resolved when the optimizer's configuration is
        built, so that a file or an option naming another kernel gets that kernel's default.
    chart : {"logmap", "xyt"}
        Residual of an edge (GTSAM's or g2o's).
    robust_edges : {"all", "closures"}
        The edges under the robust kernel: all, or every edge but the ``i -> i+1`` odometry.
    init : {"auto", "given", "lago"}
        Start from the file's poses (``given``) or from the linear LAGO estimate (``lago``);
        ``auto`` is ``lago`` without a robust kernel and ``given`` with one (LAGO is not
        robust to false edges).
    """

    robust_edges: Literal["all", "closures"] = "all"
    init: Literal["auto", "given", "lago"] = "auto"

    def __post_init__(self) -> None:
        # not OptimizerConfig's, which would resolve robust_scale: it stays None here
        self.optimizer()  # the optimizer's own rules on its fields
        if self.robust_edges not in ("all", "closures"):
            raise ValueError(f"robust_edges must be 'all' or 'closures', got {self.robust_edges!r}")
        if self.init not in ("auto", "given", "lago"):
            raise ValueError(f"init must be auto, given or lago, got {self.init!r}")

    def optimizer(self) -> OptimizerConfig:
        """The optimizer's configuration (its robust scale resolved)."""
        names = [f.name for f in fields(OptimizerConfig)]
        return OptimizerConfig(**{name: getattr(self, name) for name in names})

    @property
    def scale(self) -> float:
        """The resolved robust scale (the kernel's default when :attr:`robust_scale` is None)."""
        return self.optimizer().scale

    @property
    def start(self) -> Literal["given", "lago"]:
        """The start ``auto`` resolves to (see :attr:`init`)."""
        if self.init == "auto":
            return "lago" if self.robust == "none" else "given"
        return self.init


@dataclass(frozen=True)
class PoseGraphRun:
    """What :func:`optimize_graph` returns.

    Attributes
    ----------
    arrays : PoseGraphArrays
        The graph's poses and edges as arrays, with the id of every row.
    fixed : tuple of int
        Rows of the nodes held fixed (the gauge).
    result : OptimizeResult
        The optimizer's result (``result.poses``, shape (N, 3), rows as ``arrays.ids``).
    """

    arrays: PoseGraphArrays
    fixed: tuple[int, ...]
    result: OptimizeResult


def optimize_graph(graph: PoseGraph, config: PoseGraphConfig | None = None) -> PoseGraphRun:
    """Optimize the pose edges of ``graph`` with the settings ``config``.

    The gauge is the graph's ``FIX`` nodes, or its first node when it has none.

    Raises
    ------
    ValueError
        A graph the optimizer refuses (landmark edges, an under-determined graph:
        :func:`check_determined`, ...).
    """
    cfg = config if config is not None else PoseGraphConfig()
    a = pose_graph_arrays(graph)
    fixed = tuple(int(i) for i in a.fixed) if a.fixed.size else (0,)
    check_determined(a, fixed)
    ids = a.ids[a.edges]
    # odometry edges join consecutive ids; every other edge is a loop closure
    mask = None if cfg.robust_edges == "all" else np.abs(ids[:, 1] - ids[:, 0]) != 1
    r = optimize_pose_graph(
        a.poses,
        a.edges,
        a.measurements,
        a.information,
        cfg.optimizer(),
        fixed=fixed,
        robust_mask=mask,
        init=cfg.start,
    )
    return PoseGraphRun(a, fixed, r)


def _named(ids: NDArray[np.int64], rows: NDArray[np.int64], shown: int = 5) -> str:
    """``"vertices 4, 7 and 9"`` / ``"vertices 4, 7, 9, 11, 12, ... (40 in all)"``."""
    names = [str(int(ids[r])) for r in rows[:shown]]
    if rows.size == 1:
        return f"vertex {names[0]}"
    if rows.size <= shown:
        return f"vertices {', '.join(names[:-1])} and {names[-1]}"
    return f"vertices {', '.join(names)}, ... ({rows.size:,} in all)"


def _loose(
    n: int, edges: NDArray[np.int64], keep: NDArray[np.bool_], fixed: tuple[int, ...]
) -> NDArray[np.int64]:
    """Rows not joined to a fixed row through the edges ``keep`` selects."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    e = edges[keep]
    adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    tied = np.isin(label, label[list(fixed)])
    return np.flatnonzero(~tied)


def check_determined(a: PoseGraphArrays, fixed: tuple[int, ...]) -> None:
    """Raise unless the edges determine every pose: each vertex is joined to a fixed one by
    edges that carry information, on position and on heading, and some edge constrains every
    direction of the plane. The messages name vertex ids (the file's), never rows.

    Raises
    ------
    ValueError
        Every edge's information is zero; vertices joined to no fixed vertex (disconnected
        parts), or only by edges without position or heading information; a direction of
        the plane that no edge constrains.
    """
    n = len(a.ids)
    free = np.setdiff1d(np.arange(n), np.asarray(fixed, dtype=np.int64))
    if free.size == 0:
        return
    info = np.asarray(a.information, dtype=np.float64).reshape(-1, 3, 3)
    if len(info) and not np.any(info):
        raise ValueError("every edge has zero information: nothing constrains the poses")
    any_info = np.abs(info).reshape(-1, 9).max(axis=1) > 0
    xy = np.abs(info[:, :2, :2]).reshape(-1, 4).max(axis=1) > 0
    heading = info[:, 2, 2] > 0
    for keep, what in (
        (np.ones(len(info), dtype=bool), "by any edge (a separate part of the graph)"),
        (any_info, "by any edge with nonzero information"),
        (xy, "by edges with position information: their positions are undetermined"),
        (heading, "by edges with heading information: their headings are undetermined"),
    ):
        loose = _loose(n, a.edges, keep, fixed)
        if loose.size:
            fixed_ids = ", ".join(str(int(a.ids[f])) for f in fixed)
            raise ValueError(
                f"{_named(a.ids, loose)} {'is' if loose.size == 1 else 'are'} not joined to "
                f"the fixed vertex ({fixed_ids}) {what}"
            )
    # the position information of every edge in the world frame (rotated by the heading of
    # its first vertex): a direction none of it constrains leaves every position free along it
    th = a.poses[a.edges[:, 0], 2]
    c, s_ = np.cos(th), np.sin(th)
    R = np.stack([np.stack([c, -s_], axis=1), np.stack([s_, c], axis=1)], axis=1)
    world = np.einsum("eij,ejk,elk->il", R, info[:, :2, :2], R)
    w, v = np.linalg.eigh(world)
    if w[0] <= 1e-12 * max(w[-1], 1e-300):
        d = v[:, 0]
        raise ValueError(
            f"no edge constrains the direction ({d[0]:.3g}, {d[1]:.3g}) of the plane: the "
            f"positions of {_named(a.ids, free)} are undetermined along it"
        )
