"""Pictures of grid-SLAM results: the map with the trajectory and the accepted loop closures,
axes in metres (axes first; the caller owns the figure)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from probmap.viz.maps import label_metric_axes, sampled_cells

__all__ = ["plot_graph_slam", "save_graph_slam_figure"]


def plot_graph_slam(
    ax: Any,
    run: Any,
    *,
    title: str | None = None,
    max_pixels: int = 2000,
    doubts: Sequence[dict[str, Any]] = (),
) -> Any:
    """Draw ``run.grid`` (occupied black, free white, unknown grey), the robot trajectory
    ``run.poses``, each accepted closure as a segment from the node to the anchor of the
    submap it matched (green: kept by the robust cost, red: down-weighted below 0.5), and a
    red box around each doubtful place (``doubts``: the report's entries with a ``box_m``,
    see :func:`probmap.pipelines.laser_slam.doubts_of`).

    Parameters
    ----------
    ax : matplotlib Axes
    run : SubmapSlamRun
        From :func:`probmap.pipelines.laser_slam.run_submap_slam`.
    title : str, optional
    doubts : sequence of dict
        Entries with ``box_m = [x_min, y_min, x_max, y_max]`` (metres, map frame).
    max_pixels : int
        The map is drawn from every ``step``-th cell so that its longer side has at most this
        many pixels.
    """
    grid = run.grid
    x0, y0 = grid.spec.origin
    r = grid.spec.resolution
    h, w = grid.spec.shape
    # every step-th cell: matplotlib would otherwise resample all of them in RGBA
    lo, seen, _ = sampled_cells(grid, max_pixels)
    img = np.where(seen, 1.0 / (1.0 + np.exp(lo, dtype=np.float32)), np.float32(0.8))
    ax.imshow(
        img, cmap="gray", vmin=0.0, vmax=1.0, origin="lower", extent=(x0, x0 + w * r, y0, y0 + h * r),
        interpolation="nearest",
    )  # fmt: skip
    nodes = run.node_poses
    weights = np.asarray(run.closure_weights)
    for (k, a), wgt in zip(run.closures, weights, strict=True):
        colour = "tab:green" if wgt >= 0.5 else "tab:red"
        ax.plot(
            [nodes[k, 0], nodes[a, 0]], [nodes[k, 1], nodes[a, 1]], color=colour, lw=0.3,
            alpha=0.25,
        )  # fmt: skip
    ax.plot(run.poses[:, 0], run.poses[:, 1], color="tab:blue", lw=0.5, label="trajectory")
    from matplotlib.patches import Rectangle

    boxes = [d["box_m"] for d in doubts if "box_m" in d]
    for bx0, by0, bx1, by1 in boxes:
        pad = 1.0  # metres around the contradicted walls, so a small place shows
        ax.add_patch(
            Rectangle(
                (bx0 - pad, by0 - pad), bx1 - bx0 + 2 * pad, by1 - by0 + 2 * pad, fill=False,
                edgecolor="red", lw=1.2,
            )
        )  # fmt: skip
    if boxes:
        ax.plot([], [], color="red", lw=1.2, label=f"doubtful places ({len(boxes)})")
    kept = int(np.sum(weights >= 0.5))
    ax.plot([], [], color="tab:green", lw=0.8, label=f"loop closures ({kept})")
    if kept < len(weights):
        ax.plot([], [], color="tab:red", lw=0.8, label=f"down-weighted ({len(weights) - kept})")
    return label_metric_axes(ax, title, legend="upper right")


def save_graph_slam_figure(
    path: str | os.PathLike[str],
    run: Any,
    *,
    title: str | None = None,
    doubts: Sequence[dict[str, Any]] = (),
) -> Path:
    """Render :func:`plot_graph_slam` to a PNG (Agg backend, written atomically)."""
    from matplotlib.figure import Figure

    from probmap._atomic import atomic_write

    path = Path(path)
    fig = Figure(figsize=(9, 9))
    plot_graph_slam(fig.add_subplot(), run, title=title, doubts=doubts)
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=150, bbox_inches="tight")
    return path
