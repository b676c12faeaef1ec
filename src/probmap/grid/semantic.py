"""Multi-class (semantic) occupancy grids: the multi-class Bayes filter in log-odds form.

Each cell ``m_i`` holds one of ``K + 1`` classes; class 0 is the reference class (free space by
default). A cell stores the vector of log odds against the reference,

    l_t,i[k] = log p(m_i = k | z_1:t) / p(m_i = 0 | z_1:t),    k = 1..K,

and, by Bayes' rule and the Markov assumption (the derivation of the binary filter,
Probabilistic Robotics Table 4.2 / eq. 4.8-4.9, carried out per class against class 0),

    l_t,i[k] = log p(m_i=k | z_t) / p(m_i=0 | z_t)      (inverse term)
             + log p(m_i=0) / p(m_i=k)                  (prior term)
             + l_{t-1},i[k]                              (recursive term).

The posterior is a softmax with class 0's logit fixed at 0. With ``K = 1`` (classes free and
occupied) this is exactly the binary occupancy grid of :mod:`probmap.grid.occupancy`
(Table 9.1), and :class:`SemanticGrid` then reproduces :class:`OccupancyGrid` bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.grid._storage import _ScanGrid, grid_resolution, observed_mask, plan_growth, regrid
from probmap.grid.logodds import logit
from probmap.grid.occupancy import (
    OccupancyGrid,
    ScanStats,
    check_angles_and_max_range,
    check_beam_model_fields,
    check_one_scan,
    check_poses,
    effective_clear_range,
)
from probmap.grid.spec import GridSpec

__all__ = [
    "DEFAULT_COLORS",
    "LabelledInverseModel",
    "SemanticGrid",
    "class_entropy",
    "check_labels",
    "check_probabilities",
    "class_posterior",
    "inverse_term",
    "map_argmax",
    "occupancy_log_odds",
]

#: Default class colours (RGB): free, then a qualitative palette for the object classes.
DEFAULT_COLORS: tuple[tuple[int, int, int], ...] = (
    (255, 255, 255),
    (31, 119, 180),
    (214, 39, 40),
    (44, 160, 44),
    (255, 127, 14),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
    (0, 0, 128),
    (128, 0, 0),
    (0, 128, 0),
    (128, 128, 0),
    (0, 128, 128),
    (128, 0, 128),
)

#: Tolerance on the sum of a class probability vector.
PROB_SUM_TOL = 1e-3


# --------------------------------------------------------------------------- function tier
def inverse_term(q: ArrayLike) -> NDArray[np.float64]:
    """Log ratios ``log p(m=k | z) / p(m=0 | z)`` for classes 1..K from their probabilities.

    Parameters
    ----------
    q : array_like, shape (..., K)
        ``p(m = k | z)`` of classes 1..K; class 0 has ``1 - sum(q)``.

    Returns
    -------
    ndarray, shape (..., K)
        ``log q_k - log1p(-sum(q))``. ``log1p`` keeps the reference term exact when class 0 is
        nearly certain, and with one class it is exactly :func:`probmap.grid.logodds.logit`.

    Examples
    --------
    >>> from probmap.grid.logodds import logit
    >>> float(inverse_term([0.7])[0]) == logit(0.7)
    True
    >>> inverse_term([0.25, 0.5]).round(6).tolist()
    [0.0, 0.693147]
    """
    qa = np.asarray(q, dtype=np.float64)
    return np.asarray(np.log(qa) - np.log1p(-qa.sum(axis=-1, keepdims=True)), dtype=np.float64)


def class_posterior(log_odds: ArrayLike) -> NDArray[np.float64]:
    """Posterior over the K + 1 classes from log odds against class 0 (a softmax, logit 0 = 0).

    Evaluated as ``exp(l_k - m) / (exp(-m) + sum_j exp(l_j - m))`` with ``m = max(0, max_k l_k)``
    so that no ``exp`` overflows for large log odds.

    Parameters
    ----------
    log_odds : array_like, shape (..., K)
        ``l[k-1] = log p(k) / p(0)`` for classes 1..K (finite or ``-inf``).

    Returns
    -------
    ndarray, shape (..., K + 1)
        Class probabilities; they sum to 1 along the last axis.

    Examples
    --------
    >>> class_posterior([0.0, 0.0]).round(4).tolist()
    [0.3333, 0.3333, 0.3333]
    >>> class_posterior([1000.0, 0.0]).tolist()
    [0.0, 1.0, 0.0]
    """
    la = np.asarray(log_odds, dtype=np.float64)
    m = np.maximum(la.max(axis=-1, keepdims=True), 0.0)
    e = np.exp(la - m)
    e0 = np.exp(-m)
    z = e0 + e.sum(axis=-1, keepdims=True)
    return np.concatenate([e0 / z, e / z], axis=-1)


def occupancy_log_odds(log_odds: ArrayLike) -> NDArray[np.float64]:
    """Binary log odds of "not class 0": ``log (1 - p(0)) / p(0) = logsumexp_k l_k``.

    With one class this is ``l`` itself. Shape (..., K) -> (...).

    Examples
    --------
    >>> round(float(occupancy_log_odds([0.0, 0.0])), 6) == round(math.log(2.0), 6)
    True
    """
    la = np.asarray(log_odds, dtype=np.float64)
    if la.shape[-1] == 1:
        return np.asarray(la[..., 0], dtype=np.float64)
    m = la.max(axis=-1)
    m = np.where(np.isfinite(m), m, 0.0)
    return np.asarray(m + np.log(np.exp(la - m[..., None]).sum(axis=-1)), dtype=np.float64)


def class_entropy(log_odds: ArrayLike) -> NDArray[np.float64]:
    """Entropy in nats of each cell's class posterior, ``-sum_k p_k log p_k``, shape (...,).

    Computed as ``log Z - sum_k p_k l_k`` with ``log Z = logsumexp(0, l_1..l_K)``, which stays
    finite where some ``p_k`` underflow to 0.

    Examples
    --------
    >>> round(float(class_entropy([0.0, 0.0, 0.0])), 6) == round(math.log(4.0), 6)
    True
    """
    la = np.asarray(log_odds, dtype=np.float64)
    m = np.maximum(la.max(axis=-1), 0.0)
    e = np.exp(la - m[..., None])
    z = np.exp(-m) + e.sum(axis=-1)
    log_z = m + np.log(z)
    p = e / z[..., None]
    # p_k * l_k with p_k = 0 and l_k = -inf counts as 0
    pl = np.where(p > 0.0, p * np.where(np.isfinite(la), la, 0.0), 0.0).sum(axis=-1)
    return np.asarray(np.maximum(log_z - pl, 0.0), dtype=np.float64)


def map_argmax(log_odds: ArrayLike) -> NDArray[np.int16]:
    """Most probable class per cell (0 = reference) from log odds, shape (..., K) -> (...).

    Ties go to the lower class index.

    Examples
    --------
    >>> map_argmax([[-1.0, -2.0], [0.5, 2.0], [0.0, 0.0]]).tolist()
    [0, 2, 0]
    """
    la = np.asarray(log_odds, dtype=np.float64)
    best = la.argmax(axis=-1)
    top = np.take_along_axis(la, best[..., None], axis=-1)[..., 0]
    return np.where(top > 0.0, best + 1, 0).astype(np.int16)


# --------------------------------------------------------------------------- sensor model
@dataclass(frozen=True)
class LabelledInverseModel:
    """Inverse sensor model for labelled range beams (Table 9.2 generalised to K + 1 classes).

    A cell a beam crosses gets evidence for the free class 0: ``p(m = 0 | z) = 1 - p_miss``,
    the rest spread evenly over classes 1..K. A beam's endpoint cell (and the ``thickness``
    behind it) gets ``p(m = 0 | z) = 1 - p_hit`` and ``p(m = k | z) = p_hit * v_k`` where ``v``
    is the beam's class distribution over classes 1..K: for a hard label ``c``, ``v_c =
    p_correct`` and ``(1 - p_correct) / (K - 1)`` for every other class (the confusion model);
    for a probability vector (a segmentation network's output), ``v`` itself. With ``K >= 2``,
    ``v`` is mixed with ``label_floor`` of the uniform distribution so that no class gets
    probability 0 (a zero would be an infinite, irrevocable veto).

    Parameters
    ----------
    p_hit : float
        ``p(m != 0 | z)`` at a beam's endpoint. Default 0.7.
    p_miss : float
        ``p(m != 0 | z)`` for cells a beam crosses. Default 0.4.
    p_correct : float
        Probability that a hard label is right, in (0, 1]. Ignored with one class.
    thickness : float
        Depth in metres behind an endpoint that gets the endpoint's evidence.
    max_clear_range : float or None
        Free space cleared by a reading at or beyond the maximum range, metres (``None``: the
        maximum range; 0 ignores such readings).
    label_floor : float
        Weight of the uniform distribution mixed into every class distribution (K >= 2).
    """

    p_hit: float = 0.7
    p_miss: float = 0.4
    p_correct: float = 0.9
    thickness: float = 0.0
    max_clear_range: float | None = None
    label_floor: float = 1e-4

    def __post_init__(self) -> None:
        check_beam_model_fields(self, "LabelledInverseModel")
        if not 0.0 < self.p_correct <= 1.0:
            raise ValueError(
                f"LabelledInverseModel.p_correct must lie in (0, 1], got {self.p_correct}"
            )
        if not 0.0 <= self.label_floor < 1.0:
            raise ValueError(
                f"LabelledInverseModel.label_floor must lie in [0, 1), got {self.label_floor}"
            )

    def confusion(self, n_classes: int) -> NDArray[np.float64]:
        """Class distributions ``v`` of hard labels 1..K: row ``c - 1`` for label ``c``, (K, K)."""
        K = int(n_classes)
        if K == 1:
            return np.ones((1, 1))
        v = np.full((K, K), (1.0 - self.p_correct) / (K - 1))
        np.fill_diagonal(v, self.p_correct)
        return self._floor(v)

    def _floor(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        K = v.shape[-1]
        if K == 1:
            return np.ones_like(v)
        return (1.0 - self.label_floor) * v + self.label_floor / K

    def hit_probabilities(self, v: ArrayLike) -> NDArray[np.float64]:
        """``p(m = k | z)`` for classes 1..K at an endpoint with class distribution(s) ``v``.

        ``v`` has shape (..., K) and sums to 1; the result is ``p_hit * v`` (after the floor).
        """
        va = np.asarray(v, dtype=np.float64)
        if va.shape[-1] > 1:
            va = self._floor(va)
        else:
            va = np.ones_like(va)
        return np.asarray(self.p_hit * va, dtype=np.float64)

    def free_probabilities(self, n_classes: int) -> NDArray[np.float64]:
        """``p(m = k | z)`` for classes 1..K in a cell a beam crosses, shape (K,)."""
        return np.full(int(n_classes), self.p_miss / int(n_classes))


# --------------------------------------------------------------------------- grid
def _check_classes(classes: Sequence[str]) -> tuple[str, ...]:
    if isinstance(classes, str):
        raise ValueError("classes must be a sequence of class names, not one string")
    names = tuple(str(c) for c in classes)
    if len(names) < 2:
        raise ValueError(
            f"classes must name the reference class 0 and at least one more, got {list(names)}"
        )
    if any(not n.strip() for n in names):
        raise ValueError(f"class names must not be empty, got {list(names)}")
    if len(set(names)) != len(names):
        raise ValueError(f"class names must be unique, got {list(names)}")
    return names


def _check_colors(colors: ArrayLike | None, n: int) -> NDArray[np.uint8]:
    if colors is None:
        if n > len(DEFAULT_COLORS):
            rng = np.random.default_rng(n)
            extra = rng.integers(0, 256, (n - len(DEFAULT_COLORS), 3))
            return np.vstack([np.asarray(DEFAULT_COLORS), extra]).astype(np.uint8)
        return np.asarray(DEFAULT_COLORS[:n], dtype=np.uint8)
    c = np.asarray(colors)
    if c.shape != (n, 3):
        raise ValueError(f"colors must have shape ({n}, 3) (RGB per class), got {c.shape}")
    if not np.issubdtype(c.dtype, np.number) or not np.isfinite(c).all():
        raise ValueError("colors must be numbers in 0..255")
    if (c < 0).any() or (c > 255).any() or (c != np.round(c)).any():
        raise ValueError("colors must be integers in 0..255")
    return c.astype(np.uint8)


def _per_scan(name: str, value: Any, n_scans: int, beams: int, tail: tuple[int, ...]) -> NDArray:
    """Stack per-scan arrays of shape (B, *tail) into (S, B, *tail), naming the bad scan."""
    if isinstance(value, np.ndarray) and value.dtype != object:
        arr = value
        if arr.ndim == 1 + len(tail) and n_scans == 1 and arr.shape[0] == beams:
            arr = arr[None]
        if arr.ndim != 2 + len(tail) or arr.shape[2:] != tail:
            want = ", ".join(["S", "B", *map(str, tail)])
            raise ValueError(f"{name} must have shape ({want}), got {arr.shape}")
        if arr.shape[0] != n_scans:
            raise ValueError(f"{name} has {arr.shape[0]} scans, ranges has {n_scans}")
        if arr.shape[1] != beams:
            raise ValueError(f"scan 0: {name} has {arr.shape[1]} entries, ranges has {beams} beams")
        return arr
    seq = list(value)
    if len(seq) != n_scans:
        raise ValueError(f"{name} has {len(seq)} scans, ranges has {n_scans}")
    out = []
    for s, item in enumerate(seq):
        a = np.asarray(item)
        if a.ndim == 0 or a.shape[0] != beams:
            n = 0 if a.ndim == 0 else a.shape[0]
            raise ValueError(f"scan {s}: {name} has {n} entries, ranges has {beams} beams")
        if a.shape[1:] != tail:
            raise ValueError(f"scan {s}: {name} entries must have shape {tail}, got {a.shape[1:]}")
        out.append(a)
    return np.stack(out) if out else np.empty((0, beams, *tail))


def _small(v: NDArray[np.float64]) -> Any:
    """Per-class constants for the kernel: a tuple up to 8 classes (its length is part of the
    compiled type, so the class loop is unrolled and the values stay in registers), an array
    beyond (long tuples are indexed through memory, slower than an array)."""
    if v.shape[0] <= 8:
        return tuple(float(x) for x in v)
    return np.ascontiguousarray(v, dtype=np.float64)


class SemanticGrid(_ScanGrid):
    """A 2-D multi-class occupancy grid: per cell, float32 log odds of K classes against class 0.

    Parameters
    ----------
    classes : sequence of str
        ``K + 1`` class names; ``classes[0]`` is the reference class, the class that space a beam
        crosses is evidence for (free space, default name "free"). Default ``("free",
        "occupied")``, the binary grid.
    resolution : float
        Cell side in metres. Default 0.05.
    prior : array_like, shape (K + 1,), optional
        Prior class probabilities ``p(m = k)`` (positive, summing to 1). Default uniform.
    clamp : (p_min, p_max) or array_like, shape (K, 2)
        Per-class clamping: ``l[k]`` stays in ``[logit(p_min), logit(p_max)]``, i.e. the pairwise
        probability ``p(k) / (p(k) + p(0))`` stays in ``[p_min, p_max]``, so the map can still
        change. Default (0.01, 0.99). The prior must lie inside.
    model : LabelledInverseModel, optional
        The inverse sensor model (default ``LabelledInverseModel()``).
    colors : array_like, shape (K + 1, 3), optional
        RGB colour of each class (0..255) for images. Default :data:`DEFAULT_COLORS`.
    spec : GridSpec, optional
        Initial geometry; without it the grid is laid out around the first scan.
    fixed : bool
        If true the grid never grows: scans outside ``spec`` raise :class:`GridBoundsError`.

    Notes
    -----
    The once-per-scan rule (one scan is one measurement ``z_t``): every cell gets at most one
    update per scan, and endpoint evidence wins over free space. When several endpoints fall in
    one cell in one scan, the cell's inverse model for that scan is the average of their class
    distributions (a linear opinion pool: the scan says "one of these beams' returns is what
    occupies the cell"), so two endpoints labelled wall and door split their evidence between the
    two classes instead of counting as two independent measurements; endpoints that all carry the
    same distribution give exactly that distribution. The pool does not depend on beam order.

    Examples
    --------
    >>> import numpy as np
    >>> grid = SemanticGrid(["free", "wall", "door"], resolution=0.1)
    >>> angles = np.linspace(-0.5, 0.5, 11)
    >>> labels = np.where(angles < 0, 1, 2)
    >>> stats = grid.integrate_scan([0, 0, 0], np.full(11, 2.0), angles, labels=labels, max_range=5)
    >>> stats.hits
    11
    >>> ix, iy = grid.spec.world_to_cell([2.0 * np.cos(0.4), 2.0 * np.sin(0.4)])
    >>> grid.classes[grid.argmax()[iy, ix]]
    'door'
    >>> float(grid.probabilities().sum(axis=-1).round(12).min())
    1.0
    """

    def __init__(
        self,
        classes: Sequence[str] = ("free", "occupied"),
        *,
        resolution: float = 0.05,
        prior: ArrayLike | None = None,
        clamp: ArrayLike = (0.01, 0.99),
        model: LabelledInverseModel | None = None,
        colors: ArrayLike | None = None,
        spec: GridSpec | None = None,
        fixed: bool = False,
    ) -> None:
        self.classes = _check_classes(classes)
        K = len(self.classes) - 1
        res = grid_resolution(spec, resolution)
        if fixed and spec is None:
            raise ValueError("a fixed-bounds grid needs a spec (GridSpec) giving its bounds")
        if prior is None:
            pr = np.full(K + 1, 1.0 / (K + 1))
        else:
            pr = np.asarray(prior, dtype=np.float64)
            if pr.shape != (K + 1,):
                raise ValueError(
                    f"prior must have one probability per class ({K + 1}), got shape {pr.shape}"
                )
            if not (np.isfinite(pr).all() and (pr > 0).all() and (pr < 1).all()):
                raise ValueError(f"prior probabilities must lie in (0, 1), got {pr.tolist()}")
            if abs(pr.sum() - 1.0) > 1e-6:
                raise ValueError(f"prior must sum to 1, sums to {pr.sum():.6g}")
        cl = np.asarray(clamp, dtype=np.float64)
        if cl.shape == (2,):
            cl = np.tile(cl, (K, 1))
        if cl.shape != (K, 2):
            raise ValueError(f"clamp must be (p_min, p_max) or shape ({K}, 2), got {cl.shape}")
        if not ((cl > 0).all() and (cl < 1).all() and (cl[:, 0] <= cl[:, 1]).all()):
            raise ValueError(f"clamp must satisfy 0 < p_min <= p_max < 1, got {cl.tolist()}")
        self.resolution = res
        self.prior = pr
        # l_prior[k] = log p(k) / p(0), with log p(0) = log1p(-sum_k p(k)) (exact for K = 1)
        self.l_prior = inverse_term(pr[1:])
        self.clamp = cl
        self.l_min = np.asarray(logit(cl[:, 0]), dtype=np.float64).reshape(K)
        self.l_max = np.asarray(logit(cl[:, 1]), dtype=np.float64).reshape(K)
        if not ((self.l_min <= self.l_prior) & (self.l_prior <= self.l_max)).all():
            raise ValueError(
                "the prior log odds log p(k)/p(0) must lie inside the clamping bounds: "
                f"prior {self.l_prior.round(4).tolist()}, bounds "
                f"{np.column_stack([self.l_min, self.l_max]).round(4).tolist()}"
            )
        self.model = model if model is not None else LabelledInverseModel()
        self.colors = _check_colors(colors, K + 1)
        self.fixed = bool(fixed)
        self._scans = 0
        if spec is None:
            spec = GridSpec(res, (0.0, 0.0), (0, 0))
        self._spec = spec
        self._lo = self._blank(spec.shape)
        self._stamp = np.zeros(spec.shape, dtype=np.int32)
        self._slot = np.zeros(spec.shape, dtype=np.int32)

    def _blank(self, shape: tuple[int, int]) -> NDArray[np.float32]:
        lo = np.empty((*shape, self.n_classes), dtype=np.float32)
        lo[...] = self.l_prior.astype(np.float32)
        return lo

    # ------------------------------------------------------------------ state
    @property
    def n_classes(self) -> int:
        """K: the number of classes besides the reference class 0."""
        return len(self.classes) - 1

    @property
    def log_odds(self) -> NDArray[np.float32]:
        """Log odds ``log p(k)/p(0)``, shape (H, W, K), float32, indexed ``[iy, ix, k - 1]``."""
        return self._lo

    def probabilities(self) -> NDArray[np.float64]:
        """Posterior class probabilities per cell, shape (H, W, K + 1), summing to 1."""
        return class_posterior(self._lo)

    def argmax(self) -> NDArray[np.int16]:
        """Most probable class per cell (0 = reference), shape (H, W)."""
        return map_argmax(self._lo)

    def classify(self) -> NDArray[np.int16]:
        """Most probable class of observed cells, -1 for cells never observed, shape (H, W)."""
        out = self.argmax()
        out[~self.observed] = -1
        return out

    def entropy(self) -> NDArray[np.float64]:
        """Entropy in nats of each cell's class posterior, shape (H, W)."""
        return class_entropy(self._lo)

    def occupancy(self) -> NDArray[np.float64]:
        """``p(occupied) = 1 - p(class 0)`` per cell, shape (H, W)."""
        from probmap.grid.logodds import prob

        return np.asarray(prob(occupancy_log_odds(self._lo)), dtype=np.float64)

    def to_occupancy(self) -> OccupancyGrid:
        """The derived binary occupancy grid, ``l = log (1 - p(0)) / p(0)`` per cell.

        Its log odds are ``logsumexp_k l_k`` (exactly ``l_1`` with one class); its prior is
        ``1 - p(m = 0)`` and its clamping bounds those of the classes combined.
        """
        from probmap.grid.logodds import prob

        lo = occupancy_log_odds(self._lo)
        p0 = float(self.prior[1:].sum())
        lo_min = float(occupancy_log_odds(self.l_min))
        lo_max = float(occupancy_log_odds(self.l_max))
        eps = 1e-9
        cmin = min(max(float(prob(lo_min)), eps), p0)
        cmax = max(min(float(prob(lo_max)), 1.0 - eps), p0)
        return OccupancyGrid.from_log_odds(
            self._spec, lo, p0=p0, clamp=(cmin, cmax), observed=self.observed
        )

    @classmethod
    def from_log_odds(
        cls,
        classes: Sequence[str],
        spec: GridSpec,
        log_odds: ArrayLike,
        *,
        observed: ArrayLike | None = None,
        scans: int | None = None,
        **kwargs: Any,
    ) -> SemanticGrid:
        """Rebuild a grid from stored log odds (H, W, K) and the mask of observed cells.

        ``kwargs`` are the constructor's (prior, clamp, model, colors, fixed).
        """
        grid = cls(classes, resolution=spec.resolution, spec=spec, **kwargs)
        lo = np.asarray(log_odds)
        want = (*spec.shape, grid.n_classes)
        if lo.shape != want:
            raise ValueError(f"log_odds shape {lo.shape} does not match (H, W, K) = {want}")
        if not np.isfinite(lo).all():
            raise ValueError("log_odds must be finite")
        grid._lo = np.ascontiguousarray(lo, dtype=np.float32).copy()
        seen = observed_mask(
            observed, spec, lambda: (grid._lo != grid.l_prior.astype(np.float32)).any(axis=-1)
        )
        grid._stamp = seen.astype(np.int32)
        grid._scans = int(scans) if scans is not None else int(seen.any())
        return grid

    # ------------------------------------------------------------------ growth
    def _ensure_bounds(self, box: NDArray[np.float64]) -> None:
        new, off = plan_growth(self._spec, box, fixed=self.fixed)
        if new is self._spec:
            return
        self._lo = regrid(self._lo, new.shape, off, self.l_prior.astype(np.float32))
        self._stamp = regrid(self._stamp, new.shape, off, 0)
        self._slot = np.zeros(new.shape, dtype=np.int32)
        self._spec = new

    # ------------------------------------------------------------------ updates
    def integrate_scan(
        self,
        pose: ArrayLike,
        ranges: ArrayLike,
        angles: ArrayLike,
        *,
        labels: ArrayLike | None = None,
        probabilities: ArrayLike | None = None,
        max_range: float = math.inf,
    ) -> ScanStats:
        """Integrate one labelled scan ``z_t`` from a known sensor pose.

        Parameters as :meth:`integrate_scans` for a single scan: ``ranges`` (B,), ``labels``
        (B,) or ``probabilities`` (B, K).
        """
        p, r = check_one_scan(pose, ranges)
        return self.integrate_scans(
            p[None, :],
            r[None, :],
            angles,
            labels=None if labels is None else [labels],
            probabilities=None if probabilities is None else [probabilities],
            max_range=max_range,
        )

    def integrate_scans(
        self,
        poses: ArrayLike,
        ranges: ArrayLike,
        angles: ArrayLike,
        *,
        labels: ArrayLike | Sequence[ArrayLike] | None = None,
        probabilities: ArrayLike | Sequence[ArrayLike] | None = None,
        max_range: float = math.inf,
    ) -> ScanStats:
        """Integrate a batch of labelled scans in order, each one measurement ``z_t``.

        Parameters
        ----------
        poses : array_like, shape (S, 3)
            Sensor poses ``(x, y, theta)`` in the world frame (metres, radians).
        ranges : array_like, shape (S, B)
            Ranges in metres. NaN, inf, zero and negative readings are dropped; readings
            ``>= max_range`` have no endpoint (free space only).
        angles : array_like, shape (B,) or (S, B)
            Beam angles in radians in the sensor frame.
        labels : array_like of int, shape (S, B), optional
            Hard class label 1..K of each beam's endpoint (through the model's confusion model).
            Beams without an endpoint may carry any label (it is ignored).
        probabilities : array_like, shape (S, B, K), optional
            Class distribution over classes 1..K of each beam's endpoint (non-negative, summing
            to 1 within 1e-3). Give exactly one of ``labels`` and ``probabilities``; with one
            class both may be left out (every endpoint is "occupied").
        max_range : float
            The sensor's maximum range in metres.

        Returns
        -------
        ScanStats
            Counts of beams, hits, max-range and dropped readings and cell updates (a cell
            update changes all K log odds of one cell).

        Raises
        ------
        ValueError
            Labels out of range, probability vectors with negatives or not summing to 1, or
            per-scan arrays whose lengths disagree: the message names the scan (and beam).
        """
        from probmap.grid import _semantic_kernels

        K = self.n_classes
        P = check_poses(poses)
        S = P.shape[0]
        if isinstance(ranges, np.ndarray) and ranges.dtype != object and ranges.ndim == 2:
            R = np.ascontiguousarray(ranges, dtype=np.float64)
            if R.shape[0] != S:
                raise ValueError(f"ranges must have shape (S, B) with S = {S} poses, got {R.shape}")
        else:
            seq = list(ranges)  # type: ignore[arg-type]
            if len(seq) != S:
                raise ValueError(f"ranges has {len(seq)} scans, poses has {S}")
            if seq and np.ndim(seq[0]) != 1:
                raise ValueError(
                    f"ranges must have shape (S, B), scan 0 has shape {np.shape(seq[0])}"
                )
            B0 = int(np.shape(seq[0])[0]) if seq else 0
            R = _per_scan("ranges", seq, S, B0, ()).astype(np.float64)
            R = np.ascontiguousarray(R)
        B = R.shape[1]
        A, shared, max_range = check_angles_and_max_range(angles, R, max_range)
        hit = np.isfinite(R) & (R > 0.0) & (R < max_range)
        qrow, q_hit = self._endpoint_evidence(labels, probabilities, hit, S, B)
        d_hit = inverse_term(q_hit) - self.l_prior
        d_free = inverse_term(self.model.free_probabilities(K)) - self.l_prior
        clear_range = effective_clear_range(self.model.max_clear_range, max_range)
        if S == 0:
            return ScanStats(0, 0, 0, 0, 0, 0)
        self._fit_scans(P, R, A, shared, max_range, clear_range)
        if self._scans + S >= np.iinfo(np.int32).max:  # pragma: no cover
            raise OverflowError("more than 2**31 scans in one grid")
        counts = np.zeros(4, dtype=np.int64)
        ox, oy = self._spec.origin
        res, thickness = self._spec.resolution, self.model.thickness
        scan = (ox, oy, res, P, R, A, shared, max_range, clear_range, thickness)
        _semantic_kernels.integrate_labelled_scans(
            self._lo,
            self._stamp,
            self._slot,
            self._scans + 1,
            scan,
            qrow,
            np.ascontiguousarray(q_hit),
            np.ascontiguousarray(d_hit),
            _small(d_free),
            np.ascontiguousarray(self.l_prior),
            _small(self.l_min),
            _small(self.l_max),
            counts,
        )
        self._scans += S
        return ScanStats.from_counts(S, R.size, counts)

    def _endpoint_evidence(
        self,
        labels: Any,
        probabilities: Any,
        hit: NDArray[np.bool_],
        S: int,
        B: int,
    ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Validate labels or probabilities; return each beam's row and the evidence table."""
        K = self.n_classes
        if labels is not None and probabilities is not None:
            raise ValueError("give labels or probabilities, not both")
        if probabilities is None:
            if labels is None:
                if K != 1:
                    raise ValueError(
                        f"labels or probabilities are needed with {K} classes besides "
                        f"{self.classes[0]!r}"
                    )
                return np.zeros((S, B), np.int64), self.model.hit_probabilities(np.ones((1, 1)))
            lab = check_labels(_per_scan("labels", labels, S, B, ()), hit, self.classes)
            qrow = np.where(hit, lab - 1, 0).astype(np.int64)
            q = self.model.hit_probabilities(self.model.confusion(K))
            return np.ascontiguousarray(qrow), q
        v = check_probabilities(_per_scan("probabilities", probabilities, S, B, (K,)), hit)
        q = self.model.hit_probabilities(v.reshape(S * B, K))
        return np.arange(S * B, dtype=np.int64).reshape(S, B), np.ascontiguousarray(q)


def check_labels(
    labels: ArrayLike, hit: NDArray[np.bool_], classes: Sequence[str]
) -> NDArray[np.int64]:
    """Validate hard labels (S, B): every beam with an endpoint (``hit``) must carry 1..K.

    Beams without an endpoint may carry anything (it is ignored; 0 is returned for them).

    Raises
    ------
    ValueError
        Naming the first scan and beam with a label out of range (or not an integer).
    """
    K = len(classes) - 1
    lab = np.asarray(labels)
    if lab.shape != hit.shape:
        raise ValueError(f"labels have shape {lab.shape}, ranges {hit.shape}")
    if lab.dtype.kind == "f":
        ok = np.isfinite(lab) & (lab == np.round(lab))
        bad = hit & ~ok
        if bad.any():
            s, b = (int(v) for v in np.argwhere(bad)[0])
            raise ValueError(f"scan {s}: label {lab[s, b]} of beam {b} is not an integer")
        lab = np.where(hit, lab, 0)
    elif lab.dtype.kind not in "iub":
        raise ValueError(f"labels must be integers 1..{K}, got dtype {lab.dtype}")
    lab = np.where(hit, lab, 0).astype(np.int64)
    bad = hit & ((lab < 1) | (lab > K))
    if bad.any():
        s, b = (int(v) for v in np.argwhere(bad)[0])
        raise ValueError(
            f"scan {s}: label {int(lab[s, b])} of beam {b} is outside 1..{K} "
            f"(classes {list(classes[1:])})"
        )
    return lab


def check_probabilities(probabilities: ArrayLike, hit: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Validate per-beam class distributions (S, B, K) and renormalise them to sum to 1.

    Every beam with an endpoint (``hit``) needs finite, non-negative entries summing to 1 within
    :data:`PROB_SUM_TOL`; other beams may hold anything (they get the uniform distribution).

    Raises
    ------
    ValueError
        Naming the first scan and beam whose vector is bad, and why.
    """
    prb = np.asarray(probabilities, dtype=np.float64)
    if prb.shape[:2] != hit.shape or prb.ndim != 3:
        raise ValueError(
            f"probabilities have shape {prb.shape}, want (S, B, K) with ranges {hit.shape}"
        )
    K = prb.shape[2]
    v = np.where(hit[..., None], prb, 1.0 / K)
    finite = np.isfinite(v).all(axis=-1)
    neg = (v < 0.0).any(axis=-1)
    tot = v.sum(axis=-1)
    off = np.abs(tot - 1.0) > PROB_SUM_TOL
    for mask, what in (
        (~finite, "is not finite"),
        (neg & finite, "has negative entries"),
        (off & finite & ~neg, f"does not sum to 1 (within {PROB_SUM_TOL:g})"),
    ):
        if mask.any():
            s, b = (int(i) for i in np.argwhere(mask)[0])
            raise ValueError(
                f"scan {s}: probability vector of beam {b} {what}: "
                f"{np.round(v[s, b], 6).tolist()} (sum {tot[s, b]:.6g})"
            )
    return np.asarray(v / tot[..., None], dtype=np.float64)
