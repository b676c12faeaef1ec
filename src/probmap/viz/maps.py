"""Pictures of occupancy maps people can read: axes in metres, a scale bar, a title, the
trajectory, free space white, walls black and never-observed space a distinct blue-grey, with a
legend (axes first; the caller owns the figure).

A large map is drawn at a size that shows its walls: :func:`picture_step` picks how many cells
one pixel covers (at most :data:`MAX_PICTURE_PIXELS` pixels on the map's longer side), each
pixel shows the most occupied observed cell it covers (:func:`pooled_cells`, so a wall one cell
thick survives), and :func:`save_picture` sets the resolution so that one image pixel is one
pixel of the file."""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "FREE_RGB",
    "MAX_PICTURE_PIXELS",
    "OCCUPIED_RGB",
    "UNKNOWN_RGB",
    "add_scale_bar",
    "draw_grid",
    "label_metric_axes",
    "map_image",
    "map_legend_handles",
    "nice_length",
    "picture_step",
    "plot_map",
    "pooled_cells",
    "sampled_cells",
    "save_map_figure",
    "save_picture",
]

#: Colours of the pictures (RGB, 0..1): free space, walls, and never-observed space, a light
#: blue-grey that no probability's grey can be mistaken for.
FREE_RGB = (1.0, 1.0, 1.0)
OCCUPIED_RGB = (0.0, 0.0, 0.0)
UNKNOWN_RGB = (0.72, 0.78, 0.87)

#: The most pixels a picture gives the map's longer side: a 460 m building at 0.05 m (9,159
#: cells) is drawn at 3 cells a pixel, 3,053 pixels; its picture (a 3,436 x 2,357-pixel file)
#: adds about 72 MiB to the memory of the process that draws it (the canvas, the map image,
#: matplotlib's strips).
MAX_PICTURE_PIXELS = 4000

