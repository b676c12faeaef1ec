"""The storage both occupancy grids share (:class:`~probmap.grid.occupancy.OccupancyGrid` and
:class:`~probmap.grid.semantic.SemanticGrid`): the cell geometry and its growth to fit a batch of
scans (:func:`plan_growth`, :func:`regrid`), the one-byte per-cell stamp of the last scan that
changed a cell and the scan count (:class:`_ScanGrid`), and the observed cells of a grid rebuilt
from stored values. Private: the grids' public classes are its interface.
"""

from __future__ import annotations

import math
import mmap
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._typing import FloatArray
from probmap.errors import GridBoundsError
from probmap.grid.spec import GridSpec

__all__ = [
    "MAX_EXTENT_M",
    "grid_resolution",
    "observed_mask",
    "observed_window",
    "plan_growth",
    "regrid",
]


MAX_EXTENT_M = 3000.0
"""Default largest side of a growing grid, metres: a building, a campus or a long outdoor run
fits; a pose glitch (a laser pose at 1e7 m, a 1e9 m reading with ``max_range=inf``) does not,
and is refused with :class:`GridBoundsError` instead of an attempt to allocate terabytes."""


def plan_growth(
    spec: GridSpec,
    box: NDArray[np.float64],
    *,
    fixed: bool,
    max_extent: float = MAX_EXTENT_M,
) -> tuple[GridSpec, tuple[int, int] | None]:
    """The geometry a grid needs to contain ``box = (xmin, xmax, ymin, ymax)``.

    Returns ``(spec, offset)``: ``spec`` itself when the box fits; otherwise a larger grid on the
    same cell lattice, grown geometrically (:meth:`GridSpec.enclosing`), with ``offset = (column,
    row)`` of the old cell ``[0, 0]`` in it, or ``None`` when the old grid had no cells.

    Raises
    ------
    GridBoundsError
        When ``fixed`` and the box leaves the grid, or when the grid would have to span more
        than ``max_extent`` metres in x or y to hold the box.
    """
    xmin, xmax, ymin, ymax = (float(v) for v in box)
    if spec.width and spec.height:
        x0, x1, y0, y1 = spec.extent
        span_x, span_y = max(xmax, x1) - min(xmin, x0), max(ymax, y1) - min(ymin, y0)
    else:
        span_x, span_y = xmax - xmin, ymax - ymin
    if not fixed and max(span_x, span_y) > max_extent:
        raise GridBoundsError(
            f"the grid would have to span {span_x:.4g} x {span_y:.4g} m to hold a scan reaching "
            f"x in [{xmin:.4g}, {xmax:.4g}], y in [{ymin:.4g}, {ymax:.4g}] m, more than its "
            f"limit of {max_extent:.4g} m a side (max_extent): a pose or a range far off the "
            "map (a glitch, or an infinite max_range)?"
        )
    if spec.width == 0 or spec.height == 0:
        if fixed:
            raise GridBoundsError("fixed grid has no cells")
        return GridSpec.around(spec.resolution, xmin, xmax, ymin, ymax, margin=32), None
    new, off_x, off_y = spec.enclosing(xmin, xmax, ymin, ymax)
    if new is not spec and fixed:
        x0, x1, y0, y1 = spec.extent
        raise GridBoundsError(
            f"scan reaches x in [{xmin:.3f}, {xmax:.3f}], y in [{ymin:.3f}, {ymax:.3f}] m, "
            f"outside the fixed grid x in [{x0:.3f}, {x1:.3f}], y in [{y0:.3f}, {y1:.3f}] m"
        )
    return new, (off_x, off_y)


def filled(shape: tuple[int, ...], fill: Any) -> NDArray[Any]:
    """An array of ``shape`` and ``fill``'s dtype holding ``fill`` everywhere.

    A fill of all zero bits (the log odds of p0 = 0.5, an unset stamp) of at least
    ``LAZY_BYTES`` is an anonymous memory map: the OS makes a page resident only when a scan
    writes it, so the unseen parts of a building's bounding box cost no memory. (numpy's own
    large arrays ask for transparent huge pages, which the first write makes resident 2 MiB
    at a time: all of a map's rows.) The values are those of ``np.full``.
    """
    v = np.asarray(fill)
    size = math.prod(shape) * v.dtype.itemsize
    if v.ndim == 0 and size >= LAZY_BYTES and not v.tobytes().strip(b"\x00"):
        return np.frombuffer(_anonymous_map(size), dtype=v.dtype).reshape(shape)
    out = np.empty(shape, dtype=v.dtype)
    out[...] = v
    return out


#: smallest zero-filled array (bytes) that :func:`filled` maps lazily
LAZY_BYTES = 1 << 22


def _anonymous_map(size: int) -> mmap.mmap:
    """``size`` zero bytes of private anonymous memory. Private, not the module's default
    shared mapping: a page that is only read then stays the kernel's zero page instead of
    becoming resident (a map writer reads every cell)."""
    if hasattr(mmap, "MAP_PRIVATE"):
        return mmap.mmap(-1, size, flags=mmap.MAP_PRIVATE)
    return mmap.mmap(-1, size)  # pragma: no cover - Windows: no flags


