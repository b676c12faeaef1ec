"""EKF SLAM against a dense textbook reference, plus consistency and association checks."""

import numpy as np
import pytest
from scipy.stats import chi2
from threadpoolctl import threadpool_limits

from probmap.datasets.simulation import simulate_landmarks
from probmap.geometry.se2 import wrap_angle
from probmap.models.measurement import RangeBearingModel
from probmap.models.motion import VelocityModel
from probmap.slam.landmark.association import (
    NEW,
    REJECTED,
    associate_ml,
    chi2_gate,
    mahalanobis_squared,
)
from probmap.slam.landmark.base import LandmarkSLAM
from probmap.slam.landmark.ekf import EKFSLAM, EKFConfig, build_ekf


class DenseReferenceEKF:
    """Obviously-correct EKF SLAM: full (3+2n) Jacobians F_x^T G F_x, full H, explicit Joseph form.

    Known correspondences only; landmarks are added the same way as in EKFSLAM (inverse model with
    full cross-covariance), so the two must agree to rounding.
    """

    def __init__(self, motion, sensor, pose, cov):
        self.motion, self.sensor = motion, sensor
        self.mu = np.array(pose, float)
        self.P = np.array(cov, float)
        self.slot = {}

    def predict(self, u, dt):
        if dt == 0:
            return
        N = self.mu.size
        x_new, G, V = self.motion.predict(self.mu[:3], u, dt)
        Fx = np.zeros((3, N))
        Fx[:, :3] = np.eye(3)
        G_full = np.eye(N) + Fx.T @ (G - np.eye(3)) @ Fx
        Q = V @ self.motion.control_covariance(u, dt) @ V.T
        self.mu[:3] = x_new
        self.P = G_full @ self.P @ G_full.T + Fx.T @ Q @ Fx

    def update(self, z, ids):
        R = self.sensor.R
        rows = []
        for i, j in enumerate(ids):
            if int(j) in self.slot:
                rows.append(i)
        new = [i for i, j in enumerate(ids) if int(j) not in self.slot]
        if rows:
            N = self.mu.size
            k = len(rows)
            H = np.zeros((2 * k, N))
            nu = np.zeros(2 * k)
            for r, i in enumerate(rows):
                s = self.slot[int(ids[i])]
                c = 3 + 2 * s
                zh, Hx, Hm = self.sensor.predict(self.mu[:3], self.mu[c : c + 2])
                H[2 * r : 2 * r + 2, :3] = Hx
                H[2 * r : 2 * r + 2, c : c + 2] = Hm
                nu[2 * r : 2 * r + 2] = [z[i][0] - zh[0], wrap_angle(z[i][1] - zh[1])]
            Rb = np.kron(np.eye(k), R)
            S = H @ self.P @ H.T + Rb
            K = self.P @ H.T @ np.linalg.inv(S)
            self.mu = self.mu + K @ nu
            self.mu[2] = wrap_angle(self.mu[2])
            I_KH = np.eye(N) - K @ H
            self.P = I_KH @ self.P @ I_KH.T + K @ Rb @ K.T
        for i in new:
            lm, Jx, Jz = self.sensor.inverse(self.mu[:3], z[i])
            N = self.mu.size
            P = np.zeros((N + 2, N + 2))
            P[:N, :N] = self.P
            P[N:, :N] = Jx @ self.P[:3, :]
            P[:N, N:] = P[N:, :N].T
            P[N:, N:] = Jx @ self.P[:3, :3] @ Jx.T + Jz @ R @ Jz.T
            self.P = P
            self.mu = np.concatenate([self.mu, lm])
            self.slot[int(ids[i])] = len(self.slot)


@pytest.fixture(autouse=True)
def _one_blas_thread():
    # small dense updates: BLAS threads only add start-up cost (see BENCHMARKS.md)
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def make(sim, config=None):
    # build_ekf, the dataset's EKF, is what the tests below check against their oracles
    return build_ekf(sim, config)


def test_build_ekf_is_the_constructor_on_the_datasets_models():
    sim = simulate_landmarks(10, 20, seed=5, density=0.08)
    cfg = EKFConfig(visibility_range=10.0)
    built = build_ekf(sim, cfg)
    direct = EKFSLAM(
        sim.motion_model, sim.measurement_model, sim.initial_pose, sim.initial_covariance, cfg
    )
    assert built.config is cfg and built.motion_model is sim.motion_model
    for step in sim:
        for ekf in (built, direct):
            ekf.predict(step.control, step.dt)
            ekf.update(step.z, step.ids)
    assert np.array_equal(built.mean, direct.mean)
    assert np.array_equal(built.covariance, direct.covariance)


