"""Run a landmark-SLAM estimator over a landmark dataset and evaluate the result.

This is the pipeline layer: it knows datasets, estimators and metrics, but neither prints nor
exits. The CLI (``probmap slam ...``) and the benchmarks call it for EKF and SEIF alike.
"""

from __future__ import annotations

import io
import os
import resource
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from probmap._atomic import atomic_outputs, atomic_save
from probmap._typing import FloatArray, IntArray
from probmap.datasets.landmarks import LandmarkDataset
from probmap.geometry.se2 import wrap_angle
from probmap.geometry.timesync import interpolate_poses
from probmap.metrics.trajectory import (
    absolute_trajectory_error,
    align_se2,
    apply_se2,
    chi2_bounds,
    landmark_rmse,
    nees,
    reject_jumps,
    relative_pose_error,
)
from probmap.slam.landmark.base import LandmarkSLAM

__all__ = [
    "SlamResult",
    "dead_reckoning",
    "default_ekf_config",
    "default_graphslam_config",
    "evaluate",
    "run_landmark_slam",
    "write_slam_outputs",
]

GPS_MAX_SPEED = 15.0
"""Speed (m/s) above which a GPS fix is treated as a jump (Victoria Park tops out at 6.6 m/s)."""


@dataclass(frozen=True, eq=False)
class SlamResult:
    """Output of :func:`run_landmark_slam`.

    Attributes
    ----------
    trajectory : ndarray, shape (T, 4)
        ``time, x, y, theta`` after each step's update.
    pose_covariances : ndarray, shape (T, 3, 3)
    landmark_ids, landmark_xy, landmark_cov : ndarray, shapes (n,), (n, 2), (n, 2, 2)
        The final map.
    step_seconds : ndarray, shape (T,)
        Wall time of predict + update per step.
    n_observations : ndarray, shape (T,), int64
        Observations per step.
    nis : ndarray, shape (T,)
        Normalised innovation squared per step (NaN when nothing was fused or unavailable).
    nis_dof : ndarray, shape (T,), int64
    gt_poses : ndarray, shape (T, 3) or None
        Ground-truth pose of each step when the records carry one.
    peak_rss_bytes : int
        Peak resident memory of the process after the run.
    known_correspondences : bool
        Whether the records gave landmark ids (else the estimator chose its own ids, and
        landmark errors are computed against the nearest true landmark).
    interrupted : bool
        The run was stopped (``stop()`` returned True) before the dataset's last step; the
        arrays cover the steps it got to.
    steps_total : int
        Steps of the dataset (``T`` when the run was not interrupted).
    """

    trajectory: FloatArray
    pose_covariances: FloatArray
    landmark_ids: IntArray
    landmark_xy: FloatArray
    landmark_cov: FloatArray
    step_seconds: FloatArray
    n_observations: IntArray
    nis: FloatArray
    nis_dof: IntArray
    gt_poses: FloatArray | None
    peak_rss_bytes: int
    known_correspondences: bool = True
    interrupted: bool = False
    steps_total: int = -1

    def __post_init__(self) -> None:
        if self.steps_total < 0:  # not given: the run covered the whole dataset
            object.__setattr__(self, "steps_total", int(self.trajectory.shape[0]))


def run_landmark_slam(
    estimator: LandmarkSLAM,
    dataset: LandmarkDataset,
    *,
    progress: Callable[[int, int], None] | None = None,
    blas_threads: int | None = 1,
    observer: Callable[[int, Any, LandmarkSLAM], None] | None = None,
    stop: Callable[[], bool] | None = None,
) -> SlamResult:
    """Feed every step of ``dataset`` to ``estimator`` (predict, then update).

    Parameters
    ----------
    estimator : LandmarkSLAM
        Built with the dataset's models and initial pose.
    dataset : LandmarkDataset
    progress : callable, optional
        Called as ``progress(steps_done, total)`` every 100 steps and at the end.
    blas_threads : int or None
        BLAS threads during the run (``threadpoolctl``); the per-step matrices are small, and
        thread start-up dominated on the machines we measured (Victoria Park ran 8x faster with
        one thread). None leaves the setting alone.
    observer : callable, optional
        Called as ``observer(index, step, estimator)`` after each step's update (a live view,
        :class:`probmap.viz.live.LandmarkSlamObserver`); it must not change the estimator.
    stop : callable, optional
        Asked before each step; when it returns True the run ends there (Ctrl-C in the CLI)
        and the result covers the steps so far (``interrupted``; a batch smoother solves
        them).
    """
    from contextlib import nullcontext

    from threadpoolctl import threadpool_limits

    limit = (
        nullcontext()
        if blas_threads is None
        else threadpool_limits(limits=blas_threads, user_api="blas")
    )
    with limit:
        return _run(estimator, dataset, progress, observer, stop)


