"""Sampled motion models for particle filters (Probabilistic Robotics chapter 5).

Two tiers: array functions named after the book's algorithms, and small frozen dataclasses
holding the noise parameters that call them. Poses are ``(x, y, theta)`` in the world frame,
metres and radians; batches have shape ``(N, 3)``.

- Odometry model: ``motion_model_odometry`` (Table 5.5, density) and
  ``sample_motion_model_odometry`` (Table 5.6), parameters ``alpha1..alpha4``.
- Velocity model: ``motion_model_velocity`` (Table 5.1, density) and
  ``sample_motion_model_velocity`` (Table 5.3), parameters ``alpha1..alpha6``.

The densities use zero-mean normal distributions (``prob_normal_distribution``, Table 5.2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.geometry.se2 import wrap_angle  # re-exported: a name of this module

__all__ = [
    "OdometryMotionModel",
    "VelocityMotionModel",
    "motion_model_odometry",
    "motion_model_velocity",
    "odometry_deltas",
    "odometry_noise_std",
    "odometry_step_count",
    "rotation_noise_scale",
    "sample_motion_model_odometry",
    "sample_motion_model_velocity",
    "wrap_angle",
]

# Variances below this are treated as this value so that a noise-free configuration (all
# alphas zero, or no motion) still gives a finite density instead of a division by zero.
_MIN_VARIANCE = 1e-12
# Below this translation (m) the direction of travel is encoder noise: the first rotation is
# taken as zero instead of the atan2 of that noise (a turn in place would otherwise be read
# as "turn by up to pi, creep, turn back", and the noise terms scale with those rotations).
_MIN_TRANSLATION = 0.01


def _poses(p: ArrayLike, name: str) -> NDArray[np.float64]:
    arr = np.asarray(p, dtype=np.float64)
    if arr.shape[-1:] != (3,) or arr.ndim not in (1, 2):
        raise ValueError(f"{name} must have shape (3,) or (N, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _check_alphas(alphas: tuple[float, ...], name: str) -> None:
    for i, a in enumerate(alphas, start=1):
        if not np.isfinite(a) or a < 0:
            raise ValueError(f"{name}.alpha{i} must be finite and non-negative, got {a}")


def odometry_deltas(
    odom_prev: ArrayLike, odom_cur: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Decompose an odometry step into (rot1, trans, rot2), Table 5.5 lines 2-4.

    Parameters
    ----------
    odom_prev, odom_cur : (3,) or (N, 3) array_like
        Consecutive odometry poses ``xbar_{t-1}`` and ``xbar_t`` in the odometry frame.

    Returns
    -------
    rot1, trans, rot2 : ndarray
        First rotation (rad), translation (m), second rotation (rad).
    """
    a = _poses(odom_prev, "odom_prev")
    b = _poses(odom_cur, "odom_cur")
    dx = b[..., 0] - a[..., 0]
    dy = b[..., 1] - a[..., 1]
    trans = np.hypot(dx, dy)
    heading = np.where(trans < _MIN_TRANSLATION, a[..., 2], np.arctan2(dy, dx))
    rot1 = wrap_angle(heading - a[..., 2])
    rot2 = wrap_angle(b[..., 2] - a[..., 2] - rot1)
    return rot1, trans, rot2


def rotation_noise_scale(rot: ArrayLike) -> NDArray[np.float64]:
    """``min(|rot|, pi - |rot|)``: the rotation the noise terms of Table 5.6 scale with.

    Driving backwards reads as ``rot1 ~ pi``; the noise should scale with the small turn
    relative to the reversed heading, not with pi (the same correction as ROS amcl's).
    """
    r = np.abs(wrap_angle(rot))
    return np.asarray(np.minimum(r, np.pi - r))


