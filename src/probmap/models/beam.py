"""The beam model of range finders (Probabilistic Robotics section 6.3, Tables 6.1 and 6.2).

A reading ``z`` of a beam whose expected range is ``z*`` is explained by a mixture of four
causes: the obstacle at ``z*`` with Gaussian noise (hit), an unexpected object before it
(short), a failure that reads the maximum range (max) and random noise (rand), eq. 6.12.

- :class:`BeamModelParams`: the intrinsic parameters of that mixture, with their rules, and its
  log-likelihood ``log p(z | z*)`` (one numba kernel, :mod:`probmap.models._beam_kernels`,
  shared by every user: this class, :class:`BeamModel` and the MAP mapper of
  :mod:`probmap.mapping.map_mapping`).
- :class:`BeamModel`: the model on a grid map, ``p(z | x, m)`` vectorised over poses ``(N, 3)``
  and beams ``(B,)``, with the expected range found by ray casting, by one of three methods
  (``ray_casting``):

  * ``"sphere"`` (default): sphere tracing on the Euclidean distance transform (the ray
    advances by the clearance to the nearest occupied cell minus one cell diagonal, at least
    half a cell, and stops in the first occupied cell); overshoots a face by under half a cell.
  * ``"exact"``: exact grid traversal (Amanatides-Woo, the grid's one traversal kernel
    :mod:`probmap.grid._traverse`) on the boolean map, the range to where the ray enters the
    first occupied cell.
  * ``"table"``: a ray-casting lookup table, expected range per cell x heading bin (``K``
    bins over 360 degrees, uint16, ``H * W * K * 2`` bytes of address space), each entry cast
    exactly from the cell centre at the bin's heading when first needed (memory pages are only
    touched for the cells particles visit). A query snaps the sensor to its cell centre (at most
    ``res / sqrt(2)`` away) and its beam heading to the nearest bin (at most ``pi / K`` off), so
    the range error grows with range and incidence: see ``tests/models/test_forward.py`` for the
    measured error against exact casting.

- :func:`fit_beam_model`: the intrinsic parameters fitted to readings and their expected ranges
  by EM (Table 6.2).

The map is a plain ``(spec, occupancy)`` pair (see :mod:`probmap.models.grid_map`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._typing import FloatArray
from probmap.models import _beam_kernels as _k
from probmap.models.grid_map import (
    GridGeometry,
    ScanLikelihood,
    checked_map,
    distance_field,
    poses_array,
    scan_arrays,
)

__all__ = ["BeamModel", "BeamModelParams", "FitResult", "component_densities", "fit_beam_model"]

_RAY_CASTING = ("sphere", "exact", "table")


@dataclass(frozen=True)
class BeamModelParams:
    """Intrinsic parameters of the beam model (Probabilistic Robotics Table 6.1, eq. 6.12).

    The one parameter class of the beam model: :class:`BeamModel` (particle weights), the MAP
    mapper (:mod:`probmap.mapping.map_mapping`) and the EM fit (:func:`fit_beam_model`) all
    take it, with one set of rules.

    Parameters
    ----------
    z_hit, z_short, z_max, z_rand : float
        Mixture weights of the hit, short, max-range and random components; they must sum to
        1, and ``z_max`` and ``z_rand`` must be positive so that every reading has a positive
        likelihood (the objective can never become infinite).
    sigma_hit : float
        Standard deviation of the hit Gaussian, metres.
    lambda_short : float
        Rate of the short-reading exponential, 1/m.
    """

    z_hit: float = 0.8
    z_short: float = 0.1
    z_max: float = 0.05
    z_rand: float = 0.05
    sigma_hit: float = 0.2
    lambda_short: float = 0.1

    def __post_init__(self) -> None:
        for name in ("z_hit", "z_short", "z_max", "z_rand", "sigma_hit", "lambda_short"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0.0):
                raise ValueError(f"BeamModelParams.{name} must be a finite number >= 0, got {v!r}")
        for name in ("z_max", "z_rand", "sigma_hit", "lambda_short"):
            if not getattr(self, name) > 0.0:
                raise ValueError(
                    f"BeamModelParams.{name} must be > 0 (it keeps every likelihood positive)"
                )
        total = self.z_hit + self.z_short + self.z_max + self.z_rand
        if abs(total - 1.0) > 1e-6:
            raise ValueError(
                f"BeamModelParams mixture weights z_hit + z_short + z_max + z_rand must sum to 1,"
                f" got {total:.6g}"
            )

    def as_array(self) -> NDArray[np.float64]:
        """``[z_hit, z_short, z_max, z_rand, sigma_hit, lambda_short]`` for the kernels."""
        return np.array(
            [
                self.z_hit,
                self.z_short,
                self.z_max,
                self.z_rand,
                self.sigma_hit,
                self.lambda_short,
            ]
        )

    def log_likelihood(self, z: ArrayLike, zs: ArrayLike, max_range: float) -> NDArray[np.float64]:
        """``log p(z | z*)`` elementwise for readings ``z`` and expected ranges ``zs`` (m).

        A reading at or beyond ``max_range`` is the max-range point mass; a negative reading
        has density 0 (``-inf``).

        Examples
        --------
        >>> p = BeamModelParams()
        >>> bool(p.log_likelihood(2.0, 2.0, 10.0) > p.log_likelihood(1.0, 2.0, 10.0))
        True
        >>> round(float(p.log_likelihood(10.0, 3.0, 10.0)), 4)  # log z_max
        -2.9957
        """
        zz, ss = np.broadcast_arrays(np.asarray(z, float), np.asarray(zs, float))
        zf = np.ascontiguousarray(zz.ravel())
        out = np.empty(zf.shape[0])
        _k.beam_log_likelihoods(
            zf, np.ascontiguousarray(ss.ravel()), float(max_range), self.as_array(), out
        )
        return out.reshape(zz.shape)


class BeamModel(ScanLikelihood):
    """Beam model of range finders, Probabilistic Robotics Table 6.1, with ray casting.

    Parameters
    ----------
    spec : GridGeometry
        Grid geometry.
    occupancy : (H, W) array_like
        Boolean or probability map (NaN unknown, treated as free for ray casting).
    max_range : float
        ``z_max`` (m).
    z_hit, z_short, z_max, z_rand, sigma_hit, lambda_short : float, optional
        The intrinsic parameters (mixture weights of equation 6.12, standard deviation (m) of
        the hit component, rate (1/m) of the short component); those not given take the
        defaults of :class:`BeamModelParams`, whose rules they follow (weights summing to 1,
        ``z_max`` and ``z_rand`` > 0).
    params : BeamModelParams, optional
        All six at once, instead of the keywords above.
    occupied_threshold : float
        Probability above which a cell is an obstacle.
    ray_casting : {"sphere", "exact", "table"}
        How expected ranges are found (see the module docstring): sphere tracing on the
        distance transform, exact grid traversal, or the lookup table of exact casts.
    heading_bins : int
        Heading bins ``K`` of the lookup table (``"table"`` only); the bin width is
        ``2 pi / K``.

    Attributes
    ----------
    model : BeamModelParams
        The intrinsic parameters.
    params : (6,) float64 ndarray
        The same as the kernels take them (:meth:`BeamModelParams.as_array`).
    """

    def __init__(
        self,
        spec: GridGeometry,
        occupancy: ArrayLike,
        *,
        max_range: float,
        z_hit: float | None = None,
        z_short: float | None = None,
        z_max: float | None = None,
        z_rand: float | None = None,
        sigma_hit: float | None = None,
        lambda_short: float | None = None,
        params: BeamModelParams | None = None,
        occupied_threshold: float = 0.65,
        ray_casting: str = "sphere",
        heading_bins: int = 360,
    ) -> None:
        frame, occupied = checked_map(spec, occupancy, occupied_threshold)
        if ray_casting not in _RAY_CASTING:
            raise ValueError(f"ray_casting must be one of {_RAY_CASTING}, got {ray_casting!r}")
        if not (isinstance(heading_bins, int) and 4 <= heading_bins <= 65536):
            raise ValueError(f"heading_bins must be an integer in [4, 65536], got {heading_bins!r}")
        given = {
            k: v
            for k, v in (
                ("z_hit", z_hit),
                ("z_short", z_short),
                ("z_max", z_max),
                ("z_rand", z_rand),
                ("sigma_hit", sigma_hit),
                ("lambda_short", lambda_short),
            )
            if v is not None
        }
        if params is None:
            params = BeamModelParams(**given)
        elif given:
            raise ValueError(f"give either params or {sorted(given)}, not both")
        if not (max_range > 0 and math.isfinite(max_range)):
            raise ValueError(f"max_range must be positive, got {max_range}")
        self.spec = spec
        self.frame = frame
        self.occupied = occupied
        self.max_range = float(max_range)
        self.distance = distance_field(occupied, frame.resolution)
        self.model = params
        self.params = params.as_array()
        self.ray_casting = ray_casting
        self.heading_bins = heading_bins
        # table entries store 1 + round(range / quantum) in uint16 (0 = not cast yet)
        self.range_quantum = self.max_range / 65534.0
        self._table: NDArray[np.uint16] | None = None
        self._normalisers: NDArray[np.float64] | None = None

    @property
    def range_table(self) -> NDArray[np.uint16]:
        """The ``(H, W, K)`` lookup table of ``ray_casting="table"`` (0 = not cast yet).

        Allocated zeroed on first use; the operating system maps its pages only when written,
        so memory grows with the cells visited, up to ``H * W * K * 2`` bytes.
        """
        if self._table is None:
            h, w = self.frame.shape
            self._table = np.zeros((h, w, self.heading_bins), dtype=np.uint16)
        return self._table

    def expected_ranges(
        self, poses: ArrayLike, angles: ArrayLike, sensor_offset: ArrayLike = (0.0, 0.0, 0.0)
    ) -> NDArray[np.float64]:
        """Ray-cast ranges ``z*`` (m) for every pose and beam, shape ``(N, B)``.

        Parameters
        ----------
        poses : (N, 3) array_like
            Robot poses (x, y, theta) in the map frame (m, rad).
        angles : (B,) array_like
            Beam angles (rad) in the sensor frame.
        sensor_offset : (3,) array_like
            Sensor pose in the robot frame.
        """
        p = poses_array(poses)
        a = np.ascontiguousarray(angles, dtype=np.float64)
        _, a, o = scan_arrays(np.zeros_like(a), a, sensor_offset)
        return self._expected_ranges(p, a, o)

    def _expected_ranges(
        self, p: NDArray[np.float64], a: NDArray[np.float64], o: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        out = np.empty((p.shape[0], a.shape[0]))
        f = self.frame
        if self.ray_casting == "sphere":
            _k.cast_rays(p, a, o, self.distance, f.x0, f.y0, f.resolution, self.max_range, out)
        elif self.ray_casting == "exact":
            _k.exact_ranges(p, a, o, self.occupied, f.x0, f.y0, f.resolution, self.max_range, out)
        else:
            _k.table_ranges(
                p,
                a,
                o,
                self.occupied,
                self.range_table,
                f.x0,
                f.y0,
                f.resolution,
                self.max_range,
                self.range_quantum,
                out,
            )
        return out

    def _log_likelihood(
        self, p: FloatArray, r: FloatArray, a: FloatArray, o: FloatArray
    ) -> FloatArray:
        # readings beyond max_range are clipped to it (the max-range component)
        if self.ray_casting == "table":
            scales = self._table_normalisers()
            out = np.empty((p.shape[0], r.shape[0]))
            f = self.frame
            _k.table_beam_model(
                p,
                r,
                a,
                o,
                self.occupied,
                self.range_table,
                scales,
                f.x0,
                f.y0,
                f.resolution,
                self.max_range,
                self.range_quantum,
                self.params,
                out,
            )
            return out
        zs = self._expected_ranges(p, a, o)
        out = np.empty_like(zs)
        _k.beam_mixture(zs, r, self.max_range, self.params, out)
        return out

    def _table_normalisers(self) -> NDArray[np.float64]:
        """Factors of Table 6.1 that depend on the expected range alone, per table value."""
        if self._normalisers is None:
            scales = np.empty((65536, 2))
            _k.table_normalisers(self.range_quantum, self.max_range, self.params, scales)
            self._normalisers = scales
        return self._normalisers


# ----------------------------------------------------------------------------- the EM fit


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit_beam_model`.

    Attributes
    ----------
    params : BeamModelParams
        The fitted parameters.
    log_likelihood : tuple of float
        Mean log-likelihood per reading after each iteration (index 0: the initial guess).
    iterations : int
    converged : bool
        The mean log-likelihood changed by less than ``tol`` in the last iteration.
    readings : int
        Readings used.
    """

    params: BeamModelParams
    log_likelihood: tuple[float, ...]
    iterations: int
    converged: bool
    readings: int


