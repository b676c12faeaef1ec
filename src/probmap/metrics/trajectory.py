"""Trajectory and landmark-map error metrics: ATE, RPE, landmark RMSE, NEES/ANEES, NIS.

Each metric returns an :class:`ErrorSeries` (the error array plus named summary statistics, in the
manner of the ``evo`` package); rendering into tables or JSON happens elsewhere.

Alignment: estimates and references may live in different frames (e.g. GPS in Victoria Park). An
SE(2) alignment is the rigid motion ``(R, t)`` minimising ``sum |R p_i + t - q_i|^2`` over
corresponding points (Umeyama 1991 / Horn, without scale), applied to the estimate.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._atomic import atomic_save
from probmap._typing import FloatArray
from probmap.geometry.se2 import between, compose, wrap_angle
from probmap.geometry.timesync import interpolate_poses  # re-exported: the old import path

__all__ = [
    "ErrorSeries",
    "absolute_trajectory_error",
    "align_se2",
    "apply_se2",
    "chi2_bounds",
    "interpolate_poses",
    "landmark_rmse",
    "nees",
    "nis",
    "reject_jumps",
    "relative_pose_error",
    "write_metrics_json",
]


@dataclass(frozen=True, eq=False)
class ErrorSeries:
    """An error array with its summary statistics.

    Attributes
    ----------
    errors : ndarray, shape (n,)
        Per-sample error (units of the metric).
    """

    errors: FloatArray

    @property
    def rmse(self) -> float:
        return float(np.sqrt(np.mean(self.errors**2))) if self.errors.size else float("nan")

    @property
    def mean(self) -> float:
        return float(np.mean(self.errors)) if self.errors.size else float("nan")

    @property
    def median(self) -> float:
        return float(np.median(self.errors)) if self.errors.size else float("nan")

    @property
    def max(self) -> float:
        return float(np.max(self.errors)) if self.errors.size else float("nan")

    def stats(self) -> dict[str, float]:
        """``{"rmse", "mean", "median", "max", "n"}``."""
        return {
            "rmse": self.rmse,
            "mean": self.mean,
            "median": self.median,
            "max": self.max,
            "n": int(self.errors.size),
        }


def _xy(a: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] < 2:
        raise ValueError(f"{name} must have shape (n, 2) or (n, 3), got {arr.shape}")
    return arr


def align_se2(source: ArrayLike, target: ArrayLike) -> FloatArray:
    """Rigid SE(2) transform that best maps ``source`` points onto ``target`` points.

    Parameters
    ----------
    source, target : array_like, shape (n, >=2)
        Corresponding points; only the first two columns (x, y) are used. ``n >= 2``.

    Returns
    -------
    ndarray, shape (3,)
        ``(tx, ty, phi)``: ``target ≈ R(phi) source + t`` in the least-squares sense.
    """
    p = _xy(source, "source")[:, :2]
    q = _xy(target, "target")[:, :2]
    if p.shape != q.shape or p.shape[0] < 2:
        raise ValueError("alignment needs at least 2 corresponding points of equal count")
    pc, qc = p.mean(axis=0), q.mean(axis=0)
    a, b = p - pc, q - qc
    # the optimal rotation angle for 2-D point sets (closed form of the Kabsch solution)
    phi = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a * b))
    c, s = np.cos(phi), np.sin(phi)
    t = qc - np.array([c * pc[0] - s * pc[1], s * pc[0] + c * pc[1]])
    return np.array([t[0], t[1], phi])


def apply_se2(transform: ArrayLike, data: ArrayLike) -> FloatArray:
    """Apply an SE(2) ``transform`` (3,) to points (n, 2) or poses (n, 3)."""
    data = np.asarray(data, dtype=np.float64)
    T = np.asarray(transform, dtype=np.float64)
    if data.shape[-1] == 3:
        return compose(T, data)
    c, s = np.cos(T[2]), np.sin(T[2])
    return np.stack(
        [T[0] + c * data[..., 0] - s * data[..., 1], T[1] + s * data[..., 0] + c * data[..., 1]],
        -1,
    )


def absolute_trajectory_error(
    estimate: ArrayLike, reference: ArrayLike, *, align: bool = False
) -> tuple[ErrorSeries, ErrorSeries, FloatArray]:
    """Absolute trajectory error (ATE) between corresponding poses or positions.

    Parameters
    ----------
    estimate, reference : array_like, shape (n, 2) or (n, 3)
        Corresponding positions or poses (same timestamps).
    align : bool
        First fit an SE(2) transform of the estimate onto the reference (:func:`align_se2`).

    Returns
    -------
    translation : ErrorSeries
        Position error norms (m).
    rotation : ErrorSeries
        Absolute heading errors (rad); empty unless both inputs are poses.
    transform : ndarray, shape (3,)
        The alignment applied (identity when ``align`` is False).
    """
    est = _xy(estimate, "estimate")
    ref = _xy(reference, "reference")
    if est.shape[0] != ref.shape[0]:
        raise ValueError(f"estimate has {est.shape[0]} rows but reference {ref.shape[0]}")
    T = align_se2(est, ref) if align else np.zeros(3)
    est_a = apply_se2(T, est if est.shape[1] == 3 else est[:, :2])
    trans = np.linalg.norm(est_a[:, :2] - ref[:, :2], axis=1)
    rot = np.zeros(0)
    if est.shape[1] >= 3 and ref.shape[1] >= 3:
        rot = np.abs(wrap_angle(est_a[:, 2] - ref[:, 2]))
    return ErrorSeries(trans), ErrorSeries(rot), T


def relative_pose_error(
    estimate: ArrayLike, reference: ArrayLike, *, delta: int = 1
) -> tuple[ErrorSeries, ErrorSeries]:
    """Relative pose error over index gaps of ``delta`` (frame independent, no alignment needed).

    Compares ``between(est[i], est[i + delta])`` with the same for the reference.

    Returns
    -------
    translation : ErrorSeries (m)
    rotation : ErrorSeries (rad)
    """
    est = np.asarray(estimate, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if est.shape != ref.shape or est.ndim != 2 or est.shape[1] != 3:
        raise ValueError("estimate and reference must be pose arrays of equal shape (n, 3)")
    if delta < 1:
        raise ValueError("delta must be >= 1")
    d_est = between(est[:-delta], est[delta:])
    d_ref = between(ref[:-delta], ref[delta:])
    err = between(d_ref, d_est)
    return ErrorSeries(np.hypot(err[:, 0], err[:, 1])), ErrorSeries(np.abs(err[:, 2]))


def landmark_rmse(
    ids: ArrayLike,
    xy: ArrayLike,
    truth: dict[int, ArrayLike],
    *,
    align: bool = True,
    match: str = "id",
) -> tuple[ErrorSeries, FloatArray]:
    """Landmark position errors of an estimated map against true landmark positions.

    Parameters
    ----------
    ids : array_like, shape (n,)
    xy : array_like, shape (n, 2)
    truth : dict[int, (2,)]
    align : bool
        Fit an SE(2) transform of the estimated map onto the truth first (needs >= 2 matches).
    match : {"id", "nearest"}
        ``"id"``: compare landmarks whose id has a true position (known correspondences).
        ``"nearest"``: pair each estimated landmark with the nearest true one (for estimators
        that chose their own ids); with ``align`` the pairing is redone once after the fit.

    Returns
    -------
    errors : ErrorSeries
        Per matched landmark position error (m).
    transform : ndarray, shape (3,)
    """
    ids = np.asarray(ids, dtype=np.int64)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if match == "nearest":
        if not truth or xy.shape[0] == 0:
            return ErrorSeries(np.zeros(0)), np.zeros(3)
        tru = np.array([np.asarray(v, dtype=np.float64)[:2] for v in truth.values()])

        def nearest(points: FloatArray) -> FloatArray:
            d = np.linalg.norm(points[:, None, :] - tru[None, :, :], axis=2)
            return tru[np.argmin(d, axis=1)]

        ref = nearest(xy)
        T = np.zeros(3)
        if align and xy.shape[0] >= 2:
            T = align_se2(xy, ref)
            ref = nearest(apply_se2(T, xy))
            T = align_se2(xy, ref)
        return ErrorSeries(np.linalg.norm(apply_se2(T, xy) - ref, axis=1)), T
    if match != "id":
        raise ValueError(f"match must be 'id' or 'nearest', got {match!r}")
    sel = [i for i, j in enumerate(ids) if int(j) in truth]
    if not sel:
        return ErrorSeries(np.zeros(0)), np.zeros(3)
    est = xy[sel]
    ref = np.array([np.asarray(truth[int(ids[i])], dtype=np.float64)[:2] for i in sel])
    T = align_se2(est, ref) if align and len(sel) >= 2 else np.zeros(3)
    return ErrorSeries(np.linalg.norm(apply_se2(T, est) - ref, axis=1)), T


def nees(errors: ArrayLike, covariances: ArrayLike) -> FloatArray:
    """Normalised estimation error squared ``e^T P^-1 e`` per sample.

    Parameters
    ----------
    errors : array_like, shape (n, d)
        Estimate minus truth (angles already wrapped).
    covariances : array_like, shape (n, d, d)
    """
    e = np.asarray(errors, dtype=np.float64)
    P = np.asarray(covariances, dtype=np.float64)
    if e.ndim != 2 or P.shape != (e.shape[0], e.shape[1], e.shape[1]):
        raise ValueError(f"errors (n, d) and covariances (n, d, d) disagree: {e.shape}, {P.shape}")
    return np.einsum("ni,ni->n", e, np.linalg.solve(P, e[..., None])[..., 0])


def nis(innovations: ArrayLike, covariances: ArrayLike) -> FloatArray:
    """Normalised innovation squared ``nu^T S^-1 nu`` per sample (same shapes as :func:`nees`)."""
    return nees(innovations, covariances)


def chi2_bounds(dof: int, runs: int = 1, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided chi-square band for the average of ``runs`` NEES samples of ``dof`` each.

    For ANEES over M runs: ``chi2.ppf([(1-p)/2, (1+p)/2], dof * M) / M`` (Bar-Shalom et al. 2001).
    """
    from scipy.stats import chi2

    a = (1.0 - probability) / 2.0
    lo, hi = chi2.ppf([a, 1.0 - a], dof * runs) / runs
    return float(lo), float(hi)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def write_metrics_json(path: str | os.PathLike[str], metrics: dict[str, Any]) -> Path:
    """Write ``metrics`` as JSON atomically (temp file + ``os.replace``); NaN/inf become null."""
    path = Path(path)
    text = json.dumps(_jsonable(metrics), indent=2, sort_keys=True)
    return atomic_save(path, lambda f: f.write(text + "\n"), mode="w")