def _prob_normal(a: ArrayLike, var: ArrayLike) -> NDArray[np.float64]:
    """Zero-mean normal density with variance ``var`` at ``a`` (Table 5.2)."""
    x = np.asarray(a, dtype=np.float64)
    v = np.maximum(np.asarray(var, dtype=np.float64), _MIN_VARIANCE)
    return np.asarray(np.exp(-0.5 * x * x / v) / np.sqrt(2.0 * np.pi * v))


def motion_model_odometry(
    pose_new: ArrayLike,
    odom_prev: ArrayLike,
    odom_cur: ArrayLike,
    pose_old: ArrayLike,
    alphas: tuple[float, float, float, float],
    unit_step: float | None = None,
) -> NDArray[np.float64]:
    """Density ``p(x_t | u_t, x_{t-1})`` of the odometry motion model, Table 5.5.

    Parameters
    ----------
    pose_new, pose_old : (3,) or (N, 3) array_like
        Hypothesised poses ``x_t`` and ``x_{t-1}`` (world frame).
    odom_prev, odom_cur : (3,) array_like
        The odometry reading ``u_t = (xbar_{t-1}, xbar_t)``.
    alphas : (alpha1, alpha2, alpha3, alpha4)
        Rotation-from-rotation, rotation-from-translation, translation-from-translation and
        translation-from-rotation noise (dimensionless variance factors).
    unit_step : float, optional
        Metres: the variances are divided by the odometry step's count of such steps
        (:func:`odometry_step_count`), as :func:`sample_motion_model_odometry` does.

    Returns
    -------
    ndarray, shape () or (N,)
        Density in units of 1 / (rad^2 m).
    """
    a1, a2, a3, a4 = alphas
    r1, tr, r2 = odometry_deltas(odom_prev, odom_cur)
    k = odometry_step_count(float(tr), unit_step)
    h1, htr, h2 = odometry_deltas(pose_old, pose_new)
    q1, q2 = rotation_noise_scale(h1), rotation_noise_scale(h2)
    p1 = _prob_normal(wrap_angle(r1 - h1), (a1 * q1**2 + a2 * htr**2) / k)
    p2 = _prob_normal(tr - htr, (a3 * htr**2 + a4 * (q1**2 + q2**2)) / k)
    p3 = _prob_normal(wrap_angle(r2 - h2), (a1 * q2**2 + a2 * htr**2) / k)
    return p1 * p2 * p3


def odometry_step_count(trans: float, unit_step: float | None) -> float:
    """How many steps of ``unit_step`` metres an odometry step of ``trans`` metres spans:
    ``max(1, trans / unit_step)``; 1 with ``unit_step=None``.

    Table 5.6's variances grow with the square of the step. Splitting a step into ``k`` equal
    parts and sampling each divides them by ``k``: the noise of one metre of travel then
    depends on how often it is sampled. Dividing the variances of a long step by its count
    of unit steps gives it the noise of the chain of unit steps it stands for, so a log with a
    scan every metre gets the noise per metre of one with a scan every 20 cm. Turns are not
    counted: a turn in place taken in one step (simulated routes) keeps its noise.
    """
    if unit_step is None:
        return 1.0
    return max(1.0, trans / unit_step)


def odometry_noise_std(
    rot1: float,
    trans: float,
    rot2: float,
    alphas: tuple[float, float, float, float],
    unit_step: float | None = None,
) -> tuple[float, float, float]:
    """Standard deviations of rot1, trans and rot2 in Table 5.6 (lines 5-7).

    Rotations enter through :func:`rotation_noise_scale` so that reversing is not noisier
    than driving forwards. With ``unit_step``, the variances are divided by
    :func:`odometry_step_count`.
    """
    a1, a2, a3, a4 = alphas
    q1 = float(rotation_noise_scale(rot1))
    q2 = float(rotation_noise_scale(rot2))
    k = odometry_step_count(trans, unit_step)
    return (
        math.sqrt((a1 * q1 * q1 + a2 * trans * trans) / k),
        math.sqrt((a3 * trans * trans + a4 * (q1 * q1 + q2 * q2)) / k),
        math.sqrt((a1 * q2 * q2 + a2 * trans * trans) / k),
    )


