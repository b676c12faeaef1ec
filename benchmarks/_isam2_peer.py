"""GTSAM iSAM2 as a landmark-SLAM peer for the SEIF benchmarks (optional: ``pip install gtsam``).

The same data as the filters: each step adds the odometry factor of the velocity model's mean
motion (covariance ``V M V^T`` at the origin, plus 1e-6 on the diagonal because it is singular;
with 1e-9 GTSAM found the system indeterminate on 8 of 20 simulated runs) and
one bearing-range factor per observation, then runs one ``ISAM2.update``. New landmarks start at the
inverse measurement model from the current pose estimate. The robot pose after each step is the
current iSAM2 estimate (a smoother's latest pose, not a filter's).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np


def available() -> bool:
    """True when ``gtsam`` imports."""
    try:
        import gtsam  # noqa: F401
    except ImportError:
        return False
    return True


class ISAM2Peer:
    """Incremental smoothing and mapping over a :class:`LandmarkDataset`'s models."""

    def __init__(self, ds: Any) -> None:
        import gtsam

        self._g = gtsam
        self.motion = ds.motion_model
        self.sensor = ds.measurement_model
        if any(v != 0.0 for v in self.sensor.sensor_offset):
            raise ValueError("the iSAM2 peer assumes a sensor at the robot's origin")
        params = gtsam.ISAM2Params()
        self.isam = gtsam.ISAM2(params)
        self.k = 0
        self.pose = np.asarray(ds.initial_pose, dtype=np.float64).copy()
        R = np.asarray(self.sensor.R, dtype=np.float64)
        # BearingRangeFactor2D orders the measurement (bearing, range)
        self._meas_noise = gtsam.noiseModel.Gaussian.Covariance(
            np.array([[R[1, 1], R[1, 0]], [R[0, 1], R[0, 0]]])
        )
        self._seen: set[int] = set()
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        P0 = np.asarray(ds.initial_covariance, dtype=np.float64)
        graph.add(
            gtsam.PriorFactorPose2(
                self._x(0), gtsam.Pose2(*self.pose), gtsam.noiseModel.Gaussian.Covariance(P0)
            )
        )
        values.insert(self._x(0), gtsam.Pose2(*self.pose))
        self.isam.update(graph, values)

    def _x(self, k: int) -> int:
        return int(self._g.symbol("x", k))

    def _l(self, i: int) -> int:
        return int(self._g.symbol("l", i))

    def add_landmark_priors(self, ids: np.ndarray, xy: np.ndarray, sd: float) -> None:
        """Independent Gaussian priors on landmarks (a prior map), one update."""
        g = self._g
        graph = g.NonlinearFactorGraph()
        values = g.Values()
        noise = g.noiseModel.Isotropic.Sigma(2, sd)
        for i, p in zip(ids.tolist(), xy, strict=True):
            graph.add(g.PriorFactorPoint2(self._l(i), np.asarray(p, dtype=np.float64), noise))
            values.insert(self._l(i), np.asarray(p, dtype=np.float64))
            self._seen.add(int(i))
        self.isam.update(graph, values)

    def step(self, u: np.ndarray, dt: float, z: np.ndarray, ids: np.ndarray) -> None:
        """Odometry and observations of one step, then one iSAM2 update."""
        g = self._g
        rel, _, V = self.motion.predict(np.zeros(3), u, dt)
        Q = V @ self.motion.control_covariance(u, dt) @ V.T + 1e-6 * np.eye(3)
        graph = g.NonlinearFactorGraph()
        values = g.Values()
        k0, k1 = self._x(self.k), self._x(self.k + 1)
        odo = g.Pose2(*rel)
        graph.add(g.BetweenFactorPose2(k0, k1, odo, g.noiseModel.Gaussian.Covariance(Q)))
        guess = g.Pose2(*self.pose).compose(odo)
        values.insert(k1, guess)
        gx = np.array([guess.x(), guess.y(), guess.theta()])
        for (r, b), i in zip(z, ids.tolist(), strict=True):
            if r <= 1e-9:
                continue
            key = self._l(int(i))
            if int(i) not in self._seen:
                self._seen.add(int(i))
                xy = self.sensor.inverse(gx, np.array([r, b]))[0]
                values.insert(key, np.asarray(xy, dtype=np.float64))
            graph.add(
                g.BearingRangeFactor2D(
                    k1, key, g.Rot2.fromAngle(float(b)), float(r), self._meas_noise
                )
            )
        self.isam.update(graph, values)
        self.k += 1
        est = self.isam.calculateEstimatePose2(k1)
        self.pose = np.array([est.x(), est.y(), est.theta()])

    def landmarks(self) -> tuple[np.ndarray, np.ndarray]:
        """Ids and current estimates (n, 2) of the landmarks seen."""
        ids = np.array(sorted(self._seen), dtype=np.int64)
        est = self.isam.calculateEstimate()
        xy = np.array([est.atPoint2(self._l(int(i))) for i in ids]).reshape(-1, 2)
        return ids, xy


def time_steps(peer: ISAM2Peer, steps: list[Any]) -> np.ndarray:
    """Wall time (s) of each step (odometry + observations + update)."""
    out = np.empty(len(steps))
    clock = time.perf_counter
    for i, s in enumerate(steps):
        t0 = clock()
        peer.step(s.control, s.dt, s.z, s.ids)
        out[i] = clock() - t0
    return out
