"""Pictures of grid-SLAM results: the map with the trajectory on top, the accepted loop
closures as a light layer under it, start and end markers, a scale bar, the doubtful places,
axes in metres (axes first; the caller owns the figure); and the before-and-after picture of
a pose graph that ``probmap optimize`` writes."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from probmap.viz.maps import (
    _extent,
    _start_end,
    add_scale_bar,
    draw_grid,
    label_metric_axes,
    legend_below,
    map_figure,
    map_legend_handles,
    save_picture,
)

__all__ = [
    "graph_slam_subtitle",
    "plot_graph_slam",
    "save_graph_slam_figure",
    "save_pose_graph_figure",
]

# the closures' layer: light and thin, so that thousands of them leave the trajectory readable
_CLOSURE_ALPHA = 0.06
_CLOSURE_LW = 0.25


def _left_out(run: Any, n: int) -> NDArray[np.bool_]:
    """Per closure of ``run``, whether the pairwise check left it out of the graph (rejected:
    neither drawn nor counted); all False for a run without the check."""
    mask = getattr(getattr(getattr(run, "slam", None), "loops", None), "left_out", None)
    if mask is None or len(mask) != n:
        return np.zeros(n, dtype=bool)
    return np.asarray(mask, dtype=bool)


def graph_slam_subtitle(run: Any) -> str:
    """The picture's second line: scans, loop closures (and how many the robust cost
    down-weighted), and the real-time factor.

    >>> from types import SimpleNamespace as NS
    >>> run = NS(times=np.zeros(910), closure_weights=np.array([1.0, 0.2, 0.9]),
    ...          duration=2700.0, seconds=30.0)
    >>> graph_slam_subtitle(run)
    '910 scans, 3 loop closures (1 down-weighted), 90x real time'
    """
    weights = np.asarray(run.closure_weights, dtype=np.float64)
    weights = weights[~_left_out(run, len(weights))]
    low = int(np.sum(weights < 0.5))
    closures = f"{len(weights):,} loop closures" + (f" ({low:,} down-weighted)" if low else "")
    parts = [f"{len(run.times):,} scans", closures]
    duration, seconds = float(run.duration), float(run.seconds)
    if duration > 0 and seconds > 0:
        rtf = duration / seconds
        parts.append(f"{rtf:.0f}x real time" if rtf >= 10 else f"{rtf:.1f}x real time")
    return ", ".join(parts)


def plot_graph_slam(
    ax: Any,
    run: Any,
    *,
    title: str | None = None,
    max_pixels: int | None = None,
    doubts: Sequence[dict[str, Any]] = (),
) -> Any:
    """Draw ``run.grid`` (free white, occupied black, never observed blue-grey), the accepted
    closures as a light layer of thin segments from each node to the anchor of the submap it
    matched (green: kept by the robust cost, red: down-weighted below 0.5; those the pairwise
    check left out are rejected and not drawn), the robot
    trajectory ``run.poses`` on top with its start (circle) and end (square), a scale bar, and
    a red box around each doubtful place (``doubts``: the report's entries with a ``box_m``,
    see :func:`probmap.pipelines.laser_slam.doubts_of`). The title is ``title`` over
    :func:`graph_slam_subtitle`; the legend lies under the map.

    Parameters
    ----------
    ax : matplotlib Axes
    run : SubmapSlamRun
        From :func:`probmap.pipelines.laser_slam.run_submap_slam`.
    title : str, optional
        Usually ``graph SLAM: LOG`` (the input's name).
    max_pixels : int, optional
        The most pixels of the map's longer side (default
        :data:`probmap.viz.maps.MAX_PICTURE_PIXELS`).
    doubts : sequence of dict
        Entries with ``box_m = [x_min, y_min, x_max, y_max]`` (metres, map frame).
    """
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D
    from matplotlib.patches import Rectangle

    grid = run.grid
    if max_pixels is None:
        draw_grid(ax, grid)
    else:
        draw_grid(ax, grid, max_pixels=max_pixels)
    nodes = np.asarray(run.node_poses, dtype=np.float64).reshape(-1, 3)
    pairs = np.asarray(run.closures, dtype=np.int64).reshape(-1, 2)
    weights = np.asarray(run.closure_weights, dtype=np.float64).reshape(-1)
    accepted = ~_left_out(run, len(weights))
    pairs, weights = pairs[accepted], weights[accepted]
    segments = np.stack([nodes[pairs[:, 0], :2], nodes[pairs[:, 1], :2]], axis=1)
    kept = weights >= 0.5
    # one collection per colour: fast for thousands of closures, and under the trajectory
    ax.add_collection(
        LineCollection(
            list(segments[kept]), colors="tab:green", linewidths=_CLOSURE_LW, alpha=_CLOSURE_ALPHA,
            zorder=2,
        )
    )  # fmt: skip
    ax.add_collection(
        LineCollection(
            list(segments[~kept]),
            colors="tab:red",
            linewidths=_CLOSURE_LW,
            alpha=4 * _CLOSURE_ALPHA,
            zorder=2,
        )
    )
    poses = np.asarray(run.poses, dtype=np.float64).reshape(-1, 3)
    handles: list[Any] = []
    if len(poses):
        handles += ax.plot(
            poses[:, 0], poses[:, 1], color="tab:blue", lw=0.7, zorder=3, label="trajectory"
        )
        handles += _start_end(ax, poses)
    handles.append(
        Line2D([], [], color="tab:green", lw=1.0, alpha=0.6,
               label=f"loop closures ({int(kept.sum()):,})")
    )  # fmt: skip
    if not kept.all():
        handles.append(
            Line2D([], [], color="tab:red", lw=1.0, label=f"down-weighted ({int((~kept).sum()):,})")
        )
    boxes = [d["box_m"] for d in doubts if "box_m" in d]
    for bx0, by0, bx1, by1 in boxes:
        pad = 1.0  # metres around the contradicted walls, so a small place shows
        ax.add_patch(
            Rectangle(
                (bx0 - pad, by0 - pad), bx1 - bx0 + 2 * pad, by1 - by0 + 2 * pad, fill=False,
                edgecolor="red", lw=1.2, zorder=4,
            )
        )  # fmt: skip
    if boxes:
        handles.append(Line2D([], [], color="red", lw=1.2, label=f"doubtful places ({len(boxes)})"))
    add_scale_bar(ax, _extent(grid))
    label_metric_axes(ax)
    legend_below(ax, handles + map_legend_handles(), ncol=4)
    ax.set_title(title or "", fontsize=10, loc="left", pad=14)  # the pad is every title's
    ax.text(
        0.0, 1.01, graph_slam_subtitle(run), transform=ax.transAxes, fontsize=8, va="bottom",
        ha="left",
    )  # fmt: skip
    r = grid.spec.resolution
    h, w = grid.spec.shape
    ax.set_title(f"{w} x {h} cells at {r:g} m", fontsize=8, loc="right", pad=14)
    return ax


def save_graph_slam_figure(
    path: str | os.PathLike[str],
    run: Any,
    *,
    title: str | None = None,
    doubts: Sequence[dict[str, Any]] = (),
) -> Path:
    """Render :func:`plot_graph_slam` to a PNG (written atomically, at a size that shows a
    large map's walls: :func:`probmap.viz.maps.save_picture`)."""
    fig = map_figure(run.grid, width=9.0)
    ax = fig.add_subplot()
    plot_graph_slam(ax, run, title=title, doubts=doubts)
    return save_picture(fig, ax, path)


def _graph_layer(
    ax: Any, poses: np.ndarray, ids: np.ndarray, edges: np.ndarray, weights: Any = None
) -> None:
    """A pose graph on ``ax``: the chain of odometry edges (consecutive ids) as the robot's
    path on top, every other edge (a loop closure) as a light thin line under it (red where
    ``weights`` < 0.5), the first node marked; limits, metres and a scale bar."""
    from matplotlib.collections import LineCollection

    xy = poses[:, :2]
    pairs = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    seg = np.stack([xy[pairs[:, 0]], xy[pairs[:, 1]]], axis=1)
    chain = np.abs(ids[pairs[:, 1]] - ids[pairs[:, 0]]) == 1
    low = np.zeros(len(pairs), bool) if weights is None else np.asarray(weights) < 0.5
    ax.add_collection(
        LineCollection(seg[~chain & ~low], colors="tab:green", linewidths=0.3, alpha=0.25,
                       zorder=2)
    )  # fmt: skip
    ax.add_collection(
        LineCollection(seg[~chain & low], colors="tab:red", linewidths=0.3, alpha=0.5, zorder=2)
    )
    ax.add_collection(LineCollection(seg[chain], colors="tab:blue", linewidths=0.6, zorder=3))
    ax.plot(xy[:1, 0], xy[:1, 1], "o", color="tab:blue", mec="white", mew=0.6, ms=6, zorder=4)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    pad = 0.05 * max(float(np.max(hi - lo)), 1e-6)
    x0, y0, x1, y1 = lo[0] - pad, lo[1] - pad, hi[0] + pad, hi[1] + pad
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    add_scale_bar(ax, (x0, y0, x1, y1))
    label_metric_axes(ax)


def save_pose_graph_figure(
    path: str | os.PathLike[str],
    ids: Any,
    edges: Any,
    before: Any,
    after: Any,
    *,
    title: str | None = None,
    before_label: str = "before: the file's poses",
    after_label: str = "after: optimized",
    weights: Any = None,
) -> Path:
    """Write a before-and-after picture of a pose graph (``probmap optimize``): two panels
    side by side, each with its own metres and scale bar; the odometry chain (edges between
    consecutive ids) drawn as the robot's path on top of a light layer of loop closures
    (red: down-weighted below 0.5 by a robust kernel, in ``weights``).

    Parameters
    ----------
    path : path-like
        The PNG (written atomically).
    ids : (N,) array_like
        Vertex ids, row order of the poses.
    edges : (E, 2) array_like
        Row indices of each edge's two vertices.
    before, after : (N, 3) array_like
        Poses before and after the optimization.
    title : str, optional
        Usually the graph file's name.
    before_label, after_label : str
        The panels' titles (the errors, the iterations).
    weights : (E,) array_like, optional
        The robust kernel's final weights.
    """
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    b = np.asarray(before, dtype=np.float64).reshape(-1, 3)
    a = np.asarray(after, dtype=np.float64).reshape(-1, 3)
    if not (len(ids) == len(b) == len(a)):
        raise ValueError(f"ids {ids.shape}, before {b.shape} and after {a.shape} disagree")
    fig = Figure(figsize=(13, 5.5))
    axes = fig.subplots(1, 2)
    _graph_layer(axes[0], b, ids, edges)
    _graph_layer(axes[1], a, ids, edges, weights)
    axes[0].set_title(before_label, fontsize=9, loc="left")
    axes[1].set_title(after_label, fontsize=9, loc="left")
    if title:
        fig.suptitle(title, fontsize=11, x=0.07, ha="left")
    pairs = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    chain = int(np.sum(np.abs(ids[pairs[:, 1]] - ids[pairs[:, 0]]) == 1))
    handles = [
        Line2D([], [], color="tab:blue", lw=1.0, label=f"odometry chain ({chain:,} edges)"),
        Line2D([], [], color="tab:green", lw=1.0,
               label=f"loop closures ({len(pairs) - chain:,})"),
        Line2D([], [], color="tab:blue", marker="o", ls="", label="first node"),
    ]  # fmt: skip
    if weights is not None and np.any(np.asarray(weights) < 0.5):
        n = int(np.sum(np.asarray(weights) < 0.5))
        handles.append(Line2D([], [], color="tab:red", lw=1.0, label=f"down-weighted ({n:,})"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8, frameon=False)
    fig.subplots_adjust(bottom=0.14)
    return save_picture(fig, axes[1], path, dpi=150)