def component_densities(
    z: NDArray[np.float64],
    zs: NDArray[np.float64],
    max_range: float,
    sigma: float,
    lam: float,
) -> NDArray[np.float64]:
    """Densities ``p_hit, p_short, p_max, p_rand`` of each reading (eqs. 6.4-6.10), shape (4, N).

    ``p_max`` is the point mass at ``z_max`` (1 there, 0 elsewhere).
    """
    from scipy.special import erf

    below = z < max_range
    norm = 0.5 * (erf((max_range - zs) / (sigma * math.sqrt(2))) + erf(zs / (sigma * math.sqrt(2))))
    hit = np.where(
        below,
        np.exp(-0.5 * ((z - zs) / sigma) ** 2)
        / (sigma * math.sqrt(2 * math.pi) * np.maximum(norm, 1e-300)),
        0.0,
    )
    ok_short = below & (z <= zs) & (zs > 0)
    denom = -np.expm1(-lam * np.where(zs > 0, zs, 1.0))
    short = np.where(ok_short, lam * np.exp(-lam * z) / denom, 0.0)
    pmax = np.where(below, 0.0, 1.0)
    rand = np.where(below, 1.0 / max_range, 0.0)
    return np.stack([hit, short, pmax, rand])


def _check(ranges: ArrayLike, expected: ArrayLike, max_range: float) -> tuple[NDArray, NDArray]:
    z = np.asarray(ranges, dtype=np.float64)
    zs = np.asarray(expected, dtype=np.float64)
    if z.shape != zs.shape:
        raise ValueError(f"ranges {z.shape} and expected ranges {zs.shape} must have one shape")
    if not (math.isfinite(max_range) and max_range > 0):
        raise ValueError(f"max_range must be a finite number > 0 m, got {max_range}")
    keep = np.isfinite(z) & np.isfinite(zs) & (z >= 0) & (zs >= 0)
    z = np.minimum(z[keep], max_range)
    zs = np.minimum(zs[keep], max_range)
    if z.size < 10:
        raise ValueError(f"need at least 10 valid readings to fit the beam model, got {z.size}")
    return z, zs


