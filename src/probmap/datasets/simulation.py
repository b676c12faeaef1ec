"""Simulated landmark worlds as landmark datasets, for tests, ``probmap slam`` and benchmarks.

The world itself (landmarks, the driven loop, noisy controls and observations) is
:func:`probmap.sim.landmarks.simulate_landmark_world`; this module presents a run as a
:class:`~probmap.datasets.landmarks.LandmarkSequence` of :class:`LandmarkStep` records, so that
the SLAM pipelines read it like any logged dataset, and keeps the true landmark array beside it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from probmap._typing import FloatArray
from probmap.datasets.landmarks import LandmarkSequence, LandmarkStep
from probmap.sim.landmarks import simulate_landmark_world

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
    known_correspondences: bool = True,
    **world: Any,
) -> LandmarkSimulation:
    """A run of :func:`probmap.sim.landmarks.simulate_landmark_world` as a landmark dataset.

    Parameters
    ----------
    n_landmarks, n_steps, seed
        The world's size, the run's length and the seed, as
        :func:`~probmap.sim.landmarks.simulate_landmark_world`; equal seeds give equal datasets.
    known_correspondences : bool
        If False, every observation id is -1 (the data association is left to the estimator).
    **world
        The other options of :func:`~probmap.sim.landmarks.simulate_landmark_world` (``dt``,
        ``speed``, ``density``, ``max_range``, ``fov``, ``motion_model``,
        ``measurement_model``, ``loop_radius``), passed on unchanged.

    Returns
    -------
    LandmarkSimulation
        One :class:`LandmarkStep` per motion step (its ground-truth pose included); starts at
        the true initial pose with ``initial_covariance`` tiny, as in Table 10.1.
    """
    run = simulate_landmark_world(n_landmarks, n_steps, seed=seed, **world)
    dt = run.dt
    steps = [
        LandmarkStep(
            time=(t + 1) * dt,
            dt=dt,
            control=run.controls[t].copy(),
            z=run.z[t],
            ids=run.ids[t]
            if known_correspondences
            else np.full(run.ids[t].size, -1, dtype=np.int64),
            gt_pose=run.poses[t + 1],
        )
        for t in range(n_steps)
    ]
    lm = run.landmarks
    gt = np.column_stack([np.arange(n_steps + 1) * dt, run.poses])
    return LandmarkSimulation(
        name=f"simulation-{n_landmarks}x{n_steps}-seed{seed}",
        steps=steps,
        motion_model=run.motion_model,
        measurement_model=run.measurement_model,
        initial_pose=run.poses[0].copy(),
        initial_covariance=np.diag([1e-9, 1e-9, 1e-9]),
        landmark_truth={i: lm[i] for i in range(n_landmarks)},
        gt_trajectory=gt,
        gps=None,
        landmarks_xy=lm,
        true_poses=run.poses,
    )
