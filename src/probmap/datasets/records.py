"""Frozen records produced by the laser-log readers (CARMEN and others).

Frames and units, for every record here: poses are ``(x, y, theta)`` in metres and radians in the
log's world frame (the odometry frame of a raw log, the SLAM map frame of a corrected log); beam
angles are in the laser frame, counter-clockwise from the laser's forward axis; ranges are metres
along each beam; times are seconds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from probmap._typing import FloatArray
from probmap.datasets.validate import ReadingReport

__all__ = ["LaserScan", "Odometry", "ScanBatch"]


@dataclass(frozen=True, eq=False)
class LaserScan:
    """One planar laser scan (one measurement ``z_t``).

    Attributes
    ----------
    time : float
        Timestamp in seconds (the CARMEN ``ipc_timestamp``, an absolute wall clock).
    ranges : ndarray, shape (B,), float64
        Range of each beam in metres, as logged. Readings ``>= max_range`` mean "no return".
    angles : ndarray, shape (B,), float64
        Bearing of each beam in radians in the laser frame (0 = the laser's forward axis,
        counter-clockwise positive). Shared between scans of one geometry: read-only.
    laser_pose : ndarray, shape (3,), float64
        ``(x, y, theta)`` of the sensor in the world frame (m, m, rad).
    robot_pose : ndarray, shape (3,), float64
        ``(x, y, theta)`` of the robot base in the same frame.
    max_range : float
        The sensor's maximum range in metres: a reading at or beyond it has no endpoint.
    logger_time : float
        The CARMEN ``logger_timestamp`` (seconds since the logger started).
    source : str
        Message type: ``"FLASER"``, ``"RLASER"`` or ``"ROBOTLASER1"``.
    line : int
        1-based line number in the (decompressed) log.
    """

    time: float
    ranges: FloatArray
    angles: FloatArray
    laser_pose: FloatArray
    robot_pose: FloatArray
    max_range: float
    logger_time: float
    source: str
    line: int

    @property
    def beams(self) -> int:
        """Number of beams ``B``."""
        return int(self.ranges.shape[0])

    def endpoints(self) -> FloatArray:
        """World ``(x, y)`` of the beams that returned (``0 < r < max_range``), shape (K, 2)."""
        r = self.ranges
        ok = np.isfinite(r) & (r > 0.0) & (r < self.max_range)
        x, y, th = self.laser_pose
        a = self.angles[ok] + th
        return np.column_stack((x + r[ok] * np.cos(a), y + r[ok] * np.sin(a)))


@dataclass(frozen=True, eq=False)
class Odometry:
    """One odometry message (CARMEN ``ODOM``).

    Attributes
    ----------
    time : float
        ``ipc_timestamp`` in seconds.
    pose : ndarray, shape (3,), float64
        Robot ``(x, y, theta)`` in the odometry frame (m, m, rad).
    tv : float
        Translational velocity in m/s.
    rv : float
        Rotational velocity in rad/s.
    logger_time : float
        ``logger_timestamp`` in seconds.
    line : int
        1-based line number in the (decompressed) log.
    """

    time: float
    pose: FloatArray
    tv: float
    rv: float
    logger_time: float
    line: int


@dataclass(frozen=True, eq=False)
class ScanBatch:
    """Many scans stacked into arrays, for fast batch mapping.

    Attributes
    ----------
    times : ndarray, shape (S,), float64
        Scan timestamps in seconds.
    ranges : ndarray, shape (S, B), float64 or float32
        Ranges in metres, validated by :func:`probmap.datasets.validate.validate_ranges`: NaN
        for zero and invalid readings (NaN, -inf, negative), ``+inf`` replaced by the maximum
        range ("no return"). When beam counts differ, rows are padded with NaN on the right
        (NaN beams are dropped by the mapper) and ``beams`` holds each scan's true count.
    angles : ndarray, shape (B,) or (S, B), float64
        Beam angles in the laser frame: (B,) when every scan shares one geometry, otherwise
        one row per scan (padding angles are 0).
    laser_poses : ndarray, shape (S, 3), float64
        Sensor poses ``(x, y, theta)`` in the world frame used for mapping.
    robot_poses : ndarray, shape (S, 3), float64
        Robot base poses ``(x, y, theta)`` as logged.
    max_range : float
        One threshold for the whole batch (the smallest per-scan maximum range): readings at or
        beyond it are "no return".
    beams : ndarray, shape (S,), int64
        Number of real beams in each row of ``ranges``.
    skipped_lines : int
        Malformed lines skipped while reading (with ``skip_bad_lines=True``).
    readings : ReadingReport or None
        How the readings were classified (usable, no return, zero, invalid; beam counts);
        None for a batch built by hand.
    max_range_stated : bool
        False when the log stated no maximum range (a CARMEN log without ``ROBOTLASER1``
        ranges or PARAM): ``max_range`` is then the default or inferred from the data.
    pose_source : str
        What placed the scans: ``"odometry"`` (raw wheel odometry: a map built from it
        drifts), ``"corrected"`` (a SLAM system's estimate, e.g. a GMapping-corrected log or a
        bag's ``map`` frame), ``"laser"`` (a bag read in the laser's own frame: every scan at
        the origin) or ``""`` (unknown).
    published : ndarray, shape (S,), int64, or None
        The order the laser driver published the scans in, where the file records it: a
        ROS 1 bag's header sequence numbers (a driver restart, where they begin again, counts
        on from the last). ``np.argsort(published, kind="stable")`` puts the rows in that
        order. None where unknown: a CARMEN log is already in arrival order, and ROS 2 has
        no sequence number. A bag written in stamp order whose stamps jitter (the Intel bag)
        holds its scans in another order than the one they were taken in.
    """

    times: FloatArray
    ranges: NDArray[np.floating]
    angles: FloatArray
    laser_poses: FloatArray
    robot_poses: FloatArray
    max_range: float
    beams: NDArray[np.int64]
    skipped_lines: int = 0
    readings: ReadingReport | None = None
    max_range_stated: bool = True
    pose_source: str = ""
    published: NDArray[np.int64] | None = None

    def __len__(self) -> int:
        return int(self.times.shape[0])

    def rows(self, index: slice | NDArray[np.integer] | NDArray[np.bool_]) -> ScanBatch:
        """The batch of the scans ``index`` selects (a slice, a boolean mask or integer
        indices, in their order), every per-scan array taken alike; ``readings`` is kept as
        it is."""
        from dataclasses import replace

        angles = np.asarray(self.angles)
        return replace(
            self,
            times=np.asarray(self.times)[index],
            ranges=self.ranges[index],
            angles=angles if angles.ndim == 1 else angles[index],
            laser_poses=self.laser_poses[index],
            robot_poses=self.robot_poses[index],
            beams=self.beams[index],
            published=None if self.published is None else self.published[index],
        )


def stack_beams(
    rows: Sequence[FloatArray], angle_rows: Sequence[FloatArray], dtype: type[np.floating]
) -> tuple[NDArray[np.floating], FloatArray, NDArray[np.int64]]:
    """Per-scan ranges and beam angles stacked as :class:`ScanBatch` holds them.

    Parameters
    ----------
    rows : sequence of ndarray, each shape (B_s,)
        Ranges of each scan, metres (at least one scan).
    angle_rows : sequence of ndarray, each shape (B_s,)
        Beam angles of each scan, radians.
    dtype : numpy floating type
        dtype of the stacked ranges.

    Returns
    -------
    ranges : ndarray, shape (S, B), ``dtype``
        Padded with NaN on the right where a scan has fewer than ``B = max B_s`` beams.
    angles : ndarray, shape (B,) or (S, B), float64
        One row when every scan has the same angles (the same object, or equal values with
        equal beam counts), else one row per scan padded with 0.
    beams : ndarray, shape (S,), int64
        ``B_s`` per scan.
    """
    beams = np.array([r.shape[0] for r in rows], dtype=np.int64)
    b = int(beams.max())
    same = bool((beams == b).all())
    if same:
        ranges = np.array(rows, dtype=dtype)
    else:
        ranges = np.full((len(rows), b), np.nan, dtype=dtype)
        for i, r in enumerate(rows):
            ranges[i, : r.shape[0]] = r
    first = angle_rows[0]
    if all(a is first for a in angle_rows) or (
        same and all(np.array_equal(a, first) for a in angle_rows)
    ):
        angles = np.array(first, dtype=np.float64)
    else:
        angles = np.zeros((len(rows), b), dtype=np.float64)
        for i, a in enumerate(angle_rows):
            angles[i, : a.shape[0]] = a
    return ranges, angles, beams
