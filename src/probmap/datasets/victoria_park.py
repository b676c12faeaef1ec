"""Victoria Park (Guivant & Nebot 2001): a car with an encoder, steering and a laser among trees.

Files (see ``data/README.md``): ``inputs.dat`` (time s, encoder speed m/s, steering rad),
``measurements.dat`` (time s, range m, bearing rad in 0..pi of the laser frame, diameter m),
``gps.dat`` (time s, x m, y m), all on one clock; or the original ``aa3_dr.mat`` /
``aa3_gpsx.mat`` (read with ``scipy.io``, time in ms, rebased onto the ``.dat`` clock by
subtracting 20.967 s).

Modelling choices:

* State: pose of the rear-axle centre. Motion: :class:`~probmap.models.motion.AckermannModel`
  with L = 2.83 m and encoder offset H = 0.76 m.
* Sensor: the laser sits a = 3.78 m ahead of the rear axle and b = 0.50 m to the left
  (``sensor_offset = (3.78, 0.50, 0)``). Laser bearings are converted to the vehicle convention
  (x ahead, counter-clockwise) by subtracting pi/2. With ``range_to_centre`` the tree radius
  (diameter / 2) is added to the range, so that the landmark is the trunk's centre.
* Stepping: event-driven with a zero-order hold (:func:`~probmap.datasets.landmarks.merge_events`):
  one record per input sample (40 Hz) and per laser scan with detections.
* Correspondences are unknown (``ids = -1``); there is no ground truth, only GPS (``gps``), in a
  frame roughly aligned with dead reckoning: compare after an SE(2) fit and jump rejection.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from probmap._typing import FloatArray
from probmap.datasets.landmarks import (
    MergedEvents,
    merge_events,
    read_numeric_table,
)
from probmap.datasets.validate import check_end_time, dataset_directory
from probmap.errors import DatasetError
from probmap.models.measurement import RangeBearingModel
from probmap.models.motion import AckermannModel

__all__ = ["MAT_CLOCK_OFFSET_S", "VictoriaPark"]

MAT_CLOCK_OFFSET_S = 20.967
"""The ``.dat`` files' clock is the ``.mat`` files' clock (ms / 1000) minus this many seconds."""


def _load_mat(path: Path, keys: tuple[str, ...]) -> dict[str, FloatArray]:
    from scipy.io import loadmat

    try:
        mat = loadmat(path)
    except Exception as exc:  # scipy raises several types for a corrupt file
        raise DatasetError(f"cannot read MATLAB file: {exc}", path=path) from None
    out = {}
    for k in keys:
        if k not in mat:
            raise DatasetError("missing variable", path=path, field=k)
        out[k] = np.asarray(mat[k], dtype=np.float64).ravel()
    n = {v.size for v in out.values()}
    if len(n) != 1:
        raise DatasetError(f"variables {keys} have different lengths {sorted(n)}", path=path)
    return out


class VictoriaPark(MergedEvents):
    """The Victoria Park landmark dataset (a :class:`~probmap.datasets.landmarks.LandmarkDataset`).

    Parameters
    ----------
    directory : path-like
        Folder holding ``measurements.dat`` and either ``inputs.dat``/``gps.dat`` or
        ``aa3_dr.mat``/``aa3_gpsx.mat``.
    source : {"dat", "mat"}
        Where the controls and GPS come from.
    range_to_centre : bool
        Add half the trunk diameter to each range.
    max_range : float
        Detections farther than this (m) are dropped.
    end_time : float, optional
        Stop after this time (s on the ``.dat`` clock), e.g. for quick runs.
    motion_model, measurement_model : optional
        Override the defaults described in the module docstring.
    """

    name = "victoria-park"

    def __init__(
        self,
        directory: str | os.PathLike[str],
        *,
        source: str = "dat",
        range_to_centre: bool = True,
        max_range: float = 40.0,
        end_time: float | None = None,
        motion_model: AckermannModel | None = None,
        measurement_model: RangeBearingModel | None = None,
    ) -> None:
        d = dataset_directory(directory)
        check_end_time(end_time)
        self.directory = d
        if source == "dat":
            inputs, bad_in = read_numeric_table(d / "inputs.dat", ("time", "speed", "steering"))
            gps, bad_gps = read_numeric_table(d / "gps.dat", ("time", "x", "y"))
        elif source == "mat":
            dr = _load_mat(d / "aa3_dr.mat", ("time", "speed", "steering"))
            g = _load_mat(d / "aa3_gpsx.mat", ("timeGps", "Lo_m", "La_m"))
            inputs = np.column_stack(
                [np.round(dr["time"] / 1000.0 - MAT_CLOCK_OFFSET_S, 6), dr["speed"], dr["steering"]]
            )
            gps = np.column_stack(
                [g["timeGps"] / 1000.0 - MAT_CLOCK_OFFSET_S, g["Lo_m"], g["La_m"]]
            )
            ok_in = np.all(np.isfinite(inputs), axis=1)
            ok_gps = np.all(np.isfinite(gps), axis=1)
            bad_in, bad_gps = int((~ok_in).sum()), int((~ok_gps).sum())
            inputs, gps = inputs[ok_in], gps[ok_gps]
            if np.any(np.diff(inputs[:, 0]) < 0):
                raise DatasetError("time goes backwards", path=d / "aa3_dr.mat", field="time")
        else:
            raise ValueError(f"source must be 'dat' or 'mat', got {source!r}")
        meas, bad_m = read_numeric_table(
            d / "measurements.dat", ("time", "range", "bearing", "diameter"), min_columns=3
        )
        for what, n in (("control", bad_in), ("GPS", bad_gps), ("measurement", bad_m)):
            if n:
                warnings.warn(
                    f"{d}: skipped {n} {what} rows with NaN/inf values", UserWarning, stacklevel=2
                )
        if inputs.shape[0] == 0:
            raise DatasetError("no control rows", path=d)
        diam = np.nan_to_num(meas[:, 3], nan=0.0)
        rng = meas[:, 1] + (0.5 * diam if range_to_centre else 0.0)
        keep = (meas[:, 1] > 0) & (rng <= max_range)
        if end_time is not None:
            keep &= meas[:, 0] <= end_time
            inputs = inputs[inputs[:, 0] <= end_time]
            gps = gps[gps[:, 0] <= end_time]
            if inputs.shape[0] == 0:
                raise DatasetError(f"no control rows before end_time {end_time:g} s", path=d)
        if not keep.any():
            raise DatasetError(
                "no tree detection to use"
                + (f" before end_time {end_time:g} s" if end_time is not None else "")
                + f" (of {meas.shape[0]} rows; max_range {max_range:g} m)",
                path=d / "measurements.dat",
            )
        self.detections = int(meas.shape[0])
        z = np.column_stack([rng, meas[:, 2] - np.pi / 2])[keep]
        t0 = float(inputs[0, 0])
        self._times, self._dts, self._controls, self._obs_start, order = merge_events(
            inputs[:, 0], inputs[:, 1:3], meas[keep, 0], z, np.full(z.shape[0], -1), start=t0
        )
        self._z = z[order]
        self._ids = np.full(order.size, -1, dtype=np.int64)  # trees have no identity
        self.inputs = inputs
        self.gps: FloatArray | None = gps
        self.motion_model = motion_model if motion_model is not None else AckermannModel()
        self.measurement_model = (
            measurement_model
            if measurement_model is not None
            else RangeBearingModel(
                sensor_offset=(3.78, 0.50, 0.0), R=np.diag([0.5**2, np.deg2rad(2.0) ** 2])
            )
        )
        self.initial_pose = np.zeros(3)
        self.initial_covariance = np.diag([1e-4, 1e-4, 1e-6])
        self.landmark_truth: dict[int, FloatArray] | None = None
        self.gt_trajectory: FloatArray | None = None
