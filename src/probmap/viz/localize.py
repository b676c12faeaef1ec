"""Pictures of Monte Carlo localization: the map, the estimated trajectory from the filter's
convergence on (broken where the estimate jumps), the reference over the localized time span,
and optionally the particles (axes first; the caller owns the figure)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._checks import require_at_least
from probmap.viz.maps import legend_below, map_legend_handles, plot_map

__all__ = ["converged_index", "plot_localization", "save_localization_figure", "split_at_jumps"]


def converged_index(spread: ArrayLike, threshold: float = 1.0, hold: int = 10) -> int:
    """The first update that starts ``hold`` consecutive updates whose particle spread is at
    or below ``threshold`` (m); ``len(spread)`` when there is none (a shorter run counts
    when it reaches the end).

    A global localization's early estimates are the heaviest cluster of particles spread over
    the whole building: they jump from room to room and mean nothing until the filter
    converges. Later spikes of the spread (the random particles of augmented MCL) do not undo
    a convergence; a jump of the estimate is cut by :func:`split_at_jumps` instead.

    >>> converged_index([8.0, 5.0, 0.3, 2.0, 0.4, 0.2, 0.2], hold=3)
    4
    >>> converged_index([0.1, 0.2]), converged_index([3.0, 0.1]), converged_index([3.0, 4.0])
    (0, 1, 2)
    """
    require_at_least("hold", hold, 1)
    s = np.asarray(spread, dtype=np.float64).reshape(-1)
    ok = s <= threshold  # NaN counts as not converged
    run = 0
    for i in range(len(s) - 1, -1, -1):  # run[i]: consecutive converged updates from i on
        run = run + 1 if ok[i] else 0
        ok[i] = run >= hold or (run > 0 and i + run == len(s))
    hits = np.flatnonzero(ok)
    return int(hits[0]) if hits.size else len(s)


def split_at_jumps(xy: ArrayLike, max_step: float) -> list[NDArray[np.float64]]:
    """Cut a path (T, 2) into pieces wherever two consecutive points lie more than
    ``max_step`` metres apart, so that a plot draws no line across the jump (through a wall).
    Pieces of one point are kept (a plot marks them as points).

    >>> [p.shape[0] for p in split_at_jumps([[0, 0], [0.1, 0], [5, 0], [5.1, 0]], 1.0)]
    [2, 2]
    """
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if not max_step > 0:
        raise ValueError(f"max_step must be > 0 m, got {max_step}")
    if len(p) == 0:
        return []
    step = np.hypot(*np.diff(p, axis=0).T)
    cuts = np.flatnonzero(~(step <= max_step)) + 1
    return [piece for piece in np.split(p, cuts) if len(piece)]


def plot_localization(
    ax: Any,
    grid: Any,
    times: ArrayLike,
    poses: ArrayLike,
    spread: ArrayLike,
    *,
    reference: tuple[ArrayLike, ArrayLike] | None = None,
    particles: ArrayLike | None = None,
    converged_spread: float = 1.0,
    converged_hold: int = 10,
    converged: int | None = None,
    max_step: float = 1.0,
    title: str | None = None,
) -> Any:
    """Draw an MCL run on its map.

    The trajectory is drawn from :func:`converged_index` on (the estimates before it are
    marked as faint dots), broken by :func:`split_at_jumps` where the estimate jumps (a
    relocalization): it never draws a line through a wall. The reference (a smoothed
    trajectory, drawn whole: its poses may lie metres apart) is clipped to the time span of
    the drawn trajectory.

    Parameters
    ----------
    ax : matplotlib Axes
    grid : OccupancyGrid or LocalizationMap
        Anything with ``spec``, ``log_odds`` and ``observed`` (see
        :func:`probmap.viz.maps.plot_map`).
    times : (T,) array_like
        Update timestamps (s).
    poses : (T, 3) array_like
        Estimates (x, y, theta) in the map frame (m, rad).
    spread : (T,) array_like
        The particles' positional spread at each update (m).
    reference : (times (M,), poses (M, 3)), optional
        A reference trajectory in the same frame and clock.
    particles : (N, 3) array_like, optional
        A particle set to draw (the last one, usually).
    converged_spread, converged_hold : float, int
        The filter counts as converged from the first of ``converged_hold`` consecutive
        updates with a spread (m) at or below ``converged_spread``.
    converged : int, optional
        The first converged update as the filter judged it
        (:attr:`~probmap.pipelines.localize.LocalizationRun.converged_index`; ``len(times)``
        when it never converged); replaces the rule of ``converged_spread``.
    max_step : float
        Largest distance (m) between consecutive estimates drawn as one line (updates come
        every 0.1 m of motion by default, so 1 m is a jump).
    title : str, optional

    Returns
    -------
    matplotlib Axes
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    s = np.asarray(spread, dtype=np.float64).reshape(-1)
    if not (t.shape[0] == p.shape[0] == s.shape[0]):
        raise ValueError(
            f"times {t.shape}, poses {p.shape} and spread {s.shape} need one row per update"
        )
    plot_map(ax, grid, title=title)
    c = converged_index(s, converged_spread, converged_hold) if converged is None else converged
    c = min(max(int(c), 0), len(t))
    if reference is not None and c < len(t):
        rt = np.asarray(reference[0], dtype=np.float64).reshape(-1)
        rp = np.asarray(reference[1], dtype=np.float64).reshape(-1, 3)
        keep = (rt >= t[c]) & (rt <= t[-1])
        ax.plot(
            rp[keep, 0], rp[keep, 1], "-", color="tab:green", lw=2.0, alpha=0.6,
            label="reference",
        )  # fmt: skip
    if particles is not None:
        q = np.asarray(particles, dtype=np.float64).reshape(-1, 3)
        ax.plot(q[:, 0], q[:, 1], ".", color="tab:orange", ms=2.0, alpha=0.6, label="particles")
    if c > 0:
        ax.plot(
            p[:c, 0], p[:c, 1], ".", color="tab:red", ms=2.0, alpha=0.3,
            label=f"before convergence ({c} updates)",
        )  # fmt: skip
    for k, piece in enumerate(split_at_jumps(p[c:, :2], max_step)):
        style = "-" if len(piece) > 1 else "."
        ax.plot(
            piece[:, 0], piece[:, 1], style, color="tab:red", lw=0.8, ms=2.0,
            label="MCL" if k == 0 else None,
        )  # fmt: skip
    if len(p) > c:  # where the localized estimate starts and ends
        ax.plot(
            p[c, 0],
            p[c, 1],
            "o",
            color="tab:red",
            mec="white",
            mew=0.6,
            ms=6,
            zorder=4,
            label="start",
        )
        ax.plot(
            p[-1, 0],
            p[-1, 1],
            "s",
            color="tab:red",
            mec="white",
            mew=0.6,
            ms=6,
            zorder=4,
            label="end",
        )
    handles, _ = ax.get_legend_handles_labels()
    legend_below(ax, handles + map_legend_handles(), ncol=4)  # outside the map, large type
    return ax


def save_localization_figure(
    path: str | os.PathLike[str], grid: Any, times: ArrayLike, poses: ArrayLike,
    spread: ArrayLike, *, dpi: float | None = None, **kwargs: Any,
) -> Path:  # fmt: skip
    """Render :func:`plot_localization` to a PNG (Agg backend, written atomically; inside
    :func:`probmap._atomic.atomic_outputs` it is renamed with the command's other files), by
    default at the resolution that shows a large map's walls
    (:func:`probmap.viz.maps.save_picture`). ``kwargs`` go to :func:`plot_localization`."""
    from probmap.viz.maps import map_figure, save_picture

    fig = map_figure(grid)
    ax = fig.add_subplot()
    plot_localization(ax, grid, times, poses, spread, **kwargs)
    return save_picture(fig, ax, path, dpi=None if dpi is None else float(dpi))