def _run(
    estimator: LandmarkSLAM,
    dataset: LandmarkDataset,
    progress: Callable[[int, int], None] | None,
    observer: Callable[[int, Any, LandmarkSLAM], None] | None = None,
    stop: Callable[[], bool] | None = None,
) -> SlamResult:
    total = len(dataset)
    traj = np.empty((total, 4))
    covs = np.empty((total, 3, 3))
    secs = np.empty(total)
    nobs = np.zeros(total, dtype=np.int64)
    nis = np.full(total, np.nan)
    nis_dof = np.zeros(total, dtype=np.int64)
    gt = np.full((total, 3), np.nan)
    have_gt = False
    any_known = False
    i = -1
    interrupted = False
    clock = time.perf_counter
    for i, step in enumerate(dataset):
        if stop is not None and stop():
            interrupted = True
            i -= 1  # step i was not run
            break
        if i >= total:
            raise ValueError(f"dataset {dataset.name!r} yielded more steps than its length")
        t0 = clock()
        estimator.predict(step.control, step.dt)
        estimator.update(step.z, step.ids)
        secs[i] = clock() - t0
        traj[i, 0] = step.time
        traj[i, 1:] = estimator.pose
        covs[i] = estimator.pose_covariance
        nobs[i] = step.z.shape[0]
        nis[i] = getattr(estimator, "last_nis", np.nan)
        nis_dof[i] = getattr(estimator, "last_nis_dof", 0)
        if not any_known and step.ids.size and bool((step.ids >= 0).any()):
            any_known = True
        if step.gt_pose is not None:
            gt[i] = step.gt_pose
            have_gt = True
        if observer is not None:
            observer(i, step, estimator)
        if progress is not None and (i + 1) % 100 == 0:
            progress(i + 1, total)
    n = i + 1
    smooth = getattr(estimator, "smooth", None)
    if callable(smooth) and n:
        # a batch smoother (GraphSLAM) solves the whole log now and reports every step's
        # smoothed pose; its solve time is charged to the last step
        t0 = clock()
        poses, pose_covs = smooth()
        secs[n - 1] += clock() - t0
        traj[:n, 1:] = poses[:n]
        covs[:n] = pose_covs[:n]
    if progress is not None:
        progress(n, total)
    ids, xy, cov = estimator.landmarks()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    return SlamResult(
        trajectory=traj[:n],
        pose_covariances=covs[:n],
        landmark_ids=np.asarray(ids, dtype=np.int64),
        landmark_xy=np.asarray(xy, dtype=np.float64).reshape(-1, 2),
        landmark_cov=np.asarray(cov, dtype=np.float64).reshape(-1, 2, 2),
        step_seconds=secs[:n],
        n_observations=nobs[:n],
        nis=nis[:n],
        nis_dof=nis_dof[:n],
        gt_poses=gt[:n] if have_gt else None,
        peak_rss_bytes=int(rss),
        known_correspondences=any_known,
        interrupted=interrupted,
        steps_total=total,
    )


def dead_reckoning(dataset: LandmarkDataset) -> FloatArray:
    """Integrate the dataset's controls with its motion model from the initial pose: (T, 4)."""
    pose = np.asarray(dataset.initial_pose, dtype=np.float64).copy()
    out = np.empty((len(dataset), 4))
    i = -1
    for i, step in enumerate(dataset):
        if step.dt > 0:
            pose, _, _ = dataset.motion_model.predict(pose, step.control, step.dt)
        out[i] = (step.time, *pose)
    return out[: i + 1]


def _reference_poses(result: SlamResult, dataset: LandmarkDataset) -> FloatArray | None:
    if result.gt_poses is not None:
        return result.gt_poses
    gt = getattr(dataset, "gt_trajectory", None)
    if gt is not None and len(gt) >= 2:
        return interpolate_poses(gt, result.trajectory[:, 0])
    return None


def _trajectory_metrics(traj: FloatArray, ref: FloatArray, prefix: str) -> dict[str, Any]:
    ok = np.all(np.isfinite(ref), axis=1)
    if ok.sum() < 2:
        return {}
    est, gt = traj[ok, 1:], ref[ok]
    out: dict[str, Any] = {}
    t_err, r_err, _ = absolute_trajectory_error(est, gt)
    out[f"{prefix}ate"] = {"translation_m": t_err.stats(), "rotation_rad": r_err.stats()}
    t_err, r_err, T = absolute_trajectory_error(est, gt, align=True)
    out[f"{prefix}ate_aligned"] = {
        "translation_m": t_err.stats(),
        "rotation_rad": r_err.stats(),
        "alignment": T.tolist(),
    }
    # RPE over ~1 s windows so that the figure does not depend on the stepping rate
    times = traj[ok, 0]
    dt = float(np.median(np.diff(times))) if times.size > 1 else 1.0
    delta = max(1, round(1.0 / dt)) if dt > 0 else 1
    if est.shape[0] > delta:
        t_rpe, r_rpe = relative_pose_error(est, gt, delta=delta)
        out[f"{prefix}rpe"] = {
            "delta_steps": int(delta),
            "translation_m": t_rpe.stats(),
            "rotation_rad": r_rpe.stats(),
        }
    return out


