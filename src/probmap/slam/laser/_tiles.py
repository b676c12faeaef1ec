"""Copy-on-write tiled log-odds maps shared between particles (private).

Every particle's map is a table of tile ids into one pool of ``T x T`` float32 log-odds tiles.
Resampling copies only the tables; a tile is copied when a particle writes to it while another
particle still refers to it. Tile 0 is the never-written unknown tile (log odds 0).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from probmap.grid.spec import GridSpec


class TiledMaps:
    """The maps of ``n`` particles over one growing tile lattice.

    Parameters
    ----------
    n : int
        Number of particles.
    resolution : float
        Cell side in metres.
    tile : int
        Tile side in cells.
    """

    def __init__(self, n: int, resolution: float, tile: int = 32) -> None:
        if n < 1:
            raise ValueError(f"need at least one particle, got {n}")
        if tile < 4:
            raise ValueError(f"tile must be >= 4 cells, got {tile}")
        self.resolution = float(resolution)
        self.tile = int(tile)
        self.tile_m = self.resolution * self.tile
        # tile (0, 0) has its lower-left corner at origin; tables[k, ty, tx] is a pool id
        self.origin = (0.0, 0.0)
        self.tables = np.zeros((n, 0, 0), dtype=np.int32)
        self.pool = np.zeros((64, tile, tile), dtype=np.float32)
        self.refs = np.zeros(64, dtype=np.int64)
        self.refs[0] = 1 << 40  # the unknown tile is never freed nor written
        self._free = list(range(63, 0, -1))

    # ------------------------------------------------------------------ lattice
    def _ensure(self, tx0: int, ty0: int, tx1: int, ty1: int) -> tuple[int, int]:
        """Grow the tables to cover tile range [tx0, tx1) x [ty0, ty1) (in the current lattice
        coordinates) and return the shift applied to those coordinates."""
        n, h, w = self.tables.shape
        if h == 0:
            self.origin = (tx0 * self.tile_m + self.origin[0], ty0 * self.tile_m + self.origin[1])
            self.tables = np.zeros((n, ty1 - ty0, tx1 - tx0), dtype=np.int32)
            return -tx0, -ty0
        left = max(0, -tx0)
        down = max(0, -ty0)
        right = max(0, tx1 - w)
        up = max(0, ty1 - h)
        if left or down or right or up:
            # grow geometrically so repeated growth stays cheap
            left = left and max(left, w // 2)
            down = down and max(down, h // 2)
            right = right and max(right, w // 2)
            up = up and max(up, h // 2)
            t = np.zeros((n, h + down + up, w + left + right), dtype=np.int32)
            t[:, down : down + h, left : left + w] = self.tables
            self.tables = t
            self.origin = (
                self.origin[0] - left * self.tile_m,
                self.origin[1] - down * self.tile_m,
            )
        return left, down

    def tile_range(self, box: tuple[float, float, float, float]) -> tuple[int, int, int, int]:
        """Tile range ``(tx0, ty0, tx1, ty1)`` covering the world box, growing as needed."""
        xmin, ymin, xmax, ymax = box
        ox, oy = self.origin
        tx0 = math.floor((xmin - ox) / self.tile_m)
        ty0 = math.floor((ymin - oy) / self.tile_m)
        tx1 = math.floor((xmax - ox) / self.tile_m) + 1
        ty1 = math.floor((ymax - oy) / self.tile_m) + 1
        sx, sy = self._ensure(tx0, ty0, tx1, ty1)
        return tx0 + sx, ty0 + sy, tx1 + sx, ty1 + sy

    def window_origin(self, tx0: int, ty0: int) -> tuple[float, float]:
        """World position of the lower-left corner of tile (tx0, ty0)."""
        return (self.origin[0] + tx0 * self.tile_m, self.origin[1] + ty0 * self.tile_m)

    # ------------------------------------------------------------------ access
    def gather(self, k: int, tr: tuple[int, int, int, int]) -> NDArray[np.float32]:
        """Dense log odds of particle ``k`` over tile range ``tr``, shape (ny T, nx T)."""
        tx0, ty0, tx1, ty1 = tr
        ids = self.tables[k, ty0:ty1, tx0:tx1]
        T = self.tile
        blocks = self.pool[ids]  # (ny, nx, T, T)
        return np.ascontiguousarray(
            blocks.transpose(0, 2, 1, 3).reshape((ty1 - ty0) * T, (tx1 - tx0) * T)
        )

    def _alloc(self) -> int:
        if not self._free:
            cap = self.pool.shape[0]
            pool = np.zeros((2 * cap, self.tile, self.tile), dtype=np.float32)
            pool[:cap] = self.pool
            refs = np.zeros(2 * cap, dtype=np.int64)
            refs[:cap] = self.refs
            self.pool, self.refs = pool, refs
            self._free = list(range(2 * cap - 1, cap - 1, -1))
        return self._free.pop()

    def scatter(
        self,
        k: int,
        tr: tuple[int, int, int, int],
        lo: NDArray[np.float32],
        touched: NDArray[np.bool_],
    ) -> None:
        """Write the window ``lo`` back into particle ``k``'s tiles where ``touched[ty, tx]``
        (tile mask of the window), copying tiles that other particles share."""
        tx0, ty0, _, _ = tr
        T = self.tile
        for jy, jx in zip(*np.nonzero(touched), strict=True):
            ty, tx = ty0 + int(jy), tx0 + int(jx)
            tid = int(self.tables[k, ty, tx])
            if tid == 0 or self.refs[tid] > 1:
                if tid != 0:
                    self.refs[tid] -= 1
                tid = self._alloc()
                self.refs[tid] = 1
                self.tables[k, ty, tx] = tid
            self.pool[tid] = lo[jy * T : (jy + 1) * T, jx * T : (jx + 1) * T]

    def resample(self, indices: NDArray[np.int64]) -> None:
        """Particle ``i`` takes the map of particle ``indices[i]``; tiles no particle refers to
        any more go back to the free list."""
        self.tables = self.tables[np.asarray(indices)]
        refs = np.bincount(self.tables.ravel(), minlength=self.pool.shape[0]).astype(np.int64)
        refs[0] = 1 << 40
        self.refs = refs
        self._free = [int(i) for i in np.flatnonzero(refs == 0)[::-1]]

    # ------------------------------------------------------------------ summaries
    def tiles_in_use(self) -> int:
        """Distinct tiles referred to by any particle (excluding the unknown tile)."""
        return int(np.count_nonzero(self.refs[1:]))

    def nbytes(self) -> int:
        """Bytes held by the pool and the tables."""
        return int(self.pool.nbytes + self.tables.nbytes + self.refs.nbytes)

    def dense(self, k: int) -> tuple[NDArray[np.float32], GridSpec]:
        """Particle ``k``'s whole map as a dense log-odds array and its GridSpec."""
        _, h, w = self.tables.shape
        lo = self.gather(k, (0, 0, w, h))
        return lo, GridSpec(self.resolution, self.origin, lo.shape)  # type: ignore[arg-type]
