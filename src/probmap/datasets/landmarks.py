"""The landmark-observation record shared by every landmark-SLAM dataset.

A landmark dataset is a :class:`~probmap.datasets.protocol.Dataset` of :class:`LandmarkStep`
records, one per event (a control change or a batch of observations), and carries the models and
ground truth that an estimator and the metrics need (see :class:`LandmarkDataset`).

Stepping convention (all readers): each record says "apply ``control`` for ``dt`` seconds, then
observe ``z``". Readers are event-driven with a zero-order hold: ``dt`` is the time since the
previous record, ``control`` the latest control received before this record's time.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

__all__ = ["LandmarkDataset", "LandmarkSequence", "LandmarkStep"]


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
        if not self.dt >= 0.0:
            raise ValueError(f"dt must be >= 0, got {self.dt}")


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
