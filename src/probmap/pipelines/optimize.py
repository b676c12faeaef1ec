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

from probmap.datasets.g2o import PoseGraph, PoseGraphArrays, pose_graph_arrays
from probmap.slam.posegraph.optimize import (
    OptimizerConfig,
    OptimizeResult,
    optimize_pose_graph,
)

__all__ = ["PoseGraphConfig", "PoseGraphRun", "optimize_graph"]


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
        A graph the optimizer refuses (landmark edges, nodes not connected to a fixed one,
        ...).
    """
    cfg = config if config is not None else PoseGraphConfig()
    a = pose_graph_arrays(graph)
    fixed = tuple(int(i) for i in a.fixed) if a.fixed.size else (0,)
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
