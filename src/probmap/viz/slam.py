"""Plots of landmark-SLAM results (axes first; the caller owns the figure)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from probmap._atomic import atomic_path

__all__ = ["covariance_ellipse", "plot_slam", "save_slam_figure"]


def covariance_ellipse(
    mean: np.ndarray, cov: np.ndarray, n_sigma: float = 2.0, n_points: int = 36
) -> np.ndarray:
    """Points (n_points + 1, 2) of the ``n_sigma`` ellipse of a 2-D Gaussian."""
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    vals = np.clip(vals, 0.0, None)
    t = np.linspace(0, 2 * np.pi, n_points + 1)
    circle = np.stack([np.cos(t), np.sin(t)], -1)
    return mean + n_sigma * (circle * np.sqrt(vals)) @ vecs.T


def plot_slam(ax: Any, result: Any, dataset: Any = None, *, title: str | None = None) -> Any:
    """Draw the estimated trajectory, landmarks with 2-sigma ellipses, and any truth or GPS.

    Parameters
    ----------
    ax : matplotlib Axes
    result : SlamResult
    dataset : LandmarkDataset, optional
        Supplies ``gt_trajectory``, ``landmark_truth`` and ``gps`` when present.
    """
    if dataset is not None:
        gt = getattr(dataset, "gt_trajectory", None)
        if gt is not None:
            ax.plot(gt[:, 1], gt[:, 2], color="0.6", lw=0.8, label="ground truth")
        gps = getattr(dataset, "gps", None)
        if gps is not None:
            ax.plot(gps[:, 1], gps[:, 2], ".", color="tab:green", ms=1.5, label="GPS (raw frame)")
        truth = getattr(dataset, "landmark_truth", None)
        if truth:
            xy = np.array(list(truth.values()))
            ax.plot(xy[:, 0], xy[:, 1], "k+", ms=7, label="true landmarks")
    tr = result.trajectory
    ax.plot(tr[:, 1], tr[:, 2], color="tab:blue", lw=1.0, label="estimate")
    for m, c in zip(result.landmark_xy, result.landmark_cov, strict=True):
        e = covariance_ellipse(m, c)
        ax.plot(e[:, 0], e[:, 1], color="tab:red", lw=0.6)
    if len(result.landmark_xy):
        ax.plot(*result.landmark_xy.T, "r.", ms=3, label="landmarks (2-sigma)")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title)
    ax.legend(loc="best", fontsize=7)
    return ax


def save_slam_figure(
    path: str | os.PathLike[str], result: Any, dataset: Any = None, *, title: str | None = None
) -> Path:
    """Render :func:`plot_slam` to an image file (Agg backend, written atomically)."""
    from matplotlib.figure import Figure

    path = Path(path)
    fig = Figure(figsize=(8, 8))
    plot_slam(fig.add_subplot(), result, dataset, title=title)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches="tight")
    return path
