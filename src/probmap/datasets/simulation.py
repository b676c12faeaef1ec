"""Seeded simulator of landmark worlds with ground truth, for tests and scaling benchmarks.

Landmarks are scattered uniformly in a square; the robot (unicycle, :class:`VelocityModel`) drives
a closed loop around the centre. Executed controls are the commanded ones plus Gaussian noise drawn
from the motion model's ``control_covariance``, so an estimator that uses the same models sees
exactly the noise it assumes. Observations are range/bearing within ``max_range`` and the field of
view, found with a KD-tree (``scipy.spatial.cKDTree``), so worlds of 100,000 landmarks stay fast.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from probmap._typing import FloatArray
from probmap.datasets.landmarks import LandmarkSequence, LandmarkStep
from probmap.geometry.se2 import wrap_angle
from probmap.models.measurement import RangeBearingModel
from probmap.models.motion import VelocityModel

__all__ = ["LandmarkSimulation", "simulate_landmarks"]


@dataclass(eq=False)
class LandmarkSimulation(LandmarkSequence):
    """A simulated landmark dataset (a :class:`LandmarkSequence`) with its true landmark array.

    Attributes
    ----------
    landmarks_xy : ndarray, shape (n, 2)
        True landmark positions; the id of landmark ``i`` is ``i``.
    true_poses : ndarray, shape (T + 1, 3)
        True poses, starting with the initial pose.
    """

    landmarks_xy: FloatArray | None = None
    true_poses: FloatArray | None = None


def simulate_landmarks(
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
    known_correspondences: bool = True,
    loop_radius: float | None = None,
) -> LandmarkSimulation:
    """Simulate a robot driving a loop through a world of point landmarks.

    Parameters
    ----------
    n_landmarks : int
        Number of landmarks (>= 1, up to ~100,000 and beyond).
    n_steps : int
        Number of motion steps (each followed by an observation batch).
    seed : int
        Seed of the random generator; equal seeds give equal datasets.
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
    known_correspondences : bool
        If False, every observation id is -1.
    loop_radius : float, optional
        Radius (m) of the driven circle; default a third of the world's side (at least 3 m).

    Returns
    -------
    LandmarkSimulation
        Starts at the true initial pose with ``initial_covariance`` tiny, as in Table 10.1.
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
    steps: list[LandmarkStep] = []
    R_chol = np.linalg.cholesky(sensor.R)
    off = sensor.sensor_offset
    for t in range(n_steps):
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
        ids = cand if known_correspondences else np.full(cand.size, -1, dtype=np.int64)
        steps.append(
            LandmarkStep(time=(t + 1) * dt, dt=dt, control=u_cmd.copy(), z=z, ids=ids, gt_pose=pose)
        )
    true_poses = np.array(poses)
    gt = np.column_stack([np.arange(n_steps + 1) * dt, true_poses])
    return LandmarkSimulation(
        name=f"simulation-{n_landmarks}x{n_steps}-seed{seed}",
        steps=steps,
        motion_model=motion,
        measurement_model=sensor,
        initial_pose=true_poses[0].copy(),
        initial_covariance=np.diag([1e-9, 1e-9, 1e-9]),
        landmark_truth={i: lm[i] for i in range(n_landmarks)},
        gt_trajectory=gt,
        gps=None,
        landmarks_xy=lm,
        true_poses=true_poses,
    )
