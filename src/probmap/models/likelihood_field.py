"""The likelihood field model of range finders (Probabilistic Robotics section 6.4, Table 6.3).

The distance from every cell to the nearest occupied cell is computed once per map with
:func:`scipy.ndimage.distance_transform_edt` and stored as float32; the per-beam log-likelihood
``log(z_hit * N(d; 0, sigma_hit^2) + z_rand / z_max)`` is tabulated from it, so weighting a
particle costs one rotation and one table lookup per beam. Max-range readings contribute 0
(Table 6.3, line 4). The model works on a plain ``(spec, occupancy)`` pair (see
:mod:`probmap.models.grid_map`) and is vectorised over poses ``(N, 3)`` and beams ``(B,)``.

It is not the scan matcher's field (:class:`probmap.slam.laser.scan_matching.MatchField`), although
both are a Gaussian of the distance to an obstacle: this one is a normalised density (the
Gaussian of the distance to the nearest occupied cell centre, float32, mixed with a uniform
``z_rand / z_max``), looked up in the endpoint's cell and summed as log-likelihoods by Monte
Carlo localization; the matcher's is an unnormalised score ``exp(-d^2 / 2 sigma^2)`` in [0, 1]
(float64 distances, or splatted around occupied cells with a cut-off radius in submaps and RBPF
windows), interpolated bilinearly so that Gauss-Newton has a gradient, and its values feed the
branch-and-bound max-grids of loop closure. They differ in their values, in how they are
sampled and in what consumes them, so each keeps its own.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._typing import FloatArray
from probmap.models import _likelihood_field_kernels as _k
from probmap.models.grid_map import (
    GridGeometry,
    ScanLikelihood,
    checked_map,
    distance_field,
    scan_arrays,
)

__all__ = ["LikelihoodField"]


class LikelihoodField(ScanLikelihood):
    """Likelihood field range-finder model, Probabilistic Robotics Table 6.3.

    Parameters
    ----------
    spec : GridGeometry
        Grid geometry (resolution m, origin m, shape (H, W)).
    occupancy : (H, W) array_like
        Boolean or probability map (NaN unknown), indexed ``[iy, ix]``.
    max_range : float
        Sensor maximum range ``z_max`` (m); readings at or beyond it are skipped.
    sigma_hit : float
        Standard deviation (m) of the distance-to-obstacle Gaussian.
    z_hit, z_rand : float
        Mixture weights of the hit and random components.
    max_distance : float
        Distances are clipped here (m); endpoints outside the map count as this far.
    occupied_threshold : float
        Probability above which a cell is an obstacle.
    """

    def __init__(
        self,
        spec: GridGeometry,
        occupancy: ArrayLike,
        *,
        max_range: float,
        sigma_hit: float = 0.1,
        z_hit: float = 0.9,
        z_rand: float = 0.1,
        max_distance: float = 2.0,
        occupied_threshold: float = 0.65,
    ) -> None:
        frame, occupied = checked_map(spec, occupancy, occupied_threshold)
        for name, val in (("max_range", max_range), ("sigma_hit", sigma_hit)):
            if not (val > 0 and math.isfinite(val)):
                raise ValueError(f"{name} must be positive, got {val}")
        if z_hit < 0 or z_rand < 0 or z_hit + z_rand <= 0:
            raise ValueError(f"z_hit, z_rand must be non-negative, not both 0: {z_hit}, {z_rand}")
        if not max_distance > 0:
            raise ValueError(f"max_distance must be positive, got {max_distance}")
        self.spec = spec
        self.frame = frame
        self.occupied = occupied
        self.max_range = float(max_range)
        self.sigma_hit = float(sigma_hit)
        self.z_hit = float(z_hit)
        self.z_rand = float(z_rand)
        self.max_distance = float(max_distance)
        self.distance = np.minimum(
            distance_field(occupied, frame.resolution), np.float32(max_distance)
        )
        self.table = np.ascontiguousarray(
            self.log_likelihood_of_distance(self.distance), dtype=np.float32
        )
        self.outside = float(self.log_likelihood_of_distance(np.array(self.max_distance)))
        self._walls: tuple[Any, ...] | None = None  # log_likelihood_sum_walls' cache

    def log_likelihood_of_distance(self, d: ArrayLike) -> NDArray[np.float64]:
        """``log(z_hit * prob(d, sigma_hit^2) + z_rand / z_max)`` for distances ``d`` (m)."""
        dd = np.asarray(d, dtype=np.float64)
        s = self.sigma_hit
        hit = np.exp(-0.5 * (dd / s) ** 2) / (math.sqrt(2 * math.pi) * s)
        return np.asarray(np.log(self.z_hit * hit + self.z_rand / self.max_range))

    def endpoints(
        self, ranges: ArrayLike, angles: ArrayLike, sensor_offset: ArrayLike = (0.0, 0.0, 0.0)
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """Beam endpoints in the robot frame, computed once per scan.

        Returns ``(lx, ly, valid)``, each ``(B,)``; ``valid`` is False for max-range readings.
        """
        return self._endpoints(*scan_arrays(ranges, angles, sensor_offset))

    def _endpoints(
        self, r: FloatArray, a: FloatArray, o: FloatArray
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
        b = r.shape[0]
        lx = np.empty(b)
        ly = np.empty(b)
        valid = np.empty(b, dtype=np.bool_)
        _k.endpoints_in_robot_frame(r, a, o, self.max_range, lx, ly, valid)
        return lx, ly, valid

    def _log_likelihood(
        self, p: FloatArray, r: FloatArray, a: FloatArray, o: FloatArray
    ) -> FloatArray:
        lx, ly, valid = self._endpoints(r, a, o)  # max-range readings give 0
        out = np.empty((p.shape[0], lx.shape[0]))
        f = self.frame
        _k.likelihood_field_per_beam(
            p, lx, ly, valid, self.table, f.x0, f.y0, 1.0 / f.resolution, self.outside, out
        )
        return out

    def _log_likelihood_sum(
        self, p: FloatArray, r: FloatArray, a: FloatArray, o: FloatArray
    ) -> FloatArray:
        return self.log_likelihood_sum_prepared(p, *self._endpoints(r, a, o))

    def log_likelihood_sum_prepared(
        self,
        poses: NDArray[np.float64],
        lx: NDArray[np.float64],
        ly: NDArray[np.float64],
        valid: NDArray[np.bool_],
    ) -> NDArray[np.float64]:
        """As :meth:`log_likelihood_sum` with endpoints from :meth:`endpoints` (no checks)."""
        out = np.empty(poses.shape[0])
        f = self.frame
        _k.likelihood_field_sum(
            poses, lx, ly, valid, self.table, f.x0, f.y0, 1.0 / f.resolution, self.outside, out
        )
        return out

    def wall_beams(
        self, lx: ArrayLike, ly: ArrayLike, origin: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """What :meth:`log_likelihood_sum_walls` needs of each beam, computed once per scan:
        its direction in the robot frame (rad) and its length (cells) from the laser at
        ``origin`` (x, y in the robot frame, m) to the endpoint ``lx, ly`` (robot frame, m)."""
        o = np.asarray(origin, dtype=np.float64).reshape(-1)
        bx = np.asarray(lx, dtype=np.float64).reshape(-1) - o[0]
        by = np.asarray(ly, dtype=np.float64).reshape(-1) - o[1]
        angle = np.ascontiguousarray(np.arctan2(by, bx))
        return angle, np.ascontiguousarray(np.hypot(bx, by) / self.frame.resolution)

    def wall_cache(self) -> tuple[Any, ...]:
        """The cache of exact casts behind :meth:`log_likelihood_sum_walls`, made on first use:
        ``(occupied, slots, pool, cells, state, block, quantum)``. Casts start at the centre of
        the laser's block of ``block x block`` cells (0.1 m at 0.05 m cells), one per heading
        bin of 1 degree, and are stored in steps of ``quantum`` cells; ``pool`` keeps the casts
        of at most 4,096 blocks and forgets them all when full (a tracking filter needs a few
        dozen at a time)."""
        if self._walls is None:
            block = max(1, int(round(0.1 / self.frame.resolution)))
            h, w = self.occupied.shape
            slots = np.full((-(-h // block), -(-w // block)), -1, dtype=np.int32)
            pool = np.zeros((4096, 360), dtype=np.uint16)
            cells = np.zeros(4096, dtype=np.int64)
            # rows in use; how far a cast goes (cells): the sensor's range, and no further
            state = np.array([0, math.ceil(self.max_range / self.frame.resolution) + 2], np.int64)
            occ = np.ascontiguousarray(self.occupied)
            self._walls = (occ, slots, pool, cells, state, block, 0.2)
        return self._walls

    def log_likelihood_sum_walls(
        self,
        poses: ArrayLike,
        lx: ArrayLike,
        ly: ArrayLike,
        origin: ArrayLike = (0.0, 0.0),
        margin: float = 0.5,
    ) -> NDArray[np.float64]:
        """The scan's log-likelihood at each pose (N,), where a beam that runs through a wall
        of the map counts as a random reading (the beam model's view, Probabilistic Robotics
        section 6.3, at nearly the likelihood field's cost).

        The likelihood field looks only at where a beam ends (section 6.4.4): a pose turned so
        that the beams cross walls and end on other walls fits as well as the right one, or
        better where the map lacks walls the scan sees. Here a beam whose path from the laser
        meets an occupied cell more than ``margin`` metres short of its endpoint scores the
        field's floor (an endpoint far from any obstacle), as a reading the map cannot explain.
        The first wall along a beam is an exact cast from the centre of the laser's 0.1 m block
        at the nearest degree (:meth:`wall_cache`), so a beam that only grazes a corner may be
        judged either way.

        Parameters
        ----------
        poses : (N, 3) array_like
            Robot poses, map frame (m, rad).
        lx, ly : (B,) array_like
            Endpoints of the beams with a return, robot frame (m), as :meth:`endpoints` gives
            them (valid ones only).
        origin : (2,) array_like
            The laser's position in the robot frame (m).
        margin : float
            How far (m) short of its endpoint a beam may meet a wall.

        Examples
        --------
        >>> import numpy as np
        >>> from types import SimpleNamespace
        >>> occ = np.zeros((40, 40), bool); occ[:, 30] = True; occ[:, 20] = True  # x = 1.0, 1.5 m
        >>> lf = LikelihoodField(SimpleNamespace(resolution=0.05, origin=(0.0, 0.0),
        ...     shape=(40, 40)), occ, max_range=5.0)
        >>> pose = np.array([[0.5, 1.0, 0.0]])  # one beam to the far wall, through the near one
        >>> bool(lf.log_likelihood_sum_walls(pose, [1.025], [0.0])[0] == lf.outside)
        True
        >>> bool(lf.log_likelihood_sum_prepared(pose, np.array([1.025]), np.zeros(1),
        ...     np.ones(1, bool))[0] > lf.outside)
        True
        """
        p = np.ascontiguousarray(np.asarray(poses, dtype=np.float64).reshape(-1, 3))
        bx = np.ascontiguousarray(lx, dtype=np.float64).reshape(-1)
        by = np.ascontiguousarray(ly, dtype=np.float64).reshape(-1)
        o = np.asarray(origin, dtype=np.float64).reshape(-1)
        angle, length = self.wall_beams(bx, by, o)
        out = np.empty(p.shape[0])
        f = self.frame
        occ, slots, pool, cells, state, block, quantum = self.wall_cache()
        _k.likelihood_field_sum_walls(
            p, bx, by, self.table, f.x0, f.y0, 1.0 / f.resolution, self.outside,
            float(o[0]), float(o[1]), angle, length, float(margin) / f.resolution,
            occ, slots, pool, cells, state, block, quantum, out,
        )  # fmt: skip
        return out

    def local_search(
        self,
        pose: ArrayLike,
        lx: NDArray[np.float64],
        ly: NDArray[np.float64],
        window: tuple[float, float] = (0.5, math.radians(6.0)),
        step: tuple[float, float] = (0.05, math.radians(1.5)),
    ) -> tuple[NDArray[np.float64], float]:
        """The pose near ``pose`` whose scan fits the map best: an exhaustive search over a grid
        of positions within ``window[0]`` metres (each axis) and headings within ``window[1]``
        radians, ``step`` apart (correlative matching on this field's log-likelihoods).

        Parameters
        ----------
        pose : (3,) array_like
            Robot pose to search around, map frame (m, rad).
        lx, ly : (B,) ndarray
            Valid beam endpoints in the robot frame (m), as :meth:`endpoints` gives them.
        window : (float, float)
            Half-widths of the search (m, rad).
        step : (float, float)
            Grid steps (m, rad).

        Returns
        -------
        best : (3,) ndarray
            The best pose on the grid (``pose`` itself when nothing fits better).
        gain : float
            How much better it fits: the mean log-likelihood per beam at ``best`` minus that at
            ``pose`` (>= 0; 0 without beams).

        Examples
        --------
        >>> import numpy as np
        >>> from types import SimpleNamespace
        >>> occ = np.zeros((40, 40), bool); occ[:, 30] = True  # a wall at x = 1.5 m
        >>> lf = LikelihoodField(SimpleNamespace(resolution=0.05, origin=(0.0, 0.0),
        ...     shape=(40, 40)), occ, max_range=5.0)
        >>> best, gain = lf.local_search([0.3, 1.0, 0.0], np.array([1.0]), np.array([0.0]))
        >>> round(float(best[0]), 2), gain > 0
        (0.5, True)
        """
        p = np.asarray(pose, dtype=np.float64).reshape(3)
        bx = np.ascontiguousarray(lx, dtype=np.float64)
        by = np.ascontiguousarray(ly, dtype=np.float64)
        if bx.size == 0:
            return p.copy(), 0.0
        nt = int(round(window[0] / step[0]))
        na = int(round(window[1] / step[1]))
        d = np.arange(-nt, nt + 1) * step[0]
        a = np.arange(-na, na + 1) * step[1]
        gx, gy, ga = np.meshgrid(d, d, a, indexing="ij")
        cand = np.column_stack([p[0] + gx.ravel(), p[1] + gy.ravel(), p[2] + ga.ravel()])
        cand = np.ascontiguousarray(cand)
        score = self.log_likelihood_sum_prepared(cand, bx, by, np.ones(bx.size, dtype=np.bool_))
        here = int(np.flatnonzero((gx.ravel() == 0) & (gy.ravel() == 0) & (ga.ravel() == 0))[0])
        best = int(np.argmax(score))
        gain = float(score[best] - score[here]) / bx.size
        if gain <= 0.0:
            return p.copy(), 0.0
        out = cand[best].copy()
        out[2] = (out[2] + math.pi) % (2 * math.pi) - math.pi
        return out, gain

    def matched_fraction(
        self, pose: ArrayLike, ranges: ArrayLike, angles: ArrayLike, sensor_offset: ArrayLike,
        near: float, known: NDArray[np.bool_] | None = None,
    ) -> float:  # fmt: skip
        """The fraction of the beams with a return that end within ``near`` metres of an
        obstacle, seen from the robot pose ``pose`` (m, rad) with the laser at
        ``sensor_offset`` in the robot frame; 1.0 for a scan without a return.

        With ``known`` ((H, W) bool, the cells the map has observed), only the beams that end
        on a known cell count: one that ends where the map knows nothing (or off the grid) is
        no evidence for or against the pose (the likelihood field gives it the uniform
        ``1 / z_max``, Table 6.3). 1.0 when no beam ends on a known cell.

        Examples
        --------
        >>> import numpy as np
        >>> from types import SimpleNamespace
        >>> occ = np.zeros((40, 40), bool); occ[:, 30] = True  # a wall at x = 1.5 m
        >>> lf = LikelihoodField(SimpleNamespace(resolution=0.05, origin=(0.0, 0.0),
        ...     shape=(40, 40)), occ, max_range=5.0)
        >>> lf.matched_fraction([0.5, 1.0, 0.0], [1.0, 0.5], [0.0, 0.0], (0, 0, 0), 0.1)
        0.5
        >>> known = np.ones((40, 40), bool); known[:, 19:21] = False  # the map never saw x = 1 m
        >>> lf.matched_fraction([0.5, 1.0, 0.0], [1.0, 0.5], [0.0, 0.0], (0, 0, 0), 0.1, known)
        1.0
        """
        lx, ly, valid = self.endpoints(ranges, angles, sensor_offset)
        if not valid.any():
            return 1.0
        p = np.asarray(pose, dtype=np.float64).reshape(3)
        c, s = math.cos(p[2]), math.sin(p[2])
        ex = p[0] + c * lx[valid] - s * ly[valid]
        ey = p[1] + s * lx[valid] + c * ly[valid]
        f = self.frame
        ix = np.floor((ex - f.x0) / f.resolution).astype(np.int64)
        iy = np.floor((ey - f.y0) / f.resolution).astype(np.int64)
        h, w = self.distance.shape
        inside = (ix >= 0) & (iy >= 0) & (ix < w) & (iy < h)
        d = np.full(ex.shape, np.inf)
        d[inside] = self.distance[iy[inside], ix[inside]]
        if known is None:
            return float(np.mean(d <= near))
        seen = np.zeros(ex.shape, dtype=bool)
        seen[inside] = known[iy[inside], ix[inside]]
        return float(np.mean(d[seen] <= near)) if seen.any() else 1.0

    def see_through_fraction(
        self, pose: ArrayLike, ranges: ArrayLike, angles: ArrayLike, sensor_offset: ArrayLike,
        margin: float,
    ) -> float:  # fmt: skip
        """The fraction of the beams with a return that pass through an obstacle of the map:
        whose range exceeds, by more than ``margin`` metres, the distance to the first occupied
        cell along the beam from the robot pose ``pose`` (the laser at ``sensor_offset`` in the
        robot frame); 0.0 for a scan without a return.

        The likelihood field looks only at where a beam ends, not at what it crossed
        (Probabilistic Robotics section 6.4.4), so a scan can fit a look-alike place well while
        many of its beams run through walls there; seen from the right pose, only people, open
        doors and the map's own errors do.

        Examples
        --------
        >>> import numpy as np
        >>> from types import SimpleNamespace
        >>> occ = np.zeros((40, 40), bool); occ[:, 30] = True  # a wall at x = 1.5 m
        >>> lf = LikelihoodField(SimpleNamespace(resolution=0.05, origin=(0.0, 0.0),
        ...     shape=(40, 40)), occ, max_range=5.0)
        >>> lf.see_through_fraction([0.5, 1.0, 0.0], [1.0, 1.2], [0.0, 0.0], (0, 0, 0), 0.3)
        0.0
        >>> lf.see_through_fraction([0.5, 1.0, 0.0], [1.0, 1.9], [0.0, 0.0], (0, 0, 0), 0.3)
        0.5
        """
        from probmap.geometry.se2 import compose
        from probmap.grid.raycast import cast_rays

        r, a, o = scan_arrays(ranges, angles, sensor_offset)
        ok = np.isfinite(r) & (r > 0) & (r < self.max_range)
        if not ok.any():
            return 0.0
        laser = np.asarray(compose(np.asarray(pose, dtype=np.float64).reshape(3), o))
        spec: Any = self.spec  # cast_rays takes any GridGeometry
        expected = cast_rays(self.occupied, spec, laser.reshape(3), a[ok], self.max_range)
        return float(np.mean(r[ok] > expected + margin))