# the resolution of a small map's picture (the longer side of the axes about 1,000 pixels)
_MIN_DPI = 150.0
# rows of cells pooled at once: bounds the temporary memory of a large map's picture
_STRIP_CELLS = 1_000_000
# pixels of the map image matplotlib draws at once, and the most it draws whole (draw_grid)
_STRIP_PIXELS = 250_000
_WHOLE_PIXELS = 1_000_000


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
    ``step``: the smallest that leaves the longer side at most ``max_pixels``. What the live
    view draws (fast; a wall thinner than ``step`` cells may fall between the samples: the
    saved pictures use :func:`pooled_cells`)."""
    h, w = grid.spec.shape
    step = max(1, -(-max(h, w) // max_pixels))
    lo = np.asarray(grid.log_odds)[::step, ::step]
    seen = np.asarray(grid.observed)[::step, ::step]
    return lo, seen, step


def picture_step(grid: Any, max_pixels: int = MAX_PICTURE_PIXELS) -> int:
    """How many cells (a side) one pixel of a picture covers: the smallest ``step`` that
    leaves the map's longer side at most ``max_pixels`` pixels.

    >>> from types import SimpleNamespace as NS
    >>> picture_step(NS(spec=NS(shape=(5000, 9200)))), picture_step(NS(spec=NS(shape=(700, 600))))
    (3, 1)
    """
    h, w = grid.spec.shape
    if max_pixels < 1:
        raise ValueError(f"max_pixels must be >= 1, got {max_pixels}")
    return max(1, -(-max(h, w) // int(max_pixels)))


def _pooled_strips(
    grid: Any, step: int
) -> Iterator[tuple[int, NDArray[np.float32], NDArray[np.bool_]]]:
    """:func:`pooled_cells` a strip of rows at a time: ``(first row, log odds, observed)``
    per strip of the pooled picture, in order. The cells are read about
    a million at a time, so that neither the pooled image nor any temporary of the
    whole map is ever held."""
    lo_all = np.asarray(grid.log_odds)
    h, w = lo_all.shape
    rows_of = getattr(grid, "observed_rows", None)  # the mask a strip at a time
    if rows_of is None:
        seen_grid = np.asarray(grid.observed)

        def rows_of(r0: int, r1: int) -> NDArray[np.bool_]:
            return seen_grid[r0:r1]

    wo = -(-w // step)
    rows = max(1, _STRIP_CELLS // max(w, 1) // step) * step
    pad_w = wo * step - w
    for r0 in range(0, h, rows):
        r1 = min(h, r0 + rows)
        seen = np.asarray(rows_of(r0, r1), dtype=bool)
        if step == 1:
            yield r0, np.where(seen, lo_all[r0:r1], 0.0).astype(np.float32), seen
            continue
        lo = np.where(seen, lo_all[r0:r1], -np.inf).astype(np.float32)
        pad_h = -(-(r1 - r0) // step) * step - (r1 - r0)
        if pad_h or pad_w:
            lo = np.pad(lo, ((0, pad_h), (0, pad_w)), constant_values=-np.inf)
        blocks = lo.reshape(lo.shape[0] // step, step, wo, step).max(axis=(1, 3))
        finite = np.isfinite(blocks)
        yield r0 // step, np.where(finite, blocks, 0.0).astype(np.float32), finite


def pooled_cells(grid: Any, step: int) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """The largest log odds among the observed cells of each ``step`` x ``step`` block (the
    blocks of the last row and column may be smaller) and whether the block holds an observed
    cell. A wall one cell thick darkens its block; stride sampling would miss it two times in
    three at ``step = 3``. Works through the rows a strip at a time (the temporary memory is
    about 10 MB whatever the map's size)."""
    h, w = grid.spec.shape
    shape = (-(-h // step), -(-w // step))
    lo_out = np.empty(shape, np.float32)
    seen_out = np.empty(shape, bool)
    for o0, lo, seen in _pooled_strips(grid, step):
        lo_out[o0 : o0 + len(lo)] = lo
        seen_out[o0 : o0 + len(lo)] = seen
    return lo_out, seen_out


def map_image(grid: Any, max_pixels: int = MAX_PICTURE_PIXELS) -> tuple[np.ndarray, int]:
    """The picture's colours (RGB, ``uint8``) of the map, row 0 at the smallest y: observed
    cells white (p <= 0.25) to black (p >= 0.75), linear between (the map PNG's grey ramp),
    never-observed cells :data:`UNKNOWN_RGB`. Each pixel covers ``step`` x ``step`` cells
    (:func:`picture_step`) and shows the most occupied observed one (:func:`pooled_cells`).
    Built a strip at a time: besides the image, a few MB whatever the map's size.
    Returns the image (H, W, 3) and ``step``."""
    return _map_pixels(grid, max_pixels, 3)


def _map_pixels(grid: Any, max_pixels: int, channels: int) -> tuple[np.ndarray, int]:
    """:func:`map_image` with ``channels`` 3 (RGB) or 4 (RGBA, opaque)."""
    step = picture_step(grid, max_pixels)
    h, w = grid.spec.shape
    img = np.empty((-(-h // step), -(-w // step), channels), np.uint8)
    unknown = np.rint(255.0 * np.asarray(UNKNOWN_RGB)).astype(np.uint8)
    for o0, lo, seen in _pooled_strips(grid, step):
        # p = 1 / (1 + exp(-lo)); grey = clip((0.75 - p) / 0.5, 0, 1)
        p = 1.0 / (1.0 + np.exp(-lo, dtype=np.float32))
        grey = np.rint(255.0 * np.clip((0.75 - p) / 0.5, 0.0, 1.0)).astype(np.uint8)
        rgb = img[o0 : o0 + len(lo), :, :3]
        rgb[...] = grey[..., None]
        rgb[~seen] = unknown
    if channels == 4:
        img[..., 3] = 255
    return img, step


def map_legend_handles() -> list[Any]:
    """Legend entries of a map's colours: free, occupied, unknown (never observed)."""
    from matplotlib.patches import Patch

    return [
        Patch(facecolor=FREE_RGB, edgecolor="0.4", lw=0.5, label="free"),
        Patch(facecolor=OCCUPIED_RGB, edgecolor="0.4", lw=0.5, label="occupied"),
        Patch(facecolor=UNKNOWN_RGB, edgecolor="0.4", lw=0.5, label="unknown (never observed)"),
    ]


def draw_grid(ax: Any, grid: Any, *, max_pixels: int = MAX_PICTURE_PIXELS) -> int:
    """Draw ``grid`` (:func:`map_image`) in the world frame, metres, its extent as the axes'
    limits. Returns ``step``, the cells a pixel covers."""
    img, step = _map_pixels(grid, max_pixels, 4)
    x0, y0, x1, y1 = _extent(grid)
    # opaque RGBA, a large image in strips: matplotlib resamples an image in floating point
    # (an RGB one in float64 RGBA, 32 bytes a pixel, an RGBA one in float32, in and out); a
    # strip at a time keeps that to a few MB. A large image is drawn one file pixel per image
    # pixel (save_picture), so its strips meet on pixel borders and the file is that of the
    # image drawn whole; a small one is magnified, and drawn whole.
    h, w = img.shape[:2]
    rows = h if h * w <= _WHOLE_PIXELS else max(1, _STRIP_PIXELS // max(w, 1))
    dy = (y1 - y0) / h
    for r0 in range(0, h, rows):
        r1 = min(h, r0 + rows)
        ax.imshow(
            img[r0:r1], origin="lower", extent=(x0, x1, y0 + r0 * dy, y0 + r1 * dy),
            interpolation="nearest",
        )  # fmt: skip
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    return step


def add_scale_bar(ax: Any, extent: tuple[float, float, float, float]) -> float:
    """A red bar of a round length (:func:`nice_length`) with its label in the lower left of
    ``extent`` ``(x0, y0, x1, y1)``, metres. Returns its length."""
    from matplotlib.patches import Rectangle

    x0, y0, x1, y1 = extent
    span = max(x1 - x0, y1 - y0)
    bar = nice_length(span)
    pad = 0.04 * span
    bx, by = x0 + pad, y0 + pad
    ax.add_patch(Rectangle((bx, by), bar, 0.012 * span, color="tab:red", zorder=5))
    label = f"{bar:g} m" if bar >= 1 else f"{bar * 100:g} cm"
    ax.text(bx, by + 0.02 * span, label, color="tab:red", fontsize=8, zorder=5)
    return bar


def legend_below(ax: Any, handles: list[Any] | None = None, *, ncol: int = 3) -> Any:
    """The legend under the axes, outside the map (it never hides a wall), in columns."""
    from matplotlib.transforms import offset_copy

    if handles is None:
        handles, _ = ax.get_legend_handles_labels()
    below = offset_copy(ax.transAxes, fig=ax.figure, y=-26, units="points")  # under "x [m]"
    return ax.legend(
        handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0.0), bbox_transform=below,
        ncol=ncol, fontsize=8, frameon=False, handlelength=1.6, columnspacing=1.4,
    )  # fmt: skip


def plot_map(
    ax: Any,
    grid: Any,
    *,
    trajectory: ArrayLike | None = None,
    title: str | None = None,
    max_pixels: int = MAX_PICTURE_PIXELS,
) -> Any:
    """Draw an occupancy grid in the world frame (metres) with a scale bar, a legend of its
    colours and, optionally, a trajectory.

    Parameters
    ----------
    ax : matplotlib Axes
    grid : OccupancyGrid
    trajectory : array_like, shape (T, 2) or (T, 3), optional
        Poses (x, y[, theta]) in the map's frame, metres; drawn as a blue line with its start
        (circle) and end (square) marked.
    title : str, optional
        Usually the input's name.
    max_pixels : int
        The most pixels of the map's longer side (:func:`picture_step`).

    Returns
    -------
    matplotlib Axes
    """
    draw_grid(ax, grid, max_pixels=max_pixels)
    handles = []
    if trajectory is not None:
        t = np.asarray(trajectory, dtype=np.float64)
        if t.ndim != 2 or t.shape[1] not in (2, 3):
            raise ValueError(f"trajectory must be (T, 2) or (T, 3), got {t.shape}")
        if len(t):
            handles += ax.plot(t[:, 0], t[:, 1], color="tab:blue", lw=0.6, label="trajectory")
            handles += _start_end(ax, t)
    add_scale_bar(ax, _extent(grid))
    label_metric_axes(ax)
    legend_below(ax, handles + map_legend_handles())
    r = grid.spec.resolution
    h, w = grid.spec.shape
    ax.set_title(f"{title}\n" if title else "", fontsize=9, loc="left")
    ax.set_title(f"{w} x {h} cells at {r:g} m", fontsize=8, loc="right")
    return ax


def _start_end(ax: Any, t: np.ndarray, color: str = "tab:blue") -> list[Any]:
    """Start (circle) and end (square) markers of a path; their legend handles."""
    start = ax.plot(
        t[0, 0], t[0, 1], "o", color=color, mec="white", mew=0.6, ms=6, zorder=4, label="start"
    )
    end = ax.plot(
        t[-1, 0], t[-1, 1], "s", color=color, mec="white", mew=0.6, ms=6, zorder=4, label="end"
    )
    return [*start, *end]


def _extent(grid: Any) -> tuple[float, float, float, float]:
    x0, y0 = grid.spec.origin
    r = grid.spec.resolution
    h, w = grid.spec.shape
    return x0, y0, x0 + w * r, y0 + h * r


def map_figure(grid: Any, width: float = 8.0) -> Any:
    """A figure for a map's picture: ``width`` inches wide, as tall as the map's aspect asks
    (3 to 12 inches, plus room for the legend)."""
    from matplotlib.figure import Figure

    x0, y0, x1, y1 = _extent(grid)
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    return Figure(figsize=(width, float(np.clip(width * aspect, 3, 12)) + 1.0))


def save_picture(
    fig: Any, ax: Any, path: str | os.PathLike[str], *, dpi: float | None = None
) -> Path:
    """Write ``fig`` as a PNG (Agg, atomically; inside :func:`probmap._atomic.atomic_outputs`
    renamed with the command's other files). Without ``dpi``: the resolution that gives the
    map drawn in ``ax`` (:func:`draw_grid`) one file pixel per image pixel, at least 150 dpi,
    so a large map keeps its walls and a small one its usual size."""
    from probmap._atomic import atomic_write
    from probmap._memory import release_freed_memory

    if dpi is None:
        dpi = _MIN_DPI
        img = ax.get_images()
        if img:
            w = img[0].get_array().shape[1]
            h = sum(im.get_array().shape[0] for im in img)
            ax.apply_aspect()
            pos = ax.get_position()
            fw, fh = fig.get_size_inches()
            inches = max(pos.width * fw, 1e-3) if w >= h else max(pos.height * fh, 1e-3)
            dpi = max(_MIN_DPI, max(w, h) / inches)
    bbox = _tight_bbox(fig, dpi)
    release_freed_memory()  # the map image's temporaries, before the figure's pixels
    path = Path(path)
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=dpi, bbox_inches=bbox)
    return path


def _tight_bbox(fig: Any, dpi: float) -> Any:
    """The area ``savefig(..., bbox_inches="tight")`` writes at ``dpi`` (inches, padded by
    ``savefig.pad_inches``), measured as matplotlib measures it (a draw that renders
    nothing, then the extents of what it drew) but with a renderer of one pixel: the
    measuring renderer stays referenced by the figure's texts, and matplotlib's own, of the
    whole figure's size, would still be held while the cropped figure is drawn (about 40 MB
    for a 4,000-pixel map)."""
    from contextlib import nullcontext

    import matplotlib as mpl
    from matplotlib.backends.backend_agg import RendererAgg

    old = fig.dpi
    fig.dpi = dpi
    try:
        renderer = RendererAgg(1, 1, dpi)  # text extents depend on the dpi, not the size
        with getattr(renderer, "_draw_disabled", nullcontext)():
            fig.draw(renderer)  # places what only a draw places (ticks, the legend)
        return fig.get_tightbbox(renderer).padded(mpl.rcParams["savefig.pad_inches"])
    finally:
        fig.dpi = old


def save_map_figure(
    path: str | os.PathLike[str],
    grid: Any,
    *,
    trajectory: ArrayLike | None = None,
    title: str | None = None,
    max_pixels: int = MAX_PICTURE_PIXELS,
) -> Path:
    """Render :func:`plot_map` to a PNG (:func:`save_picture`: written atomically, at a size
    that shows a large map's walls)."""
    fig = map_figure(grid)
    ax = fig.add_subplot()
    plot_map(ax, grid, trajectory=trajectory, title=title, max_pixels=max_pixels)
    return save_picture(fig, ax, path)