def _gps_metrics(traj: FloatArray, gps: FloatArray, prefix: str) -> dict[str, Any]:
    keep = reject_jumps(gps, max_speed=GPS_MAX_SPEED)
    inside = (gps[:, 0] >= traj[0, 0]) & (gps[:, 0] <= traj[-1, 0])
    sel = keep & inside
    if sel.sum() < 2:
        return {}
    est = interpolate_poses(traj, gps[sel, 0])[:, :2]
    ref = gps[sel, 1:3]
    T = align_se2(est, ref)
    err = np.linalg.norm(apply_se2(T, est) - ref, axis=1)
    rmse = float(np.sqrt(np.mean(err**2)))
    return {
        f"{prefix}gps": {
            "rmse_m": rmse,
            "mean_m": float(err.mean()),
            "median_m": float(np.median(err)),
            "max_m": float(err.max()),
            "fixes_used": int(sel.sum()),
            "fixes_rejected_as_jumps": int((~keep & inside).sum()),
            "alignment": T.tolist(),
            "method": "SE(2) least-squares fit of the estimate (interpolated at GPS times) onto "
            f"GPS fixes kept by a {GPS_MAX_SPEED:g} m/s jump gate",
        }
    }


def evaluate(
    result: SlamResult, dataset: LandmarkDataset, *, with_dead_reckoning: bool = True
) -> dict[str, Any]:
    """Metrics of a run: ATE (raw and SE(2)-aligned), RPE, NEES, NIS, landmark RMSE, GPS error.

    Ground truth is taken from the records' ``gt_pose`` or the dataset's ``gt_trajectory``
    (interpolated at the step times); GPS (``dataset.gps``) is compared after rejecting jumps
    (:func:`~probmap.metrics.trajectory.reject_jumps`) and an SE(2) fit, since it lives in
    another frame. With ``with_dead_reckoning`` the same trajectory metrics are computed for the
    integrated controls alone, under the prefix ``dead_reckoning_``.
    """
    traj = result.trajectory
    m: dict[str, Any] = {
        "steps": int(traj.shape[0]),
        "observations": int(result.n_observations.sum()),
        "landmarks_mapped": int(result.landmark_ids.size),
        "time_s": float(result.step_seconds.sum()),
        "step_ms": {
            "mean": float(result.step_seconds.mean() * 1e3) if traj.shape[0] else float("nan"),
            "median": float(np.median(result.step_seconds) * 1e3)
            if traj.shape[0]
            else float("nan"),
            "max": float(result.step_seconds.max() * 1e3) if traj.shape[0] else float("nan"),
        },
        "peak_rss_mb": result.peak_rss_bytes / 2**20,
    }
    ref = _reference_poses(result, dataset)
    if ref is not None:
        m.update(_trajectory_metrics(traj, ref, ""))
        ok = np.all(np.isfinite(ref), axis=1)
        if ok.any():
            e = traj[ok, 1:] - ref[ok]
            e[:, 2] = wrap_angle(e[:, 2])
            v = nees(e, result.pose_covariances[ok])
            lo, hi = chi2_bounds(3, 1)
            m["pose_nees"] = {
                "mean": float(v.mean()),
                "median": float(np.median(v)),
                "fraction_in_95_band": float(np.mean((v >= lo) & (v <= hi))),
                "band": [lo, hi],
            }
    fused = result.nis_dof > 0
    if fused.any():
        m["nis"] = {
            "mean_per_dof": float(np.sum(result.nis[fused]) / np.sum(result.nis_dof[fused])),
            "steps": int(fused.sum()),
        }
    truth = getattr(dataset, "landmark_truth", None)
    if truth:
        how = "id" if result.known_correspondences else "nearest"
        ids, xy = result.landmark_ids, result.landmark_xy
        err, T = landmark_rmse(ids, xy, truth, align=False, match=how)
        err_a, T_a = landmark_rmse(ids, xy, truth, align=True, match=how)
        m["landmarks"] = {"error_m": err.stats(), "matched_by": how}
        m["landmarks_aligned"] = {"error_m": err_a.stats(), "alignment": T_a.tolist()}
    gps = getattr(dataset, "gps", None)
    if gps is not None and len(gps) >= 2 and traj.shape[0] >= 2:
        m.update(_gps_metrics(traj, np.asarray(gps, dtype=np.float64), ""))
    if with_dead_reckoning and traj.shape[0] >= 2:
        dr = dead_reckoning(dataset)
        if ref is not None and dr.shape == traj.shape:
            m.update(_trajectory_metrics(dr, ref, "dead_reckoning_"))
        if gps is not None and len(gps) >= 2:
            m.update(_gps_metrics(dr, np.asarray(gps, dtype=np.float64), "dead_reckoning_"))
    return m


