"""A seeded world of point landmarks and a robot driving a loop through it, with ground truth.

Landmarks are scattered uniformly in a square; the robot (unicycle, :class:`VelocityModel`) drives
a closed loop around the centre. Executed controls are the commanded ones plus Gaussian noise drawn
from the motion model's ``control_covariance``, so an estimator that uses the same models sees
exactly the noise it assumes. Observations are range/bearing within ``max_range`` and the field of
view, found with a KD-tree (``scipy.spatial.cKDTree``), so worlds of 100,000 landmarks stay fast.

This module returns plain arrays (:class:`LandmarkWorld`); the dataset of the same run, a
sequence of landmark records that the SLAM pipelines read like any logged dataset, is
:func:`probmap.datasets.simulation.simulate_landmarks`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from probmap._typing import FloatArray, IntArray
from probmap.geometry.se2 import wrap_angle
from probmap.models.measurement import RangeBearingModel
from probmap.models.motion import VelocityModel

__all__ = ["LandmarkWorld", "simulate_landmark_world"]


@dataclass(frozen=True, eq=False)
class LandmarkWorld:
    """Point landmarks and a robot run through them: controls, observations and the truth.

    Step ``t`` (0-based) applies ``controls[t]`` for ``dt`` seconds, reaching ``poses[t + 1]`` at
    time ``(t + 1) dt``, then observes ``z[t]``.

    Attributes
    ----------
    landmarks : ndarray, shape (n, 2)
        True landmark positions (m); the id of landmark ``i`` is ``i``.
    poses : ndarray, shape (T + 1, 3)
        True poses ``(x, y, theta)`` (m, rad), starting with the initial pose.
    controls : ndarray, shape (T, 2)
        Commanded controls ``(v, w)`` (m/s, rad/s); the executed ones carry noise.
    z : tuple of ndarray, shape (k_t, 2) each
        Observations ``(range m, bearing rad)`` in the sensor frame after each step.
    ids : tuple of ndarray of int64, shape (k_t,) each
        The true landmark of each observation.
    dt : float
        Step length (s).
    motion_model : VelocityModel
    measurement_model : RangeBearingModel
        The models the controls and observations were drawn from.
    """

    landmarks: FloatArray
    poses: FloatArray
    controls: FloatArray
    z: tuple[FloatArray, ...]
    ids: tuple[IntArray, ...]
    dt: float
    motion_model: VelocityModel
    measurement_model: RangeBearingModel


def simulate_landmark_world(
    n_landmarks: int,
    n_steps: int,
    *,
    seed: int,
    dt: float = 0.1,
    speed: float = 1.0,
    density: float = 0.03,
    max_range: float = 10.0,
    fov: float = np.pi,
    motion_model: VelocityModel | None = None,
    measurement_model: RangeBearingModel | None = None,
    loop_radius: float | None = None,
) -> LandmarkWorld:
    """Simulate a robot driving a loop through a world of point landmarks.

    Parameters
    ----------
    n_landmarks : int
        Number of landmarks (>= 1, up to ~100,000 and beyond).
    n_steps : int
        Number of motion steps (each followed by an observation batch).
    seed : int
        Seed of the random generator; equal seeds give equal worlds.
    dt : float
        Step length (s).
    speed : float
        Commanded forward speed (m/s).
    density : float
        Landmarks per square metre; the world is a square of side ``sqrt(n / density)``.
    max_range : float
        Sensor range (m).
    fov : float
        Field of view (rad), centred on the sensor heading.
    motion_model, measurement_model
        Defaults: ``VelocityModel()`` and ``RangeBearingModel()``.
    loop_radius : float, optional
        Radius (m) of the driven circle; default a third of the world's side (at least 3 m).

    Returns
    -------
    LandmarkWorld

    Examples
    --------
    >>> world = simulate_landmark_world(50, 20, seed=0)
    >>> world.poses.shape, world.controls.shape, len(world.z)
    ((21, 3), (20, 2), 20)
    """
    if n_landmarks < 1 or n_steps < 1:
        raise ValueError("n_landmarks and n_steps must be >= 1")
    if not (dt > 0 and density > 0 and max_range > 0 and 0 < fov <= 2 * np.pi):
        raise ValueError("dt, density and max_range must be > 0 and fov in (0, 2 pi]")
    from scipy.spatial import cKDTree

    motion = motion_model if motion_model is not None else VelocityModel()
    sensor = measurement_model if measurement_model is not None else RangeBearingModel()
    rng = np.random.default_rng(seed)
    side = float(np.sqrt(n_landmarks / density))
    radius = loop_radius if loop_radius is not None else max(side / 3.0, 3.0)
    lm = rng.uniform(-side / 2, side / 2, size=(n_landmarks, 2))
    tree = cKDTree(lm)
    u_cmd = np.array([speed, speed / radius])
    pose = np.array([radius, 0.0, np.pi / 2])  # on the circle, heading tangent (CCW)
    poses = [pose]
    observations: list[FloatArray] = []
    identities: list[IntArray] = []
    R_chol = np.linalg.cholesky(sensor.R)
    off = sensor.sensor_offset
    for _ in range(n_steps):
        M = motion.control_covariance(u_cmd, dt)
        u_exec = u_cmd + np.linalg.cholesky(M) @ rng.standard_normal(2)
        pose, _, _ = motion.predict(pose, u_exec, dt)
        poses.append(pose)
        c, s = np.cos(pose[2]), np.sin(pose[2])
        spos = pose[:2] + np.array([c * off[0] - s * off[1], s * off[0] + c * off[1]])
        cand = np.asarray(tree.query_ball_point(spos, max_range), dtype=np.int64)
        cand.sort()
        if cand.size:
            d = lm[cand] - spos
            rng_ = np.hypot(d[:, 0], d[:, 1])
            bear = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - pose[2] - off[2])
            keep = (np.abs(bear) <= fov / 2) & (rng_ > 1e-6)
            cand = cand[keep]
            z = np.stack([rng_[keep], bear[keep]], -1)
            z = z + rng.standard_normal(z.shape) @ R_chol.T
            z[:, 1] = wrap_angle(z[:, 1])
        else:
            z = np.zeros((0, 2))
        observations.append(z)
        identities.append(cand)
    return LandmarkWorld(
        landmarks=lm,
        poses=np.array(poses),
        controls=np.tile(u_cmd, (n_steps, 1)),
        z=tuple(observations),
        ids=tuple(identities),
        dt=dt,
        motion_model=motion,
        measurement_model=sensor,
    )
