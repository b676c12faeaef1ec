"""Motion models for landmark SLAM with analytic Jacobians.

Each model is a frozen dataclass with

* ``predict(x, u, dt) -> (x_new, G, V)``: the noise-free motion ``g(u, x)`` with
  ``G = d x_new / d x`` (3x3) and ``V = d x_new / d u`` (3x2), and
* ``control_covariance(u, dt) -> M`` (2x2): the covariance of the noise on ``u``,

so that the additive process noise of an EKF prediction is ``Q = V M V^T`` (Probabilistic Robotics,
Table 7.3 lines 3-7 and Table 10.1 lines 3-4).

Frames and units: poses ``(x, y, theta)`` in metres/radians in the world frame; times in seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from probmap._checks import is_finite_number
from probmap._typing import FloatArray
from probmap.geometry.se2 import wrap_angle
from probmap.models._motion_kernels import ackermann_rates

__all__ = ["AckermannModel", "VelocityModel"]

_SERIES = 1e-4  # |w dt| below which the arc functions use their Taylor series


def _arc_terms(d: float) -> tuple[float, float, float, float]:
    """``A = sin(d)/d``, ``B = (1 - cos d)/d`` and their derivatives in ``d``, stable at 0."""
    if abs(d) < _SERIES:
        d2 = d * d
        return 1.0 - d2 / 6.0, d / 2.0 - d * d2 / 24.0, -d / 3.0, 0.5 - d2 / 8.0
    s, c = np.sin(d), np.cos(d)
    A = s / d
    B = (1.0 - c) / d
    dA = (d * c - s) / (d * d)
    dB = (d * s - (1.0 - c)) / (d * d)
    return float(A), float(B), float(dA), float(dB)


def _check(x: ArrayLike, u: ArrayLike, dt: float) -> tuple[FloatArray, FloatArray, float]:
    x = np.asarray(x, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    if x.shape != (3,):
        raise ValueError(f"pose x must have shape (3,), got {x.shape}")
    if u.shape != (2,):
        raise ValueError(f"control u must have shape (2,), got {u.shape}")
    dt = float(dt)
    if not math.isfinite(dt) or dt < 0.0:
        raise ValueError(f"dt must be finite and >= 0, got {dt}")
    # one scalar test: a sum is finite only if every term is (NaN and inf propagate)
    if not math.isfinite(float(x.sum() + u.sum())):
        raise ValueError("pose and control must be finite")
    return x, u, dt


def _check_noise(model: Any, a: str, b: str) -> None:
    """Raise unless the noise floors ``model.<a>`` and ``model.<b>`` are finite and >= 0 and
    ``model.reference_dt`` is None or a finite number > 0 (seconds)."""
    va, vb = getattr(model, a), getattr(model, b)
    if not (is_finite_number(va) and is_finite_number(vb)):
        raise ValueError(f"{a} and {b} must be finite, got {va}, {vb}")
    if va < 0 or vb < 0:
        raise ValueError(f"{a} and {b} must be >= 0")
    dt = model.reference_dt
    if dt is not None and not (is_finite_number(dt) and dt > 0):
        raise ValueError(f"reference_dt must be a finite number > 0 s, got {dt}")


class _MotionModel:
    """What every motion model of this module shares: :meth:`predict` checks its inputs and
    hands them to the model's ``_predict``; :meth:`control_covariance` scales the model's
    per-step ``_control_noise`` by ``reference_dt / dt`` (white noise on the control)."""

    reference_dt: float | None

    def predict(
        self, x: ArrayLike, u: ArrayLike, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Noise-free motion ``g(u, x)`` and its Jacobians (Table 10.1, lines 3-4).

        Parameters
        ----------
        x : array_like, shape (3,)
            Pose ``(x, y, theta)`` (m, m, rad) at the start of the step (for
            :class:`AckermannModel`, the pose of its reference point).
        u : array_like, shape (2,)
            The control, held constant over the step: ``(v, w)`` (m/s, rad/s) for
            :class:`VelocityModel`, ``(v_e, alpha)`` (m/s, rad) for :class:`AckermannModel`.
        dt : float
            Step length (s), >= 0.

        Returns
        -------
        x_new : ndarray, shape (3,)
        G : ndarray, shape (3, 3)
            ``d x_new / d x``.
        V : ndarray, shape (3, 2)
            ``d x_new / d u``.
        """
        x, u, dt = _check(x, u, dt)
        return self._predict(x, u, dt)

    def _predict(
        self, x: FloatArray, u: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        raise NotImplementedError  # pragma: no cover - every model defines it

    def control_covariance(self, u: ArrayLike, dt: float) -> FloatArray:
        """Covariance ``M`` (2x2) of the noise on ``u`` for a step of ``dt`` s."""
        M = self._control_noise(np.asarray(u, dtype=np.float64))
        if self.reference_dt is not None and dt > 0:
            M *= self.reference_dt / dt
        return M

    def _control_noise(self, u: FloatArray) -> FloatArray:
        raise NotImplementedError  # pragma: no cover - every model defines it


@dataclass(frozen=True)
class VelocityModel(_MotionModel):
    """Unicycle velocity motion model, ``u = (v, w)`` in m/s and rad/s (Table 5.3, no final turn).

    The pose moves on the exact arc of radius ``v / w``; the straight-line limit ``w -> 0`` is
    handled by series expansions, so the model and its Jacobians are smooth in ``w``.

    Noise (Table 5.3 with a floor): the control noise covariance is
    ``M = diag(a1 v^2 + a2 w^2 + sigma_v^2, a3 v^2 + a4 w^2 + sigma_w^2) * (reference_dt / dt)``.
    The factor ``reference_dt / dt`` makes the pose uncertainty accumulated over a fixed time
    independent of how finely it is stepped (white noise on the velocity); leave
    ``reference_dt=None`` for the book's per-step noise.

    Parameters
    ----------
    alphas : tuple of 4 floats
        ``(a1, a2, a3, a4)`` of Table 5.3 (dimensionless / m^2 / rad^2 mixtures).
    sigma_v : float
        Noise floor on ``v`` (m/s).
    sigma_w : float
        Noise floor on ``w`` (rad/s).
    reference_dt : float or None
        Step length (s) at which the noise figures hold.
    """

    alphas: tuple[float, float, float, float] = (0.01, 0.001, 0.001, 0.01)
    sigma_v: float = 0.01
    sigma_w: float = 0.01
    reference_dt: float | None = None

    def __post_init__(self) -> None:
        if len(self.alphas) != 4 or not all(is_finite_number(a) and a >= 0 for a in self.alphas):
            raise ValueError(f"alphas must be 4 finite non-negative numbers, got {self.alphas}")
        _check_noise(self, "sigma_v", "sigma_w")

    def _predict(
        self, x: FloatArray, u: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        v, w = u
        th = x[2]
        d = w * dt
        A, B, dA, dB = _arc_terms(d)
        c, s = np.cos(th), np.sin(th)
        # x_new = x + v dt R(th) (A, B): exact arc written with smooth sinc-like terms
        px = c * A - s * B
        py = s * A + c * B
        x_new = np.array([x[0] + v * dt * px, x[1] + v * dt * py, wrap_angle(th + d)])
        G = np.array([[1.0, 0.0, -v * dt * py], [0.0, 1.0, v * dt * px], [0.0, 0.0, 1.0]])
        V = np.zeros((3, 2))
        V[0, 0] = dt * px
        V[1, 0] = dt * py
        V[0, 1] = v * dt * dt * (c * dA - s * dB)
        V[1, 1] = v * dt * dt * (s * dA + c * dB)
        V[2, 1] = dt
        return x_new, G, V

    def _control_noise(self, u: FloatArray) -> FloatArray:
        v2, w2 = float(u[0]) ** 2, float(u[1]) ** 2
        a1, a2, a3, a4 = self.alphas
        return np.diag([a1 * v2 + a2 * w2 + self.sigma_v**2, a3 * v2 + a4 * w2 + self.sigma_w**2])


@dataclass(frozen=True)
class AckermannModel(_MotionModel):
    """Ackermann (car-like) model driven by an encoder on a rear wheel (Guivant & Nebot 2001).

    ``u = (v_e, alpha)``: speed measured at the encoder wheel (m/s) and steering angle (rad).
    The encoder sits ``encoder_offset`` = H metres to the side of the rear-axle centre, so the
    centre speed is ``v_c = v_e / (1 - tan(alpha) H / L)``. The state is the pose of the point
    ``reference_point = (a, b)`` (metres ahead of and to the left of the rear-axle centre, in the
    vehicle frame), which moves as (Euler step of length ``dt``)::

        x' = x + dt (v_c cos(phi) - v_c / L tan(alpha) (a sin(phi) + b cos(phi)))
        y' = y + dt (v_c sin(phi) + v_c / L tan(alpha) (a cos(phi) - b sin(phi)))
        phi' = phi + dt v_c / L tan(alpha)

    With ``reference_point=(0, 0)`` (the default) the state is the rear-axle centre, and a sensor
    mounted elsewhere is described by the measurement model's ``sensor_offset``.

    Parameters
    ----------
    wheelbase : float
        L (m); 2.83 for the Victoria Park car.
    encoder_offset : float
        H (m), lateral offset of the encoder wheel; 0.76 for Victoria Park.
    reference_point : (float, float)
        (a, b) in metres.
    sigma_v : float
        Standard deviation of the encoder speed (m/s).
    sigma_steer : float
        Standard deviation of the steering angle (rad).
    reference_dt : float or None
        As for :class:`VelocityModel`: step length at which the noise figures hold.
    """

    wheelbase: float = 2.83
    encoder_offset: float = 0.76
    reference_point: tuple[float, float] = (0.0, 0.0)
    sigma_v: float = 0.5
    sigma_steer: float = np.deg2rad(3.0)
    reference_dt: float | None = None

    def __post_init__(self) -> None:
        if not (is_finite_number(self.wheelbase) and self.wheelbase > 0):
            raise ValueError(f"wheelbase must be a finite number > 0, got {self.wheelbase}")
        if not is_finite_number(self.encoder_offset):
            raise ValueError(f"encoder_offset must be finite, got {self.encoder_offset}")
        if len(self.reference_point) != 2 or not all(
            is_finite_number(v) for v in self.reference_point
        ):
            raise ValueError(
                f"reference_point must be 2 finite numbers, got {self.reference_point}"
            )
        _check_noise(self, "sigma_v", "sigma_steer")

    def _predict(
        self, x: FloatArray, u: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        ve, al = u
        L, H = self.wheelbase, self.encoder_offset
        a, b = self.reference_point
        # v_c, k = v_c tan(alpha) / L and their derivatives in (v_e, alpha): the one kernel
        # that GraphSLAM's compiled chain calls too
        ok, vc, k, dvc_dve, dvc_dal, dk_dve, dk_dal = ackermann_rates(ve, np.tan(al), H, L)
        if not ok:
            raise ValueError(f"steering angle {al} makes the encoder speed conversion singular")
        c, s = np.cos(x[2]), np.sin(x[2])
        ox = a * s + b * c  # lateral lever terms of the reference point
        oy = a * c - b * s
        x_new = np.array(
            [
                x[0] + dt * (vc * c - k * ox),
                x[1] + dt * (vc * s + k * oy),
                wrap_angle(x[2] + dt * k),
            ]
        )
        G = np.array(
            [
                [1.0, 0.0, dt * (-vc * s - k * oy)],
                [0.0, 1.0, dt * (vc * c - k * ox)],
                [0.0, 0.0, 1.0],
            ]
        )
        V = np.zeros((3, 2))
        V[0, 0] = dt * (dvc_dve * c - dk_dve * ox)
        V[0, 1] = dt * (dvc_dal * c - dk_dal * ox)
        V[1, 0] = dt * (dvc_dve * s + dk_dve * oy)
        V[1, 1] = dt * (dvc_dal * s + dk_dal * oy)
        V[2, 0] = dt * dk_dve
        V[2, 1] = dt * dk_dal
        return x_new, G, V

    def _control_noise(self, u: FloatArray) -> FloatArray:
        return np.diag([self.sigma_v**2, self.sigma_steer**2])