def _lambda_step(e: NDArray, z: NDArray, zs: NDArray, lam0: float) -> float:
    """Maximiser of ``sum e (log lam - lam z - log(1 - exp(-lam zs)))`` by bisection."""
    w = e.sum()
    if w <= 1e-12:
        return lam0

    def slope(lam: float) -> float:
        x = lam * zs
        # zs * exp(-x) / (1 - exp(-x)) = zs / expm1(x), with the limit 1/lam at x -> 0
        tail = np.where(x > 1e-12, zs / np.expm1(np.clip(x, 1e-12, 700.0)), 1.0 / lam)
        return float(w / lam - np.sum(e * z) - np.sum(e * tail))

    lo, hi = 1e-6, 1e4
    if slope(lo) <= 0:
        return lo
    if slope(hi) >= 0:
        return hi
    for _ in range(80):
        mid = math.sqrt(lo * hi)
        if slope(mid) > 0:
            lo = mid
        else:
            hi = mid
    return math.sqrt(lo * hi)


def fit_beam_model(
    ranges: ArrayLike,
    expected: ArrayLike,
    max_range: float,
    *,
    init: BeamModelParams | None = None,
    max_iterations: int = 200,
    tol: float = 1e-7,
) -> FitResult:
    """Fit the beam model's intrinsic parameters by EM (Table 6.2).

    Parameters
    ----------
    ranges : array_like
        Measured ranges ``z_i`` in metres (any shape; NaN or negative readings are ignored,
        readings beyond ``max_range`` count as max-range readings).
    expected : array_like
        Ranges ``z*_i`` (m) the map predicts for the same beams, same shape.
    max_range : float
        The sensor's maximum range ``z_max`` in metres.
    init : BeamModelParams, optional
        Starting point (default :class:`BeamModelParams`).
    max_iterations : int
        Iteration limit.
    tol : float
        Stop when the mean log-likelihood per reading changes by less than this.

    Returns
    -------
    FitResult

    Notes
    -----
    Each reading is attributed softly to the four causes of the beam model (E-step) and the
    mixture weights and component parameters are re-estimated from those attributions (M-step):

    - ``z_c = (1/|Z|) sum_i e_i,c`` for the weights,
    - ``sigma_hit^2 = sum_i e_i,hit (z_i - z*_i)^2 / sum_i e_i,hit`` (Table 6.2),
    - ``lambda_short`` maximising ``sum_i e_i,short log p_short(z_i | z*_i)`` exactly, i.e. with
      the truncation normaliser ``1 / (1 - exp(-lambda z*_i))`` of eq. 6.7 (Table 6.2's closed
      form ``sum e / sum e z`` ignores it and is only its limit for long ``z*``). The weighted
      log-likelihood of a truncated exponential is concave in lambda, so bisection on its
      derivative finds the maximiser.

    Unlike the book's listing, the E-step weighs each component by its current mixture weight
    (``e_i,c ∝ z_c p_c(z_i)``), which is what makes the procedure EM. The sigma update ignores
    the truncation of the Gaussian to ``[0, z_max]`` (negligible unless ``z*`` is within a few
    sigma of either end). The E-step needs each component's density apart
    (:func:`component_densities`, vectorised numpy); their mixture is the one log-likelihood
    kernel's (``tests/models/test_beam_fit.py`` checks that they agree).

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> zs = rng.uniform(1, 5, 5000)
    >>> z = zs + rng.normal(0, 0.1, zs.size)
    >>> fit = fit_beam_model(z, zs, 10.0)
    >>> round(fit.params.sigma_hit, 2), fit.params.z_hit > 0.95
    (0.1, True)
    """
    z, zs = _check(ranges, expected, float(max_range))
    p = init or BeamModelParams()
    weights = np.array([p.z_hit, p.z_short, p.z_max, p.z_rand])
    sigma, lam = p.sigma_hit, p.lambda_short
    floor = 1e-6  # z_max and z_rand stay positive, so no reading ever has zero likelihood
    history: list[float] = []
    converged = False
    it = 0
    for it in range(max_iterations + 1):
        dens = component_densities(z, zs, max_range, sigma, lam) * weights[:, None]
        total = dens.sum(axis=0)
        history.append(float(np.mean(np.log(total))))
        if it > 0 and abs(history[-1] - history[-2]) < tol:
            converged = True
            break
        if it == max_iterations:
            break
        e = dens / total  # E-step: responsibilities of the four causes
        weights = np.maximum(e.mean(axis=1), floor)
        weights /= weights.sum()
        sw = e[0].sum()
        if sw > 1e-12:
            sigma = max(float(np.sqrt(np.sum(e[0] * (z - zs) ** 2) / sw)), 1e-4)
        lam = _lambda_step(e[1], z, zs, lam)
    params = BeamModelParams(
        z_hit=float(weights[0]),
        z_short=float(weights[1]),
        z_max=float(weights[2]),
        z_rand=float(1.0 - weights[0] - weights[1] - weights[2]),
        sigma_hit=sigma,
        lambda_short=lam,
    )
    return FitResult(params, tuple(history), it, converged, int(z.size))
