"""The landmark-observation record shared by every landmark-SLAM dataset.

A landmark dataset is a :class:`~probmap.datasets.protocol.Dataset` of :class:`LandmarkStep`
records, one per event (a control change or a batch of observations), and carries the models and
ground truth that an estimator and the metrics need (see :class:`LandmarkDataset`).

Stepping convention (all readers): each record says "apply ``control`` for ``dt`` seconds, then
observe ``z``". Readers are event-driven with a zero-order hold: ``dt`` is the time since the
previous record, ``control`` the latest control received before this record's time.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from probmap._checks import require_at_least
from probmap._typing import FloatArray, IntArray
from probmap.datasets.validate import text_lines
from probmap.errors import DatasetError

__all__ = [
    "LandmarkDataset",
    "LandmarkSequence",
    "LandmarkStep",
    "MergedEvents",
    "merge_events",
    "read_numeric_table",
]


def _frozen(a: Any, dtype: Any, shape_tail: tuple[int, ...], name: str) -> NDArray[Any]:
    arr = np.array(a, dtype=dtype)
    if shape_tail and (arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail):
        if arr.size == 0:
            arr = arr.reshape((0, *shape_tail))
        else:
            raise ValueError(f"{name} must have shape (k, {', '.join(map(str, shape_tail))})")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class LandmarkStep:
    """One event of a landmark-SLAM run.

    Attributes
    ----------
    time : float
        Time of the event (s).
    dt : float
        Seconds since the previous record (>= 0): the length of the motion step.
    control : ndarray, shape (2,)
        Control held over the step (model-specific, e.g. ``(v, w)`` or ``(v_e, alpha)``).
    z : ndarray, shape (k, 2)
        Observations ``(range m, bearing rad)`` in the sensor frame, after the motion.
    ids : ndarray, shape (k,), int64
        Landmark identity of each observation, ``-1`` when unknown.
    gt_pose : ndarray, shape (3,) or None
        Ground-truth pose at ``time`` when known.
    """

    time: float
    dt: float
    control: FloatArray
    z: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    ids: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    gt_pose: FloatArray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "control", _frozen(self.control, np.float64, (), "control"))
        if self.control.shape != (2,):
            raise ValueError(f"control must have shape (2,), got {self.control.shape}")
        object.__setattr__(self, "z", _frozen(self.z, np.float64, (2,), "z"))
        object.__setattr__(self, "ids", _frozen(self.ids, np.int64, (), "ids"))
        if self.ids.shape != (self.z.shape[0],):
            raise ValueError(f"ids must have shape ({self.z.shape[0]},), got {self.ids.shape}")
        if self.gt_pose is not None:
            gt = _frozen(self.gt_pose, np.float64, (), "gt_pose")
            if gt.shape != (3,):
                raise ValueError(f"gt_pose must have shape (3,), got {gt.shape}")
            object.__setattr__(self, "gt_pose", gt)
        require_at_least("dt", self.dt, 0)


@runtime_checkable
class LandmarkDataset(Protocol):
    """What a landmark-SLAM dataset provides besides being a sequence of :class:`LandmarkStep`."""

    name: str
    motion_model: Any
    measurement_model: Any
    initial_pose: FloatArray
    initial_covariance: FloatArray
    landmark_truth: dict[int, FloatArray] | None
    gt_trajectory: FloatArray | None
    gps: FloatArray | None

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[LandmarkStep]: ...


@dataclass(eq=False)
class LandmarkSequence:
    """An in-memory landmark dataset: a list of steps plus its models and ground truth.

    Attributes
    ----------
    name : str
    steps : sequence of LandmarkStep
    motion_model, measurement_model
        Models from :mod:`probmap.models`.
    initial_pose : ndarray, shape (3,)
    initial_covariance : ndarray, shape (3, 3)
    landmark_truth : dict[int, ndarray (2,)] or None
        True landmark positions keyed by id (world frame).
    gt_trajectory : ndarray, shape (T, 4) or None
        ``time, x, y, theta`` ground truth.
    gps : ndarray, shape (G, 3) or None
        ``time, x, y`` GPS fixes (possibly in another frame).
    """

    name: str
    steps: Sequence[LandmarkStep]
    motion_model: Any
    measurement_model: Any
    initial_pose: FloatArray
    initial_covariance: FloatArray = field(default_factory=lambda: np.diag([1e-6] * 3))
    landmark_truth: dict[int, FloatArray] | None = None
    gt_trajectory: FloatArray | None = None
    gps: FloatArray | None = None

    def __len__(self) -> int:
        return len(self.steps)

    def __iter__(self) -> Iterator[LandmarkStep]:
        return iter(self.steps)

    def __getitem__(self, i: int) -> LandmarkStep:
        return self.steps[i]


class MergedEvents:
    """The steps of a reader that stepped its log with :func:`merge_events` (:class:`MRCLAM
    <probmap.datasets.utias.MRCLAM>`, :class:`~probmap.datasets.victoria_park.VictoriaPark`):
    their ``__len__`` and ``__iter__``, one :class:`LandmarkStep` per event.

    A subclass sets, from :func:`merge_events`' output, ``_times``, ``_dts`` (E,),
    ``_controls`` (E, 2) and ``_obs_start`` (E + 1,), and the kept observations in time order:
    ``_z`` (K, 2) and ``_ids`` (K,) (-1 where the identity is unknown).
    """

    _times: FloatArray
    _dts: FloatArray
    _controls: FloatArray
    _obs_start: IntArray
    _z: FloatArray
    _ids: IntArray

    def __len__(self) -> int:
        return int(self._times.size)

    def __iter__(self) -> Iterator[LandmarkStep]:
        s = self._obs_start
        for e in range(self._times.size):
            yield LandmarkStep(
                time=float(self._times[e]),
                dt=float(self._dts[e]),
                control=self._controls[e],
                z=self._z[s[e] : s[e + 1]],
                ids=self._ids[s[e] : s[e + 1]],
            )


def read_numeric_table(
    path: str | os.PathLike[str],
    columns: Sequence[str],
    *,
    min_columns: int | None = None,
    time_column: int | None = 0,
    allow_equal_times: bool = True,
) -> tuple[FloatArray, int]:
    """Read a whitespace-separated numeric text table with clear errors.

    Lines that are empty or start with ``#`` are ignored. Every other line must hold at least
    ``min_columns`` (default ``len(columns)``) numbers; extra fields are ignored.

    Parameters
    ----------
    path : path-like
    columns : sequence of str
        Column names, used in error messages.
    min_columns : int, optional
    time_column : int or None
        Index of a time column that must not go backwards (``None`` to skip the check).
    allow_equal_times : bool
        Whether consecutive rows may share a time stamp.

    Returns
    -------
    table : ndarray, shape (rows, len(columns))
        Rows with a NaN or infinite value are dropped (see ``skipped``).
    skipped : int
        Number of rows dropped because of NaN/inf values; the caller warns about them.

    Raises
    ------
    DatasetError
        Missing columns, non-numeric fields, or times that go backwards; names the file, line and
        field.
    """
    ncol = len(columns)
    need = ncol if min_columns is None else min_columns
    rows: list[list[float]] = []
    skipped = 0
    last_t = -np.inf
    path = Path(path)
    for lineno, line in text_lines(path):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split()
        if len(parts) < need:
            raise DatasetError(
                f"expected {need} columns ({', '.join(columns[:need])}), found {len(parts)}",
                path=path,
                line=lineno,
            )
        vals = []
        for j in range(min(ncol, len(parts))):
            try:
                vals.append(float(parts[j]))
            except ValueError:
                raise DatasetError(
                    f"not a number: {parts[j]!r}", path=path, line=lineno, field=columns[j]
                ) from None
        vals.extend([np.nan] * (ncol - len(vals)))
        if not all(np.isfinite(vals[:need])):
            skipped += 1
            continue
        if time_column is not None:
            t = vals[time_column]
            if t < last_t or (t == last_t and not allow_equal_times):
                raise DatasetError(
                    f"time {t} goes backwards (previous {last_t})",
                    path=path,
                    line=lineno,
                    field=columns[time_column],
                )
            last_t = t
        rows.append(vals)
    table = np.array(rows, dtype=np.float64).reshape(-1, ncol)
    return table, skipped


def merge_events(
    control_times: FloatArray,
    controls: FloatArray,
    obs_times: FloatArray,
    obs: FloatArray,
    obs_ids: IntArray,
    *,
    start: float | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, IntArray, IntArray]:
    """Event-driven stepping with a zero-order hold of the control.

    Events are the control times and the distinct observation times (sorted; an observation at
    the same time as a control shares its event). The step ending at event ``e`` lasts from the
    previous event and uses the control received last *before* that interval began (zero before
    the first control). Observations are attached to the event at their time.

    Parameters
    ----------
    control_times : (C,)  controls : (C, 2)
    obs_times : (K,)  obs : (K, 2)  obs_ids : (K,)
    start : float, optional
        Events before ``start`` are dropped (their controls still count for the hold).

    Returns
    -------
    times : (E,)
        Event times.
    dts : (E,)
    step_controls : (E, 2)
    obs_start : (E + 1,) int64
        Observations of event ``e`` are ``obs[order][obs_start[e]:obs_start[e + 1]]``.
    order : (K',) int64
        Indices into ``obs`` of the kept observations, sorted by time (stable).
    """
    times = np.union1d(control_times, obs_times)
    if start is not None:
        times = times[times >= start]
    # control active over (t_prev, t]: the last control at or before t_prev
    prev = np.concatenate([times[:1], times[:-1]])
    idx = np.searchsorted(control_times, prev, side="right") - 1
    step_controls = np.where(idx[:, None] >= 0, controls[np.maximum(idx, 0)], 0.0)
    dts = np.diff(times, prepend=times[:1])
    order = np.argsort(obs_times, kind="stable")
    if start is not None:
        order = order[obs_times[order] >= start]
    ev = np.searchsorted(times, obs_times[order])
    obs_start = np.searchsorted(ev, np.arange(times.size + 1))
    return times, dts, step_controls, obs_start.astype(np.int64), order.astype(np.int64)
