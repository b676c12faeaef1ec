"""Grid geometry: resolution, origin and shape, and world <-> cell conversions."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


@dataclass(frozen=True)
class GridSpec:
    """Geometry of a 2-D regular grid in the world frame.

    Parameters
    ----------
    resolution : float
        Cell side in metres (> 0).
    origin : tuple of float
        World ``(x, y)`` in metres of the lower-left corner of cell ``[0, 0]``.
    shape : tuple of int
        ``(H, W)``: number of rows (along +y) and columns (along +x).

    Notes
    -----
    Arrays over the grid are indexed ``[iy, ix]`` with row 0 at the *smallest* y (the image
    convention is flipped only when writing image files). Cell ``(ix, iy)`` covers
    ``[x0 + ix*r, x0 + (ix+1)*r) x [y0 + iy*r, y0 + (iy+1)*r)``.

    Examples
    --------
    >>> spec = GridSpec(0.5, (-1.0, -1.0), (4, 6))
    >>> spec.world_to_cell([[0.1, -0.9]]).tolist()
    [[2, 0]]
    >>> spec.cell_to_world([[2, 0]]).tolist()
    [[0.25, -0.75]]
    """

    resolution: float
    origin: tuple[float, float]
    shape: tuple[int, int]

    def __post_init__(self) -> None:
        if not (math.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(
                f"resolution must be a positive number of metres, got {self.resolution}"
            )
        if len(self.origin) != 2 or not all(math.isfinite(float(v)) for v in self.origin):
            raise ValueError(f"origin must be two finite numbers (x, y), got {self.origin!r}")
        if len(self.shape) != 2 or any(int(s) < 0 for s in self.shape):
            raise ValueError(f"shape must be two non-negative integers (H, W), got {self.shape!r}")
        object.__setattr__(self, "resolution", float(self.resolution))
        object.__setattr__(self, "origin", (float(self.origin[0]), float(self.origin[1])))
        object.__setattr__(self, "shape", (int(self.shape[0]), int(self.shape[1])))

    @property
    def height(self) -> int:
        """Number of rows (cells along +y)."""
        return self.shape[0]

    @property
    def width(self) -> int:
        """Number of columns (cells along +x)."""
        return self.shape[1]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` of the grid in metres (for ``imshow(origin='lower')``)."""
        x0, y0 = self.origin
        r = self.resolution
        return (x0, x0 + self.width * r, y0, y0 + self.height * r)

    def world_to_cell(self, xy: ArrayLike) -> NDArray[np.int64]:
        """Cell indexes ``(ix, iy)`` of world points.

        Parameters
        ----------
        xy : array_like, shape (N, 2) or (2,)
            World points in metres.

        Returns
        -------
        ndarray of int64, shape (N, 2) or (2,)
            ``floor((p - origin) / resolution)``; may lie outside the grid (see :meth:`contains`).
        """
        p = np.asarray(xy, dtype=np.float64)
        if p.shape[-1] != 2:
            raise ValueError(f"points must have shape (N, 2), got {p.shape}")
        return np.floor((p - np.asarray(self.origin)) / self.resolution).astype(np.int64)

    def cell_to_world(self, ixy: ArrayLike) -> NDArray[np.float64]:
        """World coordinates in metres of the centres of cells ``(ix, iy)``, shape (N, 2)."""
        c = np.asarray(ixy, dtype=np.float64)
        if c.shape[-1] != 2:
            raise ValueError(f"cell indexes must have shape (N, 2), got {c.shape}")
        return np.asarray(self.origin) + (c + 0.5) * self.resolution

    def contains(self, ixy: ArrayLike) -> NDArray[np.bool_]:
        """Whether cells ``(ix, iy)`` (shape (N, 2)) lie inside the grid."""
        c = np.asarray(ixy)
        return (
            (c[..., 0] >= 0)
            & (c[..., 0] < self.width)
            & (c[..., 1] >= 0)
            & (c[..., 1] < self.height)
        )

    def enclosing(
        self,
        xmin: float,
        xmax: float,
        ymin: float,
        ymax: float,
        *,
        grow: float = 0.5,
        margin: int = 16,
    ) -> tuple[GridSpec, int, int]:
        """A larger grid on the same cell lattice that contains the box, grown geometrically.

        Each side that must grow grows by at least ``grow`` times the current size (and ``margin``
        cells), so repeated growth costs amortised O(1) per update, as a dynamic array does.

        Returns
        -------
        spec : GridSpec
            The new grid (``self`` when the box already fits).
        off_x, off_y : int
            Column and row of the old cell ``[0, 0]`` in the new grid.
        """
        r = self.resolution
        x0, y0 = self.origin
        ix_lo = math.floor((xmin - x0) / r)
        ix_hi = math.floor((xmax - x0) / r)
        iy_lo = math.floor((ymin - y0) / r)
        iy_hi = math.floor((ymax - y0) / r)
        h, w = self.shape
        add_l = add_r = add_b = add_t = 0
        if ix_lo < 0:
            add_l = max(-ix_lo + margin, int(grow * w))
        if ix_hi >= w:
            add_r = max(ix_hi - w + 1 + margin, int(grow * w))
        if iy_lo < 0:
            add_b = max(-iy_lo + margin, int(grow * h))
        if iy_hi >= h:
            add_t = max(iy_hi - h + 1 + margin, int(grow * h))
        if not (add_l or add_r or add_b or add_t):
            return self, 0, 0
        new = GridSpec(r, (x0 - add_l * r, y0 - add_b * r), (h + add_b + add_t, w + add_l + add_r))
        return new, add_l, add_b

    @classmethod
    def around(
        cls, resolution: float, xmin: float, xmax: float, ymin: float, ymax: float, margin: int = 16
    ) -> GridSpec:
        """The smallest grid on the lattice through (0, 0) that covers a box, plus a margin."""
        r = float(resolution)
        ix0 = math.floor(xmin / r) - margin
        iy0 = math.floor(ymin / r) - margin
        ix1 = math.floor(xmax / r) + margin
        iy1 = math.floor(ymax / r) + margin
        return cls(r, (ix0 * r, iy0 * r), (iy1 - iy0 + 1, ix1 - ix0 + 1))