def reset_stamps(stamp: NDArray[np.uint8], rows: int = 256) -> None:
    """``np.minimum(stamp, 1, out=stamp)`` (a new stamp epoch), writing only the cells it
    changes, block of rows by block of rows: pages of never-updated cells stay untouched
    (see :func:`filled`) and no whole-grid temporary is made."""
    for r0 in range(0, stamp.shape[0], rows):
        block = stamp[r0 : r0 + rows]
        block[block > 1] = 1


def regrid(
    old: NDArray[Any], shape: tuple[int, int], offset: tuple[int, int] | None, fill: Any
) -> NDArray[Any]:
    """A ``shape`` (H, W, ...) array filled with ``fill`` holding ``old`` at ``offset`` (column,
    row) — the cells of a grown grid; ``offset=None`` gives a fresh array."""
    new = filled((*shape, *old.shape[2:]), np.asarray(fill, dtype=old.dtype))
    if offset is not None:
        off_x, off_y = offset
        h, w = old.shape[:2]
        new[off_y : off_y + h, off_x : off_x + w] = old
    return new


_EPOCH = 254  # scans per kernel call: their ids must fit the one-byte stamp (2..255)


def grid_resolution(spec: GridSpec | None, resolution: float) -> float:
    """The cell side (metres) of a grid built with ``resolution`` and an optional ``spec``.

    The spec's resolution wins; a ``resolution`` other than the default 0.05 that disagrees
    with it, and a side that is not a positive number, raise :class:`ValueError`. The one rule
    of :class:`OccupancyGrid` and :class:`~probmap.grid.semantic.SemanticGrid`.
    """
    if spec is not None and not math.isclose(spec.resolution, resolution) and resolution != 0.05:
        raise ValueError(
            f"resolution {resolution} disagrees with spec.resolution {spec.resolution}"
        )
    res = spec.resolution if spec is not None else float(resolution)
    if not (math.isfinite(res) and res > 0):
        raise ValueError(f"resolution must be a positive number of metres, got {resolution}")
    return res


def observed_window(seen: NDArray[np.bool_], margin: int) -> tuple[int, int, int, int] | None:
    """Rows ``y0:y1`` and columns ``x0:x1`` of the cells observed in ``seen`` (H, W) plus
    ``margin`` cells, inside the grid, as ``(y0, y1, x0, x1)``; None when no cell is observed.
    What :meth:`OccupancyGrid.cropped` and
    :meth:`probmap.grid.increments.IncrementGrid.cropped` keep."""
    rows = np.nonzero(seen.any(axis=1))[0]
    cols = np.nonzero(seen.any(axis=0))[0]
    if len(rows) == 0:
        return None
    h, w = seen.shape
    y0, y1 = max(int(rows[0]) - margin, 0), min(int(rows[-1]) + 1 + margin, h)
    x0, x1 = max(int(cols[0]) - margin, 0), min(int(cols[-1]) + 1 + margin, w)
    return y0, y1, x0, x1


def observed_mask(
    observed: ArrayLike | None, spec: GridSpec, unchanged: Callable[[], NDArray[np.bool_]]
) -> NDArray[np.bool_]:
    """The observed cells (H, W) of a grid rebuilt from stored log odds: ``observed`` checked
    against ``spec.shape``, or when it is None, ``unchanged()`` (the cells off the prior)."""
    if observed is None:
        return unchanged()
    seen = np.asarray(observed, dtype=bool)
    if seen.shape != spec.shape:
        raise ValueError(f"observed shape {seen.shape} does not match spec.shape {spec.shape}")
    return seen


class _ScanGrid:
    """What :class:`OccupancyGrid` and :class:`~probmap.grid.semantic.SemanticGrid` share: the
    geometry, the per-cell stamp of the last scan that changed a cell (0: never), the scan
    count, and growth to fit a batch of scans before it is integrated."""

    _spec: GridSpec
    _stamp: NDArray[Any]
    _scans: int
    model: Any

    @property
    def spec(self) -> GridSpec:
        """Current geometry (changes when the grid grows)."""
        return self._spec

    @property
    def observed(self) -> NDArray[np.bool_]:
        """Cells updated by at least one scan, shape (H, W)."""
        return self._stamp != 0

    def observed_rows(self, r0: int, r1: int) -> NDArray[np.bool_]:
        """``observed[r0:r1]`` without the whole mask (writers stream large maps by rows)."""
        return self._stamp[r0:r1] != 0

    @property
    def scans_integrated(self) -> int:
        """Number of scans integrated so far."""
        return self._scans

    def _ensure_bounds(self, box: NDArray[np.float64]) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _fit_scans(
        self,
        P: FloatArray,
        R: FloatArray,
        A: FloatArray,
        shared: bool,
        max_range: float,
        clear_range: float,
    ) -> None:
        """Grow the grid (or raise) so that every cell the scans can touch lies in it."""
        from probmap.grid import _kernels

        box = np.empty(4)
        _kernels.scan_bounds(P, R, A, shared, max_range, clear_range, self.model.thickness, box)
        self._ensure_bounds(box)
