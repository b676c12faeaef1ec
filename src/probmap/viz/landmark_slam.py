"""Plots of landmark-SLAM results (axes first; the caller owns the figure)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from probmap._atomic import atomic_path
from probmap.viz.maps import label_metric_axes, legend_below

__all__ = [
    "alignment_from_metrics",
    "covariance_ellipse",
    "metrics_caption",
    "plot_slam",
    "save_slam_figure",
]


def covariance_ellipse(
    mean: np.ndarray, cov: np.ndarray, n_sigma: float = 2.0, n_points: int = 36
) -> np.ndarray:
    """Points (n_points + 1, 2) of the ``n_sigma`` ellipse of a 2-D Gaussian."""
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    vals = np.clip(vals, 0.0, None)
    t = np.linspace(0, 2 * np.pi, n_points + 1)
    circle = np.stack([np.cos(t), np.sin(t)], -1)
    return mean + n_sigma * (circle * np.sqrt(vals)) @ vecs.T


def alignment_from_metrics(metrics: dict[str, Any] | None) -> tuple[np.ndarray | None, str]:
    """The SE(2) alignment ``(tx, ty, theta)`` the metrics used (estimate to reference) and
    what it aligns to: the ground truth's (``ate_aligned``) before GPS's (``gps``); ``(None,
    "")`` without either."""
    for key, name in (("ate_aligned", "ground truth"), ("gps", "GPS")):
        entry = (metrics or {}).get(key)
        if isinstance(entry, dict) and entry.get("alignment") is not None:
            return np.asarray(entry["alignment"], dtype=np.float64).reshape(3), name
    return None, ""


def _rmse(metrics: dict[str, Any], key: str, sub: str) -> float | None:
    entry = metrics.get(key)
    if isinstance(entry, dict) and isinstance(entry.get(sub), dict):
        value = entry[sub].get("rmse")
        return None if value is None else float(value)
    return None


def _wrapped(text: str, width: int) -> str:
    """``text``'s ``; ``-separated parts on lines of about ``width`` characters."""
    lines: list[str] = []
    for part in text.split("; ") if text else []:
        if lines and len(lines[-1]) + 2 + len(part) <= width:
            lines[-1] += "; " + part
        else:
            lines.append(part)
    return "\n".join(lines)


def metrics_caption(metrics: dict[str, Any] | None) -> str:
    """The picture's line of figures from ``metrics`` (of
    :func:`probmap.pipelines.landmark_slam.evaluate`): steps, landmarks, and the errors
    against the truth (SE(2)-aligned when it was) or GPS, with dead reckoning's beside.

    >>> metrics_caption({"steps": 18444, "landmarks_mapped": 15,
    ...     "ate_aligned": {"translation_m": {"rmse": 0.266}},
    ...     "landmarks_aligned": {"error_m": {"rmse": 0.198}},
    ...     "dead_reckoning_ate_aligned": {"translation_m": {"rmse": 2.347}}})
    '18,444 steps, 15 landmarks; ATE 0.266 m, landmarks 0.198 m (SE(2)-aligned); dead reckoning ATE 2.347 m'
    """
    m = metrics or {}
    head = []
    if "steps" in m:
        head.append(f"{int(m['steps']):,} steps")
    if "landmarks_mapped" in m:
        head.append(f"{int(m['landmarks_mapped']):,} landmarks")
    parts = [", ".join(head)] if head else []
    aligned = _rmse(m, "ate_aligned", "translation_m")
    ate = aligned if aligned is not None else _rmse(m, "ate", "translation_m")
    lm_aligned = _rmse(m, "landmarks_aligned", "error_m")
    lm = lm_aligned if lm_aligned is not None else _rmse(m, "landmarks", "error_m")
    errs = []
    if ate is not None:
        errs.append(f"ATE {ate:.3f} m")
    if lm is not None:
        errs.append(f"landmarks {lm:.3f} m")
    if errs:
        how = " (SE(2)-aligned)" if aligned is not None or lm_aligned is not None else ""
        parts.append(", ".join(errs) + how)
    dr_key = "dead_reckoning_ate_aligned" if aligned is not None else "dead_reckoning_ate"
    dr = _rmse(m, dr_key, "translation_m")
    if dr is not None:
        parts.append(f"dead reckoning ATE {dr:.3f} m")
    gps = m.get("gps")
    if isinstance(gps, dict) and gps.get("rmse_m") is not None:
        parts.append(f"GPS RMSE {float(gps['rmse_m']):.2f} m")
        dgps = m.get("dead_reckoning_gps")
        if isinstance(dgps, dict) and dgps.get("rmse_m") is not None:
            parts.append(f"dead reckoning {float(dgps['rmse_m']):.2f} m")
    return "; ".join(parts)


