"""Range-bearing measurement model with a sensor offset (Probabilistic Robotics, eq. 6.40, 10.x).

A landmark ``m = (m_x, m_y)`` (world frame, metres) is observed from a sensor mounted at
``sensor_offset = (dx, dy, dtheta)`` in the robot frame as ``z = (r, phi)``: range (m) and bearing
(rad, counter-clockwise from the sensor's x axis, wrapped to [-pi, pi)).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from probmap._typing import FloatArray
from probmap.geometry.se2 import wrap_angle

__all__ = ["RangeBearingModel"]


def _default_R() -> FloatArray:
    return np.diag([0.1**2, np.deg2rad(2.0) ** 2])


@dataclass(frozen=True, eq=False)
class RangeBearingModel:
    """Range-bearing sensor ``z = h(x, m) + N(0, R)`` (Table 10.1, lines 12-16).

    Parameters
    ----------
    sensor_offset : (float, float, float)
        Sensor pose ``(dx, dy, dtheta)`` in the robot frame (m, m, rad).
    R : ndarray, shape (2, 2)
        Measurement noise covariance of ``(range, bearing)`` (m^2, rad^2).
    """

    sensor_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    R: FloatArray = field(default_factory=_default_R)

    def __post_init__(self) -> None:
        R = np.array(self.R, dtype=np.float64)
        if R.shape != (2, 2) or not np.all(np.isfinite(R)):
            raise ValueError(f"R must be a finite 2x2 matrix, got shape {R.shape}")
        if not np.allclose(R, R.T) or np.any(np.linalg.eigvalsh(R) <= 0):
            raise ValueError("R must be symmetric positive definite")
        R.setflags(write=False)
        object.__setattr__(self, "R", R)
        if len(self.sensor_offset) != 3:
            raise ValueError("sensor_offset must be (dx, dy, dtheta)")
        object.__setattr__(self, "sensor_offset", tuple(float(v) for v in self.sensor_offset))

    def _sensor(self, pose: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Sensor position (..., 2), its derivative in theta (..., 2), and sensor heading."""
        dx, dy, dth = self.sensor_offset
        c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
        sx = pose[..., 0] + c * dx - s * dy
        sy = pose[..., 1] + s * dx + c * dy
        dsx = -s * dx - c * dy
        dsy = c * dx - s * dy
        return np.stack([sx, sy], -1), np.stack([dsx, dsy], -1), pose[..., 2] + dth

    def predict(
        self, pose: ArrayLike, landmark: ArrayLike
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Expected measurement and Jacobians.

        Parameters
        ----------
        pose : array_like, shape (3,)
            Robot pose (world frame).
        landmark : array_like, shape (2,)
            Landmark position (world frame).

        Returns
        -------
        z : ndarray, shape (2,)
            ``(range, bearing)``, bearing wrapped.
        H_x : ndarray, shape (2, 3)
            ``dz / d pose``.
        H_m : ndarray, shape (2, 2)
            ``dz / d landmark``.
        """
        z, H_x, H_m = self.predict_many(pose, np.asarray(landmark, dtype=np.float64)[None, :])
        return z[0], H_x[0], H_m[0]

    def predict_many(
        self, pose: ArrayLike, landmarks: ArrayLike
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Vectorised :meth:`predict` for ``landmarks`` of shape (n, 2).

        Returns ``z (n, 2)``, ``H_x (n, 2, 3)``, ``H_m (n, 2, 2)``. A landmark at the sensor
        position (zero range) raises ``ValueError``.
        """
        pose = np.asarray(pose, dtype=np.float64)
        m = np.asarray(landmarks, dtype=np.float64)
        if pose.shape != (3,):
            raise ValueError(f"pose must have shape (3,), got {pose.shape}")
        if m.ndim != 2 or m.shape[1] != 2:
            raise ValueError(f"landmarks must have shape (n, 2), got {m.shape}")
        spos, ds, heading = self._sensor(pose)
        d = m - spos
        q = np.einsum("ij,ij->i", d, d)
        if np.any(q <= 1e-18):
            raise ValueError("a landmark coincides with the sensor position (zero range)")
        r = np.sqrt(q)
        z = np.stack([r, wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - heading)], -1)
        n = m.shape[0]
        H_m = np.empty((n, 2, 2))
        H_m[:, 0, 0] = d[:, 0] / r
        H_m[:, 0, 1] = d[:, 1] / r
        H_m[:, 1, 0] = -d[:, 1] / q
        H_m[:, 1, 1] = d[:, 0] / q
        # dz/dpose = -H_m d(sensor)/d(pose) - [0, 0, 1] for the bearing's heading term
        H_x = np.empty((n, 2, 3))
        H_x[:, :, 0] = -H_m[:, :, 0]
        H_x[:, :, 1] = -H_m[:, :, 1]
        H_x[:, :, 2] = -(H_m[:, :, 0] * ds[0] + H_m[:, :, 1] * ds[1])
        H_x[:, 1, 2] -= 1.0
        return z, H_x, H_m

    def inverse(self, pose: ArrayLike, z: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Landmark position from a measurement (used to initialise new landmarks).

        Parameters
        ----------
        pose : array_like, shape (3,)
        z : array_like, shape (2,)
            ``(range, bearing)``.

        Returns
        -------
        landmark : ndarray, shape (2,)
        J_x : ndarray, shape (2, 3)
            ``d landmark / d pose``.
        J_z : ndarray, shape (2, 2)
            ``d landmark / d z``.
        """
        pose = np.asarray(pose, dtype=np.float64)
        z = np.asarray(z, dtype=np.float64)
        if pose.shape != (3,) or z.shape != (2,):
            raise ValueError(f"pose must be (3,) and z (2,), got {pose.shape} and {z.shape}")
        spos, ds, heading = self._sensor(pose)
        r, phi = z
        a = heading + phi
        c, s = np.cos(a), np.sin(a)
        landmark = spos + r * np.array([c, s])
        J_x = np.array([[1.0, 0.0, ds[0] - r * s], [0.0, 1.0, ds[1] + r * c]])
        J_z = np.array([[c, -r * s], [s, r * c]])
        return landmark, J_x, J_z
