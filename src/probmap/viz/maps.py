"""Pictures of occupancy maps people can read: axes in metres, a scale bar, a title, the
trajectory (axes first; the caller owns the figure)."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "label_metric_axes",
    "map_image",
    "nice_length",
    "plot_map",
    "sampled_cells",
    "save_map_figure",
]


def nice_length(span: float) -> float:
    """A round length (1, 2 or 5 times a power of ten, metres) of about a fifth of ``span``,
    for a scale bar.

    >>> nice_length(47.0), nice_length(460.0), nice_length(3.0)
    (5.0, 50.0, 0.5)
    """
    if not (math.isfinite(span) and span > 0):
        raise ValueError(f"span must be a positive length, got {span}")
    target = span / 5.0
    base = 10.0 ** math.floor(math.log10(target))
    for m in (5.0, 2.0, 1.0):
        if m * base <= target:
            return m * base
    return base  # pragma: no cover - target >= base always holds


def label_metric_axes(ax: Any, title: str | None = None, *, legend: str | None = None) -> Any:
    """Finish a plot in world coordinates: equal aspect, both axes labelled in metres, the
    ``title`` if given, and a small legend at ``legend`` (a matplotlib ``loc``) if given.

    The one place every picture of :mod:`probmap.viz` labels its axes, so that they all read
    the same. Returns ``ax``.
    """
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title)
    if legend is not None:
        ax.legend(loc=legend, fontsize=7)
    return ax


def sampled_cells(grid: Any, max_pixels: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Every ``step``-th row and column of ``grid``'s log odds and observed mask, and
    ``step``: the smallest that leaves the longer side at most ``max_pixels``. What every
    picture of a map draws (a picture has a few thousand pixels a side; a large building's map
    has tens of millions of cells)."""
    h, w = grid.spec.shape
    step = max(1, -(-max(h, w) // max_pixels))
    lo = np.asarray(grid.log_odds)[::step, ::step]
    seen = np.asarray(grid.observed)[::step, ::step]
    return lo, seen, step


def map_image(grid: Any, max_pixels: int = 2000) -> tuple[np.ndarray, int]:
    """Grey levels (0 black .. 1 white) of every ``step``-th cell, row 0 at the smallest y:
    free white (p <= 0.25), occupied black (p >= 0.75), linear between, unknown mid-grey (the
    map PNG's palette). Returns the image and ``step`` (the longer side has at most
    ``max_pixels``)."""
    lo, seen, step = sampled_cells(grid, max_pixels)
    p = 1.0 - 1.0 / (1.0 + np.exp(lo.astype(np.float64)))
    grey = np.clip((0.75 - p) / 0.5, 0.0, 1.0)
    return np.where(seen, grey, 0.5), step


def plot_map(
    ax: Any,
    grid: Any,
    *,
    trajectory: ArrayLike | None = None,
    title: str | None = None,
    max_pixels: int = 2000,
) -> Any:
    """Draw an occupancy grid in the world frame (metres) with a scale bar and, optionally,
    a trajectory.

    Parameters
    ----------
    ax : matplotlib Axes
    grid : OccupancyGrid
    trajectory : array_like, shape (T, 2) or (T, 3), optional
        Poses (x, y[, theta]) in the map's frame, metres; drawn as a blue line with its start
        marked.
    title : str, optional
        Usually the input's name.
    max_pixels : int
        The map is drawn from every ``step``-th cell so that its longer side has at most this
        many pixels.

    Returns
    -------
    matplotlib Axes
    """
    from matplotlib.patches import Rectangle

    img, _ = map_image(grid, max_pixels)
    x0, y0, x1, y1 = _extent(grid)
    ax.imshow(
        img, cmap="gray", vmin=0.0, vmax=1.0, origin="lower", extent=(x0, x1, y0, y1),
        interpolation="nearest",
    )  # fmt: skip
    if trajectory is not None:
        t = np.asarray(trajectory, dtype=np.float64)
        if t.ndim != 2 or t.shape[1] not in (2, 3):
            raise ValueError(f"trajectory must be (T, 2) or (T, 3), got {t.shape}")
        if len(t):
            ax.plot(t[:, 0], t[:, 1], color="tab:blue", lw=0.6, label="trajectory")
            ax.plot(t[0, 0], t[0, 1], "o", color="tab:blue", ms=3, label="start")
            ax.legend(loc="upper right", fontsize=7)
    span = max(x1 - x0, y1 - y0)
    bar = nice_length(span)
    pad = 0.04 * span
    bx, by = x0 + pad, y0 + pad
    ax.add_patch(Rectangle((bx, by), bar, 0.012 * span, color="tab:red", zorder=3))
    label = f"{bar:g} m" if bar >= 1 else f"{bar * 100:g} cm"
    ax.text(bx, by + 0.02 * span, label, color="tab:red", fontsize=8, zorder=3)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    label_metric_axes(ax)
    r = grid.spec.resolution
    h, w = grid.spec.shape
    ax.set_title(f"{title}\n" if title else "", fontsize=9, loc="left")
    ax.set_title(f"{w} x {h} cells at {r:g} m", fontsize=8, loc="right")
    return ax


def _extent(grid: Any) -> tuple[float, float, float, float]:
    x0, y0 = grid.spec.origin
    r = grid.spec.resolution
    h, w = grid.spec.shape
    return x0, y0, x0 + w * r, y0 + h * r


def save_map_figure(
    path: str | os.PathLike[str],
    grid: Any,
    *,
    trajectory: ArrayLike | None = None,
    title: str | None = None,
) -> Path:
    """Render :func:`plot_map` to a PNG (Agg backend, written atomically; inside
    :func:`probmap._atomic.atomic_outputs` it is renamed with the command's other files)."""
    from matplotlib.figure import Figure

    from probmap._atomic import atomic_write

    path = Path(path)
    x0, y0, x1, y1 = _extent(grid)
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    fig = Figure(figsize=(8, float(np.clip(8 * aspect, 3, 12)) + 0.6))
    plot_map(fig.add_subplot(), grid, trajectory=trajectory, title=title)
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=150, bbox_inches="tight")
    return path