def test_matches_dense_reference():
    sim = simulate_landmarks(30, 120, seed=3, density=0.08)
    ekf = make(sim)
    ref = DenseReferenceEKF(
        sim.motion_model, sim.measurement_model, sim.initial_pose, sim.initial_covariance
    )
    assert isinstance(ekf, LandmarkSLAM)
    for step in sim:
        ekf.predict(step.control, step.dt)
        ref.predict(step.control, step.dt)
        # new landmarks of a step are added in order of appearance in both filters
        ekf.update(step.z, step.ids)
        ref.update(step.z, step.ids)
        order = np.argsort([ref.slot[i] for i in ekf._ids])
        assert np.array_equal(order, np.arange(order.size))
        assert np.allclose(ekf.mean, ref.mu, atol=1e-8)
        assert np.allclose(ekf.covariance, ref.P, atol=1e-10)
    P = ekf.covariance
    assert np.array_equal(P, P.T) or np.abs(P - P.T).max() < 1e-14
    assert np.linalg.eigvalsh(P).min() > 0


def test_anees_within_chi2_bounds_50_runs():
    runs, steps = 50, 150
    nees = np.zeros((runs, steps))
    for r in range(runs):
        sim = simulate_landmarks(25, steps, seed=100 + r, density=0.06)
        ekf = make(sim)
        for t, step in enumerate(sim):
            ekf.predict(step.control, step.dt)
            ekf.update(step.z, step.ids)
            e = ekf.pose - step.gt_pose
            e[2] = wrap_angle(e[2])
            nees[r, t] = e @ np.linalg.solve(ekf.pose_covariance, e)
    anees_t = nees.mean(axis=0)
    lo, hi = chi2.ppf([0.025, 0.975], 3 * runs) / runs
    assert lo < anees_t.mean() < hi, anees_t.mean()
    # no time step is grossly inconsistent (EKF SLAM drifts slightly overconfident over time)
    assert anees_t.max() < 2 * hi


def test_unknown_correspondences_recover_map():
    sim = simulate_landmarks(40, 400, seed=7, density=0.05, known_correspondences=False)
    ekf = make(sim, config=EKFConfig(visibility_range=10.0, visibility_fov=np.pi))
    for step in sim:
        ekf.predict(step.control, step.dt)
        ekf.update(step.z, step.ids)
    ids, xy, cov = ekf.landmarks()
    truth = sim.landmarks_xy
    d = np.linalg.norm(xy[:, None, :] - truth[None, :, :], axis=2).min(axis=1)
    assert np.all(d < 0.5)  # every mapped landmark is a real one
    assert (
        abs(
            len(ids)
            - len(set(np.argmin(np.linalg.norm(xy[:, None, :] - truth[None], axis=2), axis=1)))
        )
        == 0
    )  # no duplicates
    assert np.all(cov[:, 0, 0] > 0)


def test_spurious_provisional_landmarks_removed():
    motion = VelocityModel()
    sensor = RangeBearingModel()
    ekf = EKFSLAM(
        motion,
        sensor,
        np.zeros(3),
        np.eye(3) * 1e-6,
        EKFConfig(accept_hits=3, max_misses=2, visibility_range=20.0),
    )
    ekf.update([[5.0, 0.3]], [-1])  # a clutter detection, never seen again
    assert ekf.n_landmarks == 1 and len(ekf.landmarks()[0]) == 0
    for _ in range(3):
        ekf.predict([0.0, 0.0], 0.1)
        ekf.update(np.zeros((0, 2)), np.zeros(0, dtype=np.int64))  # no scan: no miss
    assert ekf.n_landmarks == 1
    for _ in range(3):
        ekf.update([[5.0, -0.3]], [-1])  # scans that see another landmark only
    assert ekf.n_landmarks == 1 and ekf.landmarks()[1][0][1] < 0
    assert len(ekf.landmarks()[0]) == 1  # the real one, seen repeatedly, is confirmed


def test_bad_measurements_raise_cleanly():
    sim = simulate_landmarks(10, 5, seed=0)
    ekf = make(sim)
    with pytest.raises(ValueError, match="finite"):
        ekf.update([[np.nan, 0.1]], [0])
    with pytest.raises(ValueError, match="rows"):
        ekf.update([[1.0, 0.1]], [0, 1])


def test_association_helpers():
    S = np.array([np.eye(2) * 0.01, np.eye(2) * 0.04])
    z_hat = np.array([[5.0, 0.0], [5.0, np.pi - 0.01]])
    z = np.array([[5.05, 0.0], [5.0, -np.pi + 0.01], [50.0, 1.0], [5.0, 0.5]])
    D2 = mahalanobis_squared(z, z_hat, S)
    assert np.isclose(D2[0, 0], 0.25) and np.isclose(D2[1, 1], 0.0004 / 0.04)
    res = associate_ml(z, z_hat, S, gate=chi2_gate(0.99), new_gate=chi2_gate(0.9999))
    assert list(res.match[:3]) == [0, 1, NEW]
    # mutual exclusion: two observations of one landmark -> the closer one wins
    res = associate_ml(z[[0, 0]] + [[0, 0], [0.08, 0]], z_hat, S, gate=9.21, new_gate=20.0)
    assert res.match[0] == 0 and res.match[1] == REJECTED
    with pytest.raises(ValueError):
        chi2_gate(1.5)
