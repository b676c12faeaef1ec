"""UTIAS Multi-Robot Cooperative Localization and Mapping (MRCLAM) datasets (Leung et al. 2011).

A dataset folder holds ``Barcodes.dat`` (subject -> barcode), ``Landmark_Groundtruth.dat`` and,
per robot N, ``RobotN_Odometry.dat`` (time, v, w), ``RobotN_Measurement.dat`` (time, barcode,
range, bearing) and ``RobotN_Groundtruth.dat`` (time, x, y, theta; Vicon). Subjects 1-5 are the
robots and 6-20 the landmarks in every MRCLAM dataset; the barcode numbers differ between datasets,
so they are always mapped through ``Barcodes.dat``.

Modelling choices:

* Landmark ids are subject numbers (6-20) and correspondences are known (``known=False`` hides
  them). Observations of other robots are *not* landmarks: they are kept apart in
  :attr:`MRCLAM.robot_observations`. Unknown barcodes are skipped with a counted warning.
* Stepping: event-driven with a zero-order hold
  (:func:`~probmap.datasets.landmarks.merge_events`): one record per odometry message (~67 Hz)
  and per distinct measurement time; ``dt`` is the time since the previous record and the control
  is the last odometry message received before the interval began. The run starts at the first
  odometry message at or after the start of the ground truth, from the (interpolated) true pose.
* Motion: :class:`~probmap.models.motion.VelocityModel` with white velocity noise
  (``reference_dt``), measurement noise from the residuals quoted in ``data/README.md``.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from probmap._typing import FloatArray, IntArray
from probmap.datasets.landmarks import (
    MergedEvents,
    merge_events,
    read_numeric_table,
)
from probmap.datasets.validate import check_end_time, dataset_directory
from probmap.errors import DatasetError
from probmap.geometry.timesync import interpolate_poses
from probmap.models.measurement import RangeBearingModel
from probmap.models.motion import VelocityModel

__all__ = ["MRCLAM", "ROBOT_SUBJECTS"]

ROBOT_SUBJECTS = range(1, 6)
"""Subject numbers of the robots; all other subjects are landmarks."""


class MRCLAM(MergedEvents):
    """One robot of an MRCLAM dataset as a landmark dataset.

    Parameters
    ----------
    directory : path-like
        The dataset folder (e.g. ``MRCLAM_Dataset7``).
    robot : int
        Robot number, 1-5.
    known : bool
        Give the landmark ids (known correspondences) or -1 (unknown).
    end_time : float, optional
        Stop this many seconds after the start (for quick runs).
    motion_model, measurement_model : optional
        Override the defaults.
    """

    def __init__(
        self,
        directory: str | os.PathLike[str],
        robot: int = 1,
        *,
        known: bool = True,
        end_time: float | None = None,
        motion_model: VelocityModel | None = None,
        measurement_model: RangeBearingModel | None = None,
    ) -> None:
        d = dataset_directory(directory)
        if robot not in ROBOT_SUBJECTS:
            raise ValueError(f"robot must be 1-5, got {robot}")
        check_end_time(end_time)
        self.directory = d
        self.robot = robot
        self.name = f"mrclam-{d.name}-robot{robot}"
        bc, _ = read_numeric_table(d / "Barcodes.dat", ("subject", "barcode"), time_column=None)
        barcode_to_subject = {int(b): int(s) for s, b in bc}
        lm, _ = read_numeric_table(
            d / "Landmark_Groundtruth.dat",
            ("subject", "x", "y", "x_std", "y_std"),
            min_columns=3,
            time_column=None,
        )
        odo, bad_o = read_numeric_table(d / f"Robot{robot}_Odometry.dat", ("time", "v", "w"))
        meas, bad_m = read_numeric_table(
            d / f"Robot{robot}_Measurement.dat", ("time", "barcode", "range", "bearing")
        )
        gt, bad_g = read_numeric_table(
            d / f"Robot{robot}_Groundtruth.dat", ("time", "x", "y", "theta")
        )
        if odo.shape[0] == 0 or gt.shape[0] < 2:
            raise DatasetError("needs odometry and at least 2 ground-truth rows", path=d)
        subjects = np.array([barcode_to_subject.get(int(b), -1) for b in meas[:, 1]], dtype=int)
        unknown = subjects < 0
        self.unknown_barcodes = int(unknown.sum())
        skipped = {"odometry": bad_o, "measurement": bad_m, "ground-truth": bad_g}
        for what, n in skipped.items():
            if n:
                warnings.warn(
                    f"{d}: robot {robot}: skipped {n} {what} rows with NaN/inf values",
                    UserWarning,
                    stacklevel=2,
                )
        if self.unknown_barcodes:
            warnings.warn(
                f"{d / f'Robot{robot}_Measurement.dat'}: skipped {self.unknown_barcodes} "
                "measurements of barcodes not in Barcodes.dat",
                UserWarning,
                stacklevel=2,
            )
        is_robot = np.isin(subjects, list(ROBOT_SUBJECTS))
        self.robot_observations: FloatArray = np.column_stack(
            [meas[is_robot, 0], subjects[is_robot], meas[is_robot, 2:4]]
        )
        """``(M, 4)``: time, observed robot's subject number, range, bearing."""
        is_lm = ~unknown & ~is_robot & (meas[:, 2] > 0)
        start = float(odo[odo[:, 0] >= gt[0, 0], 0][0]) if np.any(odo[:, 0] >= gt[0, 0]) else None
        if start is None:
            raise DatasetError("odometry ends before the ground truth starts", path=d)
        stop = gt[-1, 0] if end_time is None else min(gt[-1, 0], start + end_time)
        odo = odo[odo[:, 0] <= stop]
        is_lm &= meas[:, 0] <= stop
        if not is_lm.any():
            raise DatasetError(
                "no landmark measurement to use (none of a known landmark barcode within the "
                "ground truth's time span"
                + (f" and end_time {end_time:g} s" if end_time is not None else "")
                + ")",
                path=d / f"Robot{robot}_Measurement.dat",
            )
        ids = subjects[is_lm].astype(np.int64)
        self._times, self._dts, self._controls, self._obs_start, order = merge_events(
            odo[:, 0], odo[:, 1:3], meas[is_lm, 0], meas[is_lm, 2:4], ids, start=start
        )
        self._z = meas[is_lm, 2:4][order]
        self._ids: IntArray = ids[order] if known else np.full(order.size, -1, dtype=np.int64)
        self.gt_trajectory: FloatArray | None = gt
        self.gps: FloatArray | None = None
        self.landmark_truth: dict[int, FloatArray] | None = {int(r[0]): r[1:3].copy() for r in lm}
        self.initial_pose = interpolate_poses(gt, [start])[0]
        self.initial_covariance = np.diag([1e-6, 1e-6, 1e-6])
        self.motion_model = (
            motion_model
            if motion_model is not None
            else VelocityModel(
                alphas=(0.0, 0.0, 0.0, 0.0), sigma_v=0.05, sigma_w=0.1, reference_dt=1.0
            )
        )
        self.measurement_model = (
            measurement_model
            if measurement_model is not None
            else RangeBearingModel(R=np.diag([0.15**2, 0.04**2]))
        )