def plot_slam(
    ax: Any,
    result: Any,
    dataset: Any = None,
    *,
    title: str | None = None,
    alignment: Any = None,
    aligned_to: str = "the reference",
) -> Any:
    """Draw the estimated trajectory, landmarks with 2-sigma ellipses, and any truth or GPS.

    SLAM estimates in its own frame (the first pose), which is not the reference's; drawn raw,
    a good run looks wrong. With ``alignment`` (the SE(2) transform the metrics fitted, see
    :func:`alignment_from_metrics`) the estimate (trajectory, landmarks and their ellipses) is
    drawn after it, in the reference's frame, and the legend says so.

    Parameters
    ----------
    ax : matplotlib Axes
    result : SlamResult
    dataset : LandmarkDataset, optional
        Supplies ``gt_trajectory``, ``landmark_truth`` and ``gps`` when present.
    title : str, optional
    alignment : array_like, shape (3,), optional
        ``(tx, ty, theta)`` from the estimate's frame to the reference's.
    aligned_to : str
        The reference's name, for the legend (``"ground truth"``, ``"GPS"``).
    """
    from probmap.geometry.se2 import compose

    T = None if alignment is None else np.asarray(alignment, dtype=np.float64).reshape(3)
    c, s_ = (1.0, 0.0) if T is None else (float(np.cos(T[2])), float(np.sin(T[2])))
    R = np.array([[c, -s_], [s_, c]])
    if dataset is not None:
        gt = getattr(dataset, "gt_trajectory", None)
        if gt is not None:
            ax.plot(gt[:, 1], gt[:, 2], color="0.6", lw=0.8, label="ground truth")
        gps = getattr(dataset, "gps", None)
        if gps is not None:
            ax.plot(gps[:, 1], gps[:, 2], ".", color="tab:green", ms=1.5, label="GPS")
        truth = getattr(dataset, "landmark_truth", None)
        if truth:
            xy = np.array(list(truth.values()))
            ax.plot(xy[:, 0], xy[:, 1], "k+", ms=7, label="true landmarks")
    tr = np.asarray(result.trajectory, dtype=np.float64)[:, 1:4]
    lm = np.asarray(result.landmark_xy, dtype=np.float64).reshape(-1, 2)
    covs = np.asarray(result.landmark_cov, dtype=np.float64).reshape(-1, 2, 2)
    if T is not None:
        tr = compose(T, tr)
        lm = lm @ R.T + T[:2]
        covs = R @ covs @ R.T
    label = "estimate" if T is None else f"estimate (SE(2)-aligned to {aligned_to})"
    ax.plot(tr[:, 0], tr[:, 1], color="tab:blue", lw=1.0, label=label)
    for m, cov in zip(lm, covs, strict=True):
        e = covariance_ellipse(m, cov)
        ax.plot(e[:, 0], e[:, 1], color="tab:red", lw=0.6)
    if len(lm):
        ax.plot(*lm.T, "r.", ms=3, label="landmarks (2-sigma)")
    return label_metric_axes(ax, title, legend="best")


def save_slam_figure(
    path: str | os.PathLike[str],
    result: Any,
    dataset: Any = None,
    *,
    title: str | None = None,
    metrics: dict[str, Any] | None = None,
) -> Path:
    """Render :func:`plot_slam` to an image file (Agg backend, written atomically), the
    estimate aligned as ``metrics`` (from :func:`probmap.pipelines.landmark_slam.evaluate`)
    aligned it, when they hold an alignment. The title is ``TITLE on DATASET`` (the
    metrics' ``dataset``, e.g. ``mrclam-MRCLAM_Dataset7-robot1``, which names the robot),
    over a line of the metrics' figures (:func:`metrics_caption`)."""
    from matplotlib.figure import Figure

    path = Path(path)
    fig = Figure(figsize=(8, 8))
    T, name = alignment_from_metrics(metrics)
    ax = fig.add_subplot()
    plot_slam(ax, result, dataset, alignment=T, aligned_to=name)
    source = (metrics or {}).get("dataset") or getattr(dataset, "name", "")
    heading = " on ".join(v for v in (title or "", str(source)) if v)
    caption = _wrapped(metrics_caption(metrics), 60)
    ax.set_title(heading, loc="left", fontsize=10, pad=4 + 11 * (caption.count("\n") + 1))
    ax.text(
        0.0, 1.01, caption, transform=ax.transAxes, fontsize=8, va="bottom", ha="left",
    )  # fmt: skip
    legend_below(ax, ncol=2)  # under the axes: it hides no landmark
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches="tight")
    return path
