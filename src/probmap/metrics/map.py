"""Map metrics: how well an occupancy or a class map agrees with the true map.

- :func:`map_accuracy`: the fraction of classified cells of an occupancy map whose class
  (occupied or free) matches the truth, with a one-cell tolerance for occupied cells;
- :func:`semantic_iou`: per-class intersection over union of a class map, with a boundary
  tolerance;
- :func:`reliability`: a reliability diagram and the expected calibration error of a class map's
  probabilities;
- :func:`truth_on_grid`: resamples a true class map onto the grid of an estimated map, so the
  two can be compared cell by cell.

The true maps come from the simulators of :mod:`probmap.sim` (or any other ground truth on a
:class:`~probmap.grid.spec.GridSpec`). Ray endpoints on a surface fall on either side of its
boundary (a range error of a fraction of a cell), hence the tolerances.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from probmap.grid.spec import GridSpec

__all__ = ["Reliability", "map_accuracy", "reliability", "semantic_iou", "truth_on_grid"]


def map_accuracy(
    classified: NDArray[np.int8],
    grid_spec: GridSpec,
    truth: NDArray[np.bool_],
    truth_spec: GridSpec,
) -> tuple[float, int]:
    """Fraction of classified (non-unknown) cells whose class matches the true map.

    ``classified`` holds 1 occupied, 0 free, -1 unknown on ``grid_spec``; each classified cell is
    compared with the true cell containing its centre (cells outside the truth count as free).
    A cell counts as correct if it is occupied and a true occupied cell lies within one cell of it
    (ray endpoints on a wall face fall on either side of the boundary), or it is free and its own
    true cell is free. Returns ``(accuracy, number of classified cells)``.
    """
    iy, ix = np.nonzero(classified >= 0)
    if len(ix) == 0:
        return float("nan"), 0
    centres = grid_spec.cell_to_world(np.column_stack([ix, iy]))
    tc = truth_spec.world_to_cell(centres)
    inside = truth_spec.contains(tc)
    pad = np.pad(truth, 1)
    near = np.zeros_like(pad)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            near |= np.roll(np.roll(pad, dy, 0), dx, 1)
    tx = np.clip(tc[:, 0], 0, truth_spec.width - 1)
    ty = np.clip(tc[:, 1], 0, truth_spec.height - 1)
    true_occ = np.where(inside, truth[ty, tx], False)
    near_occ = np.where(inside, near[ty + 1, tx + 1], False)
    cls = classified[iy, ix]
    correct = np.where(cls == 1, near_occ, ~true_occ)
    return float(correct.mean()), int(len(ix))


def truth_on_grid(
    grid_spec: GridSpec, truth: NDArray[np.integer], truth_spec: GridSpec
) -> NDArray[np.int16]:
    """The true class of each cell of ``grid_spec`` (its centre's truth cell; outside: 0)."""
    h, w = grid_spec.shape
    iy, ix = np.mgrid[0:h, 0:w]
    centres = grid_spec.cell_to_world(np.column_stack([ix.ravel(), iy.ravel()]))
    tc = truth_spec.world_to_cell(centres)
    inside = truth_spec.contains(tc)
    tx = np.clip(tc[:, 0], 0, truth_spec.width - 1)
    ty = np.clip(tc[:, 1], 0, truth_spec.height - 1)
    return np.where(inside, truth[ty, tx], 0).astype(np.int16).reshape(h, w)


def _dilate(mask: NDArray[np.bool_], tolerance: int) -> NDArray[np.bool_]:
    if tolerance <= 0:
        return mask
    from scipy.ndimage import maximum_filter

    return np.asarray(maximum_filter(mask, size=2 * tolerance + 1, mode="constant"), dtype=bool)


def semantic_iou(
    classified: NDArray[np.integer],
    truth: NDArray[np.integer],
    n_classes: int,
    *,
    tolerance: int = 1,
) -> NDArray[np.float64]:
    """Per-class intersection over union on observed cells, with a boundary tolerance.

    Parameters
    ----------
    classified : ndarray of int, shape (H, W)
        Predicted class per cell, -1 for cells never observed (ignored).
    truth : ndarray of int, shape (H, W)
        True class per cell on the same grid (see :func:`truth_on_grid`).
    n_classes : int
        Number of classes including class 0.
    tolerance : int
        Cells. A cell predicted ``k`` is a true positive if a true ``k`` cell lies within
        ``tolerance`` cells (Chebyshev distance), else a false positive; an observed true ``k``
        cell predicted otherwise is a false negative unless an observed cell predicted ``k`` lies
        within ``tolerance``. Ray endpoints on a surface fall on either side of its boundary (a
        range error of a fraction of a cell), hence the default of one cell; 0 is the strict IoU.

    Returns
    -------
    ndarray, shape (n_classes,)
        ``TP / (TP + FP + FN)`` per class; NaN for a class absent from both.
    """
    c = np.asarray(classified)
    t = np.asarray(truth)
    if c.shape != t.shape:
        raise ValueError(f"classified shape {c.shape} does not match truth shape {t.shape}")
    seen = c >= 0
    out = np.full(n_classes, np.nan)
    for k in range(n_classes):
        pred_k = seen & (c == k)
        true_k = t == k
        near_true = _dilate(true_k, tolerance)
        near_pred = _dilate(pred_k, tolerance)
        tp = int((pred_k & near_true).sum())
        fp = int((pred_k & ~near_true).sum())
        fn = int((seen & true_k & ~pred_k & ~near_pred).sum())
        if tp + fp + fn:
            out[k] = tp / (tp + fp + fn)
    return out


@dataclass(frozen=True)
class Reliability:
    """A reliability diagram: per bin of predicted confidence, how often the prediction was right.

    Attributes
    ----------
    edges : ndarray, shape (n + 1,)
        Bin edges of the confidence (the top class's probability).
    confidence : ndarray, shape (n,)
        Mean confidence of the cells in each bin (NaN for empty bins).
    accuracy : ndarray, shape (n,)
        Fraction of those cells whose top class is right (NaN for empty bins).
    count : ndarray of int, shape (n,)
        Cells per bin.
    """

    edges: NDArray[np.float64]
    confidence: NDArray[np.float64]
    accuracy: NDArray[np.float64]
    count: NDArray[np.int64]

    @property
    def expected_calibration_error(self) -> float:
        """Cell-weighted mean of ``|accuracy - confidence|`` over the bins (ECE)."""
        ok = self.count > 0
        w = self.count[ok] / self.count[ok].sum()
        return float((w * np.abs(self.accuracy[ok] - self.confidence[ok])).sum())


def reliability(
    probabilities: NDArray[np.floating],
    observed: NDArray[np.bool_],
    truth: NDArray[np.integer],
    *,
    edges: NDArray[np.floating] | None = None,
    tolerance: int = 1,
) -> Reliability:
    """Calibration of a class map: confidence of the top class against how often it is right.

    ``probabilities`` (H, W, K + 1), ``observed`` (H, W), ``truth`` (H, W) on the same grid.
    The top class of a cell is right if a true cell of that class lies within ``tolerance``
    cells (see :func:`semantic_iou`). Default bins: ``0, 0.1, ..., 1``.
    """
    p = np.asarray(probabilities)
    top = p.argmax(axis=-1)
    conf = p.max(axis=-1)
    right = np.zeros(top.shape, dtype=bool)
    for k in range(p.shape[-1]):
        right |= (top == k) & _dilate(np.asarray(truth) == k, tolerance)
    e = np.linspace(0.0, 1.0, 11) if edges is None else np.asarray(edges, dtype=np.float64)
    seen = np.asarray(observed, dtype=bool)
    cs, rs = conf[seen], right[seen]
    idx = np.clip(np.searchsorted(e, cs, side="right") - 1, 0, len(e) - 2)
    n = len(e) - 1
    count = np.bincount(idx, minlength=n).astype(np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_c = np.bincount(idx, weights=cs, minlength=n) / count
        acc = np.bincount(idx, weights=rs.astype(np.float64), minlength=n) / count
    return Reliability(e, mean_c, acc, count)
