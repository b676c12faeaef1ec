"""The relation-based SLAM error metric of Kuemmerle et al. (2009).

"On measuring the accuracy of SLAM algorithms" (Autonomous Robots 27(4)) scores a trajectory by
relative poses: for each reference relation ``delta_ref`` between the poses at two timestamps, the
estimate's relation ``delta_est = x1^-1 (+) x2`` is compared as ``e = delta_ref^-1 (+) delta_est``.
The translational error is ``||e_xy||`` and the rotational error ``|e_theta|``; the metric reports
their mean and standard deviation, absolute and squared, over all relations (weighted equally).

Relations files (Freiburg SLAM-evaluation format) hold one relation per line:
``t1 t2 dx dy dz droll dpitch dyaw`` with ``(dx, dy, dyaw)`` the pose of scan 2 in the frame of
scan 1 and the timestamps the CARMEN ``ipc_timestamp`` of the two scans.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from probmap.errors import DatasetError
from probmap.geometry.se2 import between, compose, inverse, wrap_angle
from probmap.geometry.timesync import nearest_time_index


@dataclass(frozen=True)
class RelationsConfig:
    """Settings of ``probmap evaluate relations``; loadable from and dumpable to YAML with
    :mod:`probmap.config`.

    Attributes
    ----------
    tolerance : float
        A relation's timestamps match a trajectory's pose within this many seconds (>= 0).
    poses : {"robot", "laser"}
        For a CARMEN log: its odometry fields (robot) or its laser poses.
    """

    tolerance: float = 1e-3
    poses: Literal["robot", "laser"] = "robot"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tolerance) and self.tolerance >= 0):
            raise ValueError(f"tolerance must be a number >= 0 s, got {self.tolerance}")
        if self.poses not in ("robot", "laser"):
            raise ValueError(f"poses must be 'robot' or 'laser', got {self.poses!r}")


@dataclass(frozen=True, eq=False)
class Relations:
    """Reference relative poses.

    Attributes
    ----------
    t1, t2 : ndarray, shape (N,)
        Timestamps (seconds) of the first and second pose of each relation.
    delta : ndarray, shape (N, 3)
        ``(dx, dy, dtheta)``: pose 2 in the frame of pose 1 (metres, radians).
    """

    t1: NDArray[np.float64]
    t2: NDArray[np.float64]
    delta: NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.t1.shape[0])


@dataclass(frozen=True, eq=False)
class RelationErrors:
    """Per-relation errors and their statistics.

    Attributes
    ----------
    translation : ndarray, shape (M,)
        ``||e_xy||`` in metres for each relation whose two timestamps were found.
    rotation : ndarray, shape (M,)
        ``|e_theta|`` in radians.
    used : ndarray of bool, shape (N,)
        Which relations were evaluated.
    """

    translation: NDArray[np.float64]
    rotation: NDArray[np.float64]
    used: NDArray[np.bool_]

    @property
    def missing(self) -> int:
        """Relations skipped because a timestamp had no pose within the tolerance."""
        return int((~self.used).sum())

    def summary(self) -> dict[str, float]:
        """Mean and standard deviation of the absolute and squared errors (metres, degrees)."""
        t = self.translation
        r = np.degrees(self.rotation)
        return {
            "relations": float(len(t)),
            "missing": float(self.missing),
            "trans_abs_mean_m": float(t.mean()),
            "trans_abs_std_m": float(t.std()),
            "trans_sq_mean_m2": float((t**2).mean()),
            "trans_sq_std_m2": float((t**2).std()),
            "rot_abs_mean_deg": float(r.mean()),
            "rot_abs_std_deg": float(r.std()),
            "rot_sq_mean_deg2": float((r**2).mean()),
            "rot_sq_std_deg2": float((r**2).std()),
        }


def read_relations(path: str | os.PathLike[str]) -> Relations:
    """Read a relations file (``t1 t2 dx dy dz droll dpitch dyaw`` per line; ``#`` comments).

    Raises
    ------
    DatasetError
        Naming the file and line of a malformed relation, or an empty file.
    """
    p = Path(path)
    from probmap.datasets.validate import number_rows

    rows = [
        [v[0], v[1], v[2], v[3], v[7]]
        for _, v in number_rows(p, "t1 t2 dx dy dz droll dpitch dyaw", "relation")
    ]
    if not rows:
        raise DatasetError("no relations in file", path=p)
    a = np.asarray(rows)
    return Relations(a[:, 0], a[:, 1], a[:, 2:5].copy())


def read_trajectory(
    path: str | os.PathLike[str], *, poses: str = "robot"
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Timestamps (T,) and poses (T, 3) from a trajectory CSV, a TUM file or a CARMEN log.

    A CSV needs a header with ``time``/``timestamp``, ``x``, ``y`` and ``theta``/``yaw`` columns
    (as probmap writes ``trajectory.csv``). A ``.tum`` file is read by
    :func:`probmap.datasets.tum.read_tum` (as ``--tum`` writes it; the yaw of its quaternions is
    the heading). A CARMEN log gives its scans' ipc timestamps with the
    robot poses (``poses="robot"``: the ``odom_*`` fields of FLASER) or laser poses
    (``poses="laser"``).
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file")
    if poses not in ("robot", "laser"):
        raise ValueError(f"poses must be 'robot' or 'laser', got {poses!r}")
    if p.suffix.lower() == ".csv":
        return _read_trajectory_csv(p)
    if p.suffix.lower() == ".tum":
        from probmap.datasets.tum import read_tum

        return read_tum(p)
    from probmap.datasets.carmen import load_scans

    batch = load_scans(p, poses="corrected")
    xy = batch.robot_poses if poses == "robot" else batch.laser_poses
    return np.asarray(batch.times, dtype=np.float64), np.asarray(xy, dtype=np.float64)


def _read_trajectory_csv(p: Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    with open(p, newline="", encoding="utf-8") as f:
        reader = csv.reader(f)
        try:
            header = [h.strip().lower() for h in next(reader)]
        except StopIteration:
            raise DatasetError("empty trajectory file", path=p) from None
        cols = []
        for names in (("time", "timestamp", "t"), ("x",), ("y",), ("theta", "yaw", "heading")):
            idx = next((header.index(n) for n in names if n in header), None)
            if idx is None:
                raise DatasetError(
                    f"missing column {names[0]!r} (header is {','.join(header)})",
                    path=p,
                    line=1,
                    field=names[0],
                )
            cols.append(idx)
        rows = []
        for number, row in enumerate(reader, 2):
            if not row or row[0].startswith("#"):
                continue
            try:
                rows.append([float(row[i]) for i in cols])
            except (ValueError, IndexError):
                raise DatasetError("malformed trajectory row", path=p, line=number) from None
    if not rows:
        raise DatasetError("trajectory has no poses", path=p)
    a = np.asarray(rows)
    if not np.isfinite(a).all():
        raise DatasetError("non-finite value in trajectory", path=p)
    return a[:, 0].copy(), a[:, 1:4].copy()


def relation_errors(
    times: NDArray[np.float64],
    poses: NDArray[np.float64],
    relations: Relations,
    *,
    tolerance: float = 1e-3,
) -> RelationErrors:
    """Errors of a trajectory on reference relations (Kuemmerle et al. 2009).

    Parameters
    ----------
    times : ndarray, shape (T,)
        Timestamps of the estimated poses, seconds.
    poses : ndarray, shape (T, 3)
        Estimated poses ``(x, y, theta)``.
    relations : Relations
        Reference relative poses.
    tolerance : float
        A relation's timestamp matches the nearest pose within this many seconds.

    Returns
    -------
    RelationErrors

    Raises
    ------
    ValueError
        If shapes disagree or no relation could be matched.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.array([0.0, 1.0]); x = np.array([[0, 0, 0], [1.0, 0, 0]])
    >>> rel = Relations(np.array([0.0]), np.array([1.0]), np.array([[1.2, 0.0, 0.0]]))
    >>> round(float(relation_errors(t, x, rel).translation[0]), 6)
    0.2
    """
    times = np.asarray(times, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    if times.ndim != 1 or poses.shape != (len(times), 3):
        raise ValueError(f"times (T,) and poses (T, 3) disagree: {times.shape}, {poses.shape}")
    if len(times) == 0:
        raise ValueError("the trajectory has no poses")
    i1 = nearest_time_index(times, relations.t1, tolerance)
    i2 = nearest_time_index(times, relations.t2, tolerance)
    used = (i1 >= 0) & (i2 >= 0)
    if not used.any():
        raise ValueError(
            f"no relation timestamp matches a trajectory time within {tolerance} s "
            f"(trajectory {times.min():.3f}..{times.max():.3f}, relations "
            f"{relations.t1.min():.3f}..{relations.t2.max():.3f})"
        )
    est = between(poses[i1[used]], poses[i2[used]])
    err = compose(inverse(relations.delta[used]), est)
    return RelationErrors(
        translation=np.hypot(err[:, 0], err[:, 1]),
        rotation=np.abs(wrap_angle(err[:, 2])),
        used=used,
    )