def default_ekf_config(dataset: object) -> Any:
    """EKF settings suited to a dataset (resolved in one place, so the CLI stays thin).

    * Victoria Park: landmarks are expected within 25 m ahead (half plane) for miss counting.
    * MRCLAM: known-id observations beyond the 0.9999 chi-square gate are rejected (barcode
      misreads); camera field of view +-0.6 rad, 6 m range for miss counting.
    """
    from probmap.slam.landmark.ekf import EKFConfig

    kind = type(dataset).__name__
    if kind == "VictoriaPark":
        return EKFConfig(visibility_range=25.0, visibility_fov=np.pi, accept_hits=3, max_misses=3)
    if kind == "MRCLAM":
        return EKFConfig(outlier_probability=0.9999, visibility_range=6.0, visibility_fov=1.2)
    return EKFConfig()


def default_graphslam_config(dataset: object) -> Any:
    """GraphSLAM settings suited to a dataset, mirroring :func:`default_ekf_config`.

    * MRCLAM: measurements beyond the 0.9999 chi-square gate (barcode misreads) are dropped
      and the log is solved again, as the EKF rejects them.
    * Victoria Park: trees are expected within 25 m ahead (half plane); a landmark in view of
      more than 3 poses that do not see it before its third sighting is dropped, the EKF's
      rule for spurious landmarks (:func:`default_ekf_config`).
    """
    from probmap.slam.landmark.graphslam import GraphSLAMConfig

    kind = type(dataset).__name__
    if kind == "MRCLAM":
        return GraphSLAMConfig(outlier_probability=0.9999)
    if kind == "VictoriaPark":
        return GraphSLAMConfig(visibility_range=25.0, visibility_fov=float(np.pi), max_misses=3)
    return GraphSLAMConfig()


def default_fastslam_config(dataset: object, config: Any = None) -> Any:
    """FastSLAM settings suited to a dataset, mirroring :func:`default_ekf_config`: ``config``
    (a :class:`~probmap.slam.landmark.fastslam.FastSLAMConfig`, default its defaults) with the dataset's
    fields set.

    * Victoria Park: trees are expected within 25 m ahead (half plane), for the counter that
      removes spurious landmarks (Table 13.2), as the EKF's miss counting assumes.
    """
    import dataclasses

    from probmap.slam.landmark.fastslam import FastSLAMConfig

    cfg = config if config is not None else FastSLAMConfig()
    if type(dataset).__name__ == "VictoriaPark":
        return dataclasses.replace(cfg, visibility_range=25.0, visibility_fov=float(np.pi))
    return cfg


def _atomic_text(path: Path, text: str) -> Path:
    return atomic_save(path, lambda f: f.write(text), mode="w")


def write_slam_outputs(
    result: SlamResult, metrics: dict[str, Any], out_dir: str | os.PathLike[str]
) -> list[Path]:
    """Write ``trajectory.csv``, ``landmarks.csv`` and ``metrics.json`` into ``out_dir``,
    all-or-nothing (inside an enclosing :func:`probmap._atomic.atomic_outputs` block, with the
    rest of that block's files); a missing ``out_dir`` is created.

    ``trajectory.csv``: ``time,x,y,theta,var_x,var_y,var_theta``;
    ``landmarks.csv``: ``id,x,y,var_x,cov_xy,var_y`` (metres, radians, seconds).
    """
    from probmap.metrics.trajectory import write_metrics_json

    out = Path(out_dir)
    tr = result.trajectory
    var = np.diagonal(result.pose_covariances, axis1=1, axis2=2)
    rows = np.column_stack([tr, var])
    buf = io.StringIO()
    buf.write("time,x,y,theta,var_x,var_y,var_theta\n")
    np.savetxt(buf, rows, delimiter=",", fmt=["%.6f"] + ["%.9g"] * 6)
    trajectory = buf.getvalue()
    buf = io.StringIO()
    buf.write("id,x,y,var_x,cov_xy,var_y\n")
    c = result.landmark_cov
    for i, (x, y), cv in zip(result.landmark_ids, result.landmark_xy, c, strict=True):
        buf.write(f"{int(i)},{x:.9g},{y:.9g},{cv[0, 0]:.9g},{cv[0, 1]:.9g},{cv[1, 1]:.9g}\n")
    with atomic_outputs():
        files = [_atomic_text(out / "trajectory.csv", trajectory)]
        files.append(_atomic_text(out / "landmarks.csv", buf.getvalue()))
        files.append(write_metrics_json(out / "metrics.json", metrics))
    return files