# Docstring sections and particle-array check as in sample_motion_model_velocity: each sampler
# documents its own inputs; the shared work is in _poses and the noise helpers.
def sample_motion_model_odometry(
    poses: ArrayLike,
    odom_prev: ArrayLike,
    odom_cur: ArrayLike,
    alphas: tuple[float, float, float, float],
    rng: np.random.Generator,
    unit_step: float | None = None,
) -> NDArray[np.float64]:
    """Draw ``x_t ~ p(x_t | u_t, x_{t-1})`` for every particle, Table 5.6.

    Parameters
    ----------
    poses : (N, 3) array_like
        Particle poses ``x_{t-1}`` (world frame).
    odom_prev, odom_cur : (3,) array_like
        The odometry reading ``u_t``.
    alphas : (alpha1, alpha2, alpha3, alpha4)
        Noise parameters as in :func:`motion_model_odometry`.
    rng : numpy.random.Generator
        Source of the ``(N, 3)`` standard normal draws.
    unit_step : float, optional
        Noise per step of this many metres: a longer step's variances are divided by its
        count of them (:func:`odometry_step_count`).

    Returns
    -------
    (N, 3) ndarray
        New poses, heading wrapped to ``[-pi, pi)``.
    """
    p = _poses(poses, "poses").reshape(-1, 3)
    r1, tr, r2 = (float(v) for v in odometry_deltas(odom_prev, odom_cur))
    sd1, sdt, sd2 = odometry_noise_std(r1, tr, r2, alphas, unit_step)
    e = rng.standard_normal((p.shape[0], 3))
    # The book's "sample(b^2)" draws with variance b^2: a standard normal scaled by sqrt(b^2).
    h1 = r1 - e[:, 0] * sd1
    htr = tr - e[:, 1] * sdt
    h2 = r2 - e[:, 2] * sd2
    out = np.empty_like(p)
    heading = p[:, 2] + h1
    out[:, 0] = p[:, 0] + htr * np.cos(heading)
    out[:, 1] = p[:, 1] + htr * np.sin(heading)
    out[:, 2] = wrap_angle(heading + h2)
    return out


def _velocity_arc(
    pose: NDArray[np.float64], v: NDArray[np.float64], w: NDArray[np.float64], dt: float
) -> NDArray[np.float64]:
    """Exact arc motion for velocities ``v`` (m/s) and ``w`` (rad/s), equation (5.9)."""
    x, y, th = pose[..., 0], pose[..., 1], pose[..., 2]
    small = np.abs(w) < 1e-9
    w_safe = np.where(small, 1.0, w)
    r = v / w_safe
    th_new = th + w * dt
    x_arc = x - r * np.sin(th) + r * np.sin(th_new)
    y_arc = y + r * np.cos(th) - r * np.cos(th_new)
    # Straight line limit of the arc when w -> 0.
    x_new = np.where(small, x + v * dt * np.cos(th), x_arc)
    y_new = np.where(small, y + v * dt * np.sin(th), y_arc)
    return np.stack([x_new, y_new, th_new], axis=-1)


