"""Trajectories in the TUM RGB-D format, the plain-text format that ``evo`` reads.

One pose per line, fields separated by spaces::

    timestamp tx ty tz qx qy qz qw

with the position in metres and the orientation as a unit quaternion (Hamilton, scalar last).
Lines starting with ``#`` are comments. probmap's poses are planar ``(x, y, theta)``: they are
written with ``tz = 0`` and the heading as a rotation about z, ``q = (0, 0, sin(theta/2),
cos(theta/2))`` with ``theta`` wrapped to ``[-pi, pi)`` (so ``qw >= 0``). Reading keeps the
position's ``x, y`` and the quaternion's yaw; height, roll and pitch are dropped.

Examples
--------
>>> import tempfile, pathlib
>>> path = pathlib.Path(tempfile.mkdtemp()) / "run.tum"
>>> _ = write_tum(path, [0.0, 0.1], [[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
>>> path.read_text().splitlines()[2]
'0.100000000 1.000000000 2.000000000 0.000000000 0.000000000000 0.000000000000 0.997494986604 0.070737201668'
>>> times, poses = read_tum(path)
>>> poses[1].round(6).tolist()
[1.0, 2.0, 3.0]
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._atomic import atomic_write
from probmap.datasets.validate import number_rows
from probmap.errors import DatasetError
from probmap.geometry.se2 import wrap_angle

__all__ = ["TUM_HEADER", "read_tum", "write_tum", "yaw_quaternion", "quaternion_yaw"]

TUM_HEADER = "# timestamp tx ty tz qx qy qz qw"
"""The comment line :func:`write_tum` puts first (``evo`` skips ``#`` lines)."""


def yaw_quaternion(theta: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternions ``(qx, qy, qz, qw)`` of rotations by ``theta`` about z, shape (..., 4).

    ``theta`` is wrapped to ``[-pi, pi)`` first, so ``qw = cos(theta/2) >= 0``.
    """
    half = 0.5 * wrap_angle(theta)
    zero = np.zeros_like(half)
    return np.stack([zero, zero, np.sin(half), np.cos(half)], axis=-1)


def quaternion_yaw(q: ArrayLike) -> NDArray[np.float64]:
    """Yaw (rotation about z, wrapped to ``[-pi, pi)``) of quaternions ``(qx, qy, qz, qw)``,
    shape (..., 4) -> (...). Any norm but zero is accepted (the quaternion is normalised)."""
    a = np.asarray(q, dtype=np.float64)
    x, y, z, w = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    yaw = np.arctan2(2.0 * (w * z + x * y), (w * w + x * x) - (y * y + z * z))
    return wrap_angle(yaw)


def write_tum(path: str | os.PathLike[str], times: ArrayLike, poses: ArrayLike) -> Path:
    """Write a planar trajectory as a TUM file, atomically.

    Parameters
    ----------
    path : path-like
        The file to write (conventionally ``*.tum`` or ``*.txt``); inside an
        :func:`probmap._atomic.atomic_outputs` block it joins that block's files.
    times : array_like, shape (T,)
        Timestamps in seconds.
    poses : array_like, shape (T, 3)
        ``(x, y, theta)`` in metres and radians.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        When the shapes disagree or a value is not finite.
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{path}: poses must have shape (T, 3), got {p.shape}")
    if p.shape[0] != t.shape[0]:
        raise ValueError(f"{path}: {t.shape[0]} timestamps for {p.shape[0]} poses")
    if not (np.isfinite(t).all() and np.isfinite(p).all()):
        raise ValueError(f"{path}: timestamps and poses must be finite")
    q = yaw_quaternion(p[:, 2])
    rows = np.column_stack([t, p[:, 0], p[:, 1], np.zeros_like(t), q])
    buf = io.StringIO()
    buf.write(TUM_HEADER + "\n")
    if len(rows):
        np.savetxt(buf, rows, fmt=["%.9f"] * 4 + ["%.12f"] * 4, delimiter=" ")
    with atomic_write(path, "w") as f:
        f.write(buf.getvalue())
    return Path(path)


def read_tum(path: str | os.PathLike[str]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Timestamps (T,) and planar poses (T, 3) ``(x, y, yaw)`` from a TUM trajectory file.

    Blank lines and lines starting with ``#`` are skipped; fields may be separated by spaces,
    tabs or commas (as ``evo`` accepts).

    Raises
    ------
    FileNotFoundError
        When the file does not exist.
    DatasetError
        On a line without exactly 8 numbers, a non-finite value or a zero quaternion (the
        message names the file and the line), or a file without poses.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file")
    rows: list[list[float]] = []
    for number, values in number_rows(p, "timestamp tx ty tz qx qy qz qw", "TUM pose", commas=True):
        if not any(values[4:8]):
            raise DatasetError("zero quaternion in TUM pose", path=p, line=number)
        rows.append(values)
    if not rows:
        raise DatasetError("TUM trajectory has no poses", path=p)
    a = np.asarray(rows, dtype=np.float64)
    poses = np.column_stack([a[:, 1], a[:, 2], quaternion_yaw(a[:, 4:8])])
    return a[:, 0].copy(), poses
