"""Comparing a localization run with a reference trajectory: the run's poses at the
reference's own times, interpolated between the filter's updates (it never updates for them).
Re-exported from :mod:`probmap.pipelines.localize`."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.geometry.se2 import wrap_angle

if TYPE_CHECKING:
    from probmap.pipelines.localize import LocalizationRun

__all__ = ["interpolate_run", "trajectory_errors"]


def trajectory_errors(
    run: LocalizationRun,
    ref_times: ArrayLike,
    ref_poses: ArrayLike,
    *,
    laser: bool = False,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Position and heading errors at the reference poses that lie within the run's span.

    The run's trajectory is interpolated at each reference time between the filter's own
    updates (:func:`~probmap.geometry.timesync.interpolate_poses`): the filter is never made
    to update for a reference, so a run evaluated against one is the run made without it.
    Updates come every ``update_distance`` or ``update_angle`` of motion (0.1 m, 0.1 rad by
    default), so the interpolation adds little; a reference may be far sparser (Intel's
    corrected log keeps one scan in 15).

    The reference is a robot trajectory, compared with ``run.poses``; with ``laser=True`` it
    is a laser trajectory (a session's, a log's laser poses), compared with
    ``run.laser_poses``.

    Returns
    -------
    position_error : (M,) ndarray
        Metres.
    heading_error : (M,) ndarray
        Absolute radians.
    """
    rt = np.asarray(ref_times, dtype=np.float64)
    rp = np.asarray(ref_poses, dtype=np.float64)
    if rt.ndim != 1 or rp.shape != (rt.shape[0], 3) or rt.size == 0:
        raise ValueError(f"reference needs times (M,) and poses (M, 3), got {rt.shape}, {rp.shape}")
    est = interpolate_run(run, rt, laser=laser)
    ok = np.all(np.isfinite(est), axis=1)
    d = est[ok] - rp[ok]
    return np.hypot(d[:, 0], d[:, 1]), np.abs(wrap_angle(d[:, 2]))


def interpolate_run(
    run: LocalizationRun, times: ArrayLike, *, laser: bool = False
) -> NDArray[np.float64]:
    """The run's poses (robot's, or the laser's with ``laser=True``) at ``times`` (M,),
    interpolated between its updates (by the odometry, :attr:`LocalizationRun.track`, where
    the run has it); NaN rows outside the span of its updates.

    Update times that go back (a log's clock jitter) are taken in time order.
    """
    from probmap.geometry.se2 import compose
    from probmap.geometry.timesync import interpolate_poses

    t = np.asarray(times, dtype=np.float64)
    poses = run.laser_poses if laser else run.poses
    if run.times.size == 0:
        return np.full((t.size, 3), np.nan)
    stamps = run.times
    if run.track_times.size >= 2:  # every scan, by the odometry between the updates
        stamps, poses = run.track_times, run.track
        if laser:
            poses = np.asarray(compose(poses, run.laser_offset)).reshape(-1, 3)
    order = np.argsort(stamps, kind="stable")
    traj = np.column_stack([stamps[order], poses[order]])
    if traj.shape[0] == 1:  # a single update: the poses at its own time only
        out = np.full((t.size, 3), np.nan)
        out[t == traj[0, 0]] = traj[0, 1:]
        return out
    return np.asarray(interpolate_poses(traj, t))