# Docstring sections and particle-array check as in sample_motion_model_odometry (see there).
def sample_motion_model_velocity(
    poses: ArrayLike,
    control: ArrayLike,
    dt: float,
    alphas: tuple[float, float, float, float, float, float],
    rng: np.random.Generator,
) -> NDArray[np.float64]:
    """Draw new poses from the velocity motion model, Table 5.3.

    Parameters
    ----------
    poses : (N, 3) array_like
        Particle poses ``x_{t-1}`` (world frame).
    control : (2,) array_like
        ``(v, w)``: forward velocity (m/s) and rotational velocity (rad/s).
    dt : float
        Time step (s), positive.
    alphas : (alpha1, ..., alpha6)
        Noise variance factors; ``alpha5, alpha6`` set the final-rotation noise ``gamma``.
    rng : numpy.random.Generator
        Source of the ``(N, 3)`` standard normal draws.

    Returns
    -------
    (N, 3) ndarray
        New poses, heading wrapped to ``[-pi, pi)``.
    """
    p = _poses(poses, "poses").reshape(-1, 3)
    u = np.asarray(control, dtype=np.float64)
    if u.shape != (2,) or not np.all(np.isfinite(u)):
        raise ValueError(f"control must be a finite (v, w) pair, got {u!r}")
    if not dt > 0:
        raise ValueError(f"dt must be positive, got {dt}")
    a1, a2, a3, a4, a5, a6 = alphas
    v, w = float(u[0]), float(u[1])
    e = rng.standard_normal((p.shape[0], 3))
    vh = v + e[:, 0] * np.sqrt(a1 * v * v + a2 * w * w)
    wh = w + e[:, 1] * np.sqrt(a3 * v * v + a4 * w * w)
    gh = e[:, 2] * np.sqrt(a5 * v * v + a6 * w * w)
    out = _velocity_arc(p, vh, wh, dt)
    out[:, 2] = wrap_angle(out[:, 2] + gh * dt)
    return out


def motion_model_velocity(
    pose_new: ArrayLike,
    control: ArrayLike,
    dt: float,
    pose_old: ArrayLike,
    alphas: tuple[float, float, float, float, float, float],
) -> NDArray[np.float64]:
    """Density ``p(x_t | u_t, x_{t-1})`` of the velocity motion model, Table 5.1.

    Recovers the circle through both poses (centre ``(x*, y*)``, radius ``r*``), the implied
    velocities ``vhat, what`` and final rotation ``gammahat``, and scores them under the
    three zero-mean normals of the model.

    Parameters
    ----------
    pose_new, pose_old : (3,) or (N, 3) array_like
        Poses ``x_t`` and ``x_{t-1}`` (world frame).
    control : (2,) array_like
        ``(v, w)`` in m/s and rad/s.
    dt : float
        Time step (s).
    alphas : (alpha1, ..., alpha6)
        Noise parameters as in :func:`sample_motion_model_velocity`.

    Returns
    -------
    ndarray, shape () or (N,)
        Density in the velocity parameters (units 1 / (m/s * (rad/s)^2)), as in the book.
    """
    a = _poses(pose_old, "pose_old")
    b = _poses(pose_new, "pose_new")
    u = np.asarray(control, dtype=np.float64)
    a1, a2, a3, a4, a5, a6 = alphas
    v, w = float(u[0]), float(u[1])
    x, y, th = a[..., 0], a[..., 1], a[..., 2]
    xp, yp, thp = b[..., 0], b[..., 1], b[..., 2]
    num = (x - xp) * np.cos(th) + (y - yp) * np.sin(th)
    den = (y - yp) * np.cos(th) - (x - xp) * np.sin(th)
    straight = np.abs(den) < 1e-12
    mu = np.where(straight, 0.0, 0.5 * num / np.where(straight, 1.0, den))
    xs = 0.5 * (x + xp) + mu * (y - yp)
    ys = 0.5 * (y + yp) + mu * (xp - x)
    dth = wrap_angle(np.arctan2(yp - ys, xp - xs) - np.arctan2(y - ys, x - xs))
    dist = np.hypot(xp - x, yp - y)
    # Straight motion: the circle degenerates; velocity is distance over time, along heading.
    forward = np.sign((xp - x) * np.cos(th) + (yp - y) * np.sin(th))
    wh = np.where(straight, 0.0, dth / dt)
    # The book's vhat = dth/dt * r* loses the sign when turning clockwise while driving
    # forwards; the signed radius (centre on the robot's left is positive) keeps it.
    r_signed = (ys - y) * np.cos(th) - (xs - x) * np.sin(th)
    vh = np.where(straight, forward * dist / dt, wh * r_signed)
    gh = wrap_angle(thp - th) / dt - wh
    p1 = _prob_normal(v - vh, a1 * v * v + a2 * w * w)
    p2 = _prob_normal(w - wh, a3 * v * v + a4 * w * w)
    p3 = _prob_normal(gh, a5 * v * v + a6 * w * w)
    return p1 * p2 * p3


