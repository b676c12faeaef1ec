"""The interface every landmark-SLAM estimator (EKF, SEIF) offers to pipelines and metrics."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from numpy.typing import ArrayLike

from probmap._typing import FloatArray, IntArray

__all__ = ["LandmarkSLAM"]


@runtime_checkable
class LandmarkSLAM(Protocol):
    """An online landmark-SLAM estimator.

    ``predict`` then ``update`` once per :class:`~probmap.datasets.landmarks.LandmarkStep`.
    """

    def predict(self, u: ArrayLike, dt: float) -> None:
        """Motion update with control ``u`` (2,) held for ``dt`` seconds."""

    def update(self, z: ArrayLike, ids: ArrayLike) -> None:
        """Measurement update with ``z`` (k, 2) range/bearing and ``ids`` (k,) (-1 = unknown)."""

    @property
    def pose(self) -> FloatArray:
        """Current pose estimate (3,)."""

    @property
    def pose_covariance(self) -> FloatArray:
        """Marginal covariance of the pose (3, 3)."""

    def landmarks(self) -> tuple[IntArray, FloatArray, FloatArray]:
        """Mapped landmarks: ``ids (n,)``, ``xy (n, 2)``, ``cov (n, 2, 2)``."""