def reject_jumps(track: ArrayLike, *, max_speed: float) -> NDArray[np.bool_]:
    """Flag fixes of a ``(G, 3)`` ``time, x, y`` track that imply an impossible speed.

    A fix is kept when the speed needed to reach it from the last *kept* fix is at most
    ``max_speed`` (m/s), so an isolated jump and the fixes that follow it while the receiver is off
    are both rejected until the track comes back. The first fix is kept.

    Returns
    -------
    ndarray of bool, shape (G,)
        True for the fixes kept.
    """
    tr = np.asarray(track, dtype=np.float64)
    if tr.ndim != 2 or tr.shape[1] < 3:
        raise ValueError(f"track must have shape (G, 3), got {tr.shape}")
    if not max_speed > 0:
        raise ValueError("max_speed must be > 0")
    keep = np.zeros(tr.shape[0], dtype=bool)
    if tr.shape[0] == 0:
        return keep
    finite = np.all(np.isfinite(tr[:, :3]), axis=1)
    last = -1
    for i in range(tr.shape[0]):
        if not finite[i]:
            continue
        if last < 0:
            keep[i] = True
            last = i
            continue
        dt = tr[i, 0] - tr[last, 0]
        dist = float(np.hypot(tr[i, 1] - tr[last, 1], tr[i, 2] - tr[last, 2]))
        if dt > 0 and dist <= max_speed * dt:
            keep[i] = True
            last = i
    return keep