# The class tier over the functions (as VelocityMotionModel): typed alpha fields, one line a
# method; the checks are _check_alphas.
@dataclass(frozen=True)
class OdometryMotionModel:
    """Odometry motion model (Tables 5.5 and 5.6) with noise parameters ``alpha1..alpha4``.

    Parameters
    ----------
    alpha1, alpha2, alpha3, alpha4 : float
        Variance factors: rotation from rotation (rad^2/rad^2), rotation from translation
        (rad^2/m^2), translation from translation (m^2/m^2), translation from rotation
        (m^2/rad^2).
    unit_step : float or None
        The alphas give the noise of a step this long (m); a longer step is as noisy as the
        chain of such steps it spans (:func:`odometry_step_count`). None: Table 5.6 as
        printed, whatever the step.
    """

    alpha1: float = 0.05
    alpha2: float = 0.05
    alpha3: float = 0.05
    alpha4: float = 0.05
    unit_step: float | None = None

    def __post_init__(self) -> None:
        _check_alphas(self.alphas, "OdometryMotionModel")
        u = self.unit_step
        if u is not None and not (math.isfinite(u) and u > 0):
            raise ValueError(f"OdometryMotionModel: unit_step must be None or > 0 m, got {u}")

    @property
    def alphas(self) -> tuple[float, float, float, float]:
        return (self.alpha1, self.alpha2, self.alpha3, self.alpha4)

    def sample(
        self,
        poses: ArrayLike,
        odom_prev: ArrayLike,
        odom_cur: ArrayLike,
        rng: np.random.Generator,
    ) -> NDArray[np.float64]:
        """Sample new particle poses, Table 5.6 (see :func:`sample_motion_model_odometry`)."""
        return sample_motion_model_odometry(
            poses, odom_prev, odom_cur, self.alphas, rng, self.unit_step
        )

    def probability(
        self, pose_new: ArrayLike, odom_prev: ArrayLike, odom_cur: ArrayLike, pose_old: ArrayLike
    ) -> NDArray[np.float64]:
        """Density of the motion, Table 5.5 (see :func:`motion_model_odometry`)."""
        return motion_model_odometry(
            pose_new, odom_prev, odom_cur, pose_old, self.alphas, self.unit_step
        )


# The class tier over the functions, as OdometryMotionModel (see there).
@dataclass(frozen=True)
class VelocityMotionModel:
    """Velocity motion model (Tables 5.1 and 5.3) with noise parameters ``alpha1..alpha6``."""

    alpha1: float = 0.05
    alpha2: float = 0.05
    alpha3: float = 0.05
    alpha4: float = 0.05
    alpha5: float = 0.01
    alpha6: float = 0.01

    def __post_init__(self) -> None:
        _check_alphas(self.alphas, "VelocityMotionModel")

    @property
    def alphas(self) -> tuple[float, float, float, float, float, float]:
        return (self.alpha1, self.alpha2, self.alpha3, self.alpha4, self.alpha5, self.alpha6)

    def sample(
        self, poses: ArrayLike, control: ArrayLike, dt: float, rng: np.random.Generator
    ) -> NDArray[np.float64]:
        """Sample new particle poses, Table 5.3 (see :func:`sample_motion_model_velocity`)."""
        return sample_motion_model_velocity(poses, control, dt, self.alphas, rng)

    def probability(
        self, pose_new: ArrayLike, control: ArrayLike, dt: float, pose_old: ArrayLike
    ) -> NDArray[np.float64]:
        """Density of the motion, Table 5.1 (see :func:`motion_model_velocity`)."""
        return motion_model_velocity(pose_new, control, dt, pose_old, self.alphas)
