"""EKF SLAM's two tiers: the array functions of Table 10.1 driven by hand against the
:class:`EKFSLAM` class, step by step on a seeded simulation (they must agree exactly)."""

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from probmap.datasets.simulation import simulate_landmarks
from probmap.slam.landmark.ekf import (
    EKFSLAM,
    ekf_slam_augment,
    ekf_slam_correct,
    ekf_slam_innovation_covariances,
    ekf_slam_predict,
    landmark_covariances,
)


@pytest.fixture(autouse=True)
def _one_blas_thread():
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def _function_tier_step(state, motion, sensor, u, dt, z, ids, symmetrize_every=50):
    """One predict + known-correspondence update with the function tier only."""
    mu, P, slot = state["mu"], state["P"], state["slot"]
    if dt != 0.0:
        u = np.asarray(u, dtype=np.float64)
        x_new, G, V = motion.predict(mu[:3], u, dt)
        M = motion.control_covariance(u, dt)
        mu, P = ekf_slam_predict(mu, P, x_new, G, V @ M @ V.T)
    z = np.asarray(z, dtype=np.float64).reshape(-1, 2)
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    keep = z[:, 0] > 1e-9
    z, ids = z[keep], ids[keep]
    rows, slots, new_rows, new_ids = [], [], [], []
    for i, j in enumerate(ids):
        if int(j) in slot:
            rows.append(i)
            slots.append(slot[int(j)])
        elif int(j) not in new_ids:
            new_rows.append(i)
            new_ids.append(int(j))
    nis = np.nan
    if rows:
        sl = np.asarray(slots, dtype=np.int64)
        z_hat, H_x, H_m = sensor.predict_many(mu[:3], mu[3:].reshape(-1, 2)[sl])
        mu, P, nis = ekf_slam_correct(mu, P, z[rows], sl, z_hat, H_x, H_m, sensor.R)
        state["n_updates"] += 1
        if state["n_updates"] % symmetrize_every == 0:
            P = np.ascontiguousarray(0.5 * (P + P.T))
    if new_rows:
        k = len(new_rows)
        xy, Jx, Jz = np.empty((k, 2)), np.empty((k, 2, 3)), np.empty((k, 2, 2))
        for r, i in enumerate(new_rows):
            xy[r], Jx[r], Jz[r] = sensor.inverse(mu[:3], z[i])
        for j in new_ids:
            slot[j] = len(slot)
        mu, P = ekf_slam_augment(mu, P, xy, Jx, Jz, sensor.R)
    state.update(mu=mu, P=P, nis=nis)


@pytest.mark.parametrize("seed", [3, 11])
def test_functions_and_class_agree_step_by_step(seed):
    sim = simulate_landmarks(30, 200, seed=seed, density=0.08)
    ekf = EKFSLAM(sim.motion_model, sim.measurement_model, sim.initial_pose, sim.initial_covariance)
    P0 = np.asarray(sim.initial_covariance, dtype=np.float64)
    state = {
        "mu": np.array(sim.initial_pose, dtype=np.float64),
        "P": np.array(0.5 * (P0 + P0.T), order="C"),
        "slot": {},
        "n_updates": 0,
    }
    fused = 0
    for step in sim:
        ekf.predict(step.control, step.dt)
        ekf.update(step.z, step.ids)
        _function_tier_step(
            state, sim.motion_model, sim.measurement_model, step.control, step.dt, step.z, step.ids
        )
        assert np.array_equal(ekf.mean, state["mu"])
        assert np.array_equal(ekf.covariance, state["P"])
        if np.isnan(state["nis"]):
            assert np.isnan(ekf.last_nis)
        else:
            fused += 1
            assert ekf.last_nis == state["nis"]
        ids, xy, cov = ekf.landmarks()
        slots = np.array([state["slot"][int(i)] for i in ids], dtype=np.int64)
        assert np.array_equal(xy, state["mu"][3:].reshape(-1, 2)[slots])
        assert np.array_equal(cov, landmark_covariances(state["P"], slots))
    assert fused > 100 and ekf.n_landmarks == len(state["slot"]) > 10


def test_innovation_covariances_match_dense_jacobian():
    rng = np.random.default_rng(0)
    n, N = 4, 11
    A = rng.normal(size=(N, N))
    P = A @ A.T + N * np.eye(N)
    slots = np.array([2, 0, 3])
    H_x, H_m = rng.normal(size=(3, 2, 3)), rng.normal(size=(3, 2, 2))
    R = np.diag([0.01, 0.002])
    S = ekf_slam_innovation_covariances(P, slots, H_x, H_m, R)
    assert S.shape == (3, 2, 2) and N == 3 + 2 * n
    for i, s in enumerate(slots):
        H = np.zeros((2, N))
        H[:, :3] = H_x[i]
        H[:, 3 + 2 * s : 5 + 2 * s] = H_m[i]
        assert np.allclose(S[i], H @ P @ H.T + R, rtol=1e-12, atol=1e-12)


def test_predict_only_touches_robot_rows_and_columns():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(9, 9))
    P = A @ A.T
    mu = rng.normal(size=9)
    G = np.eye(3) + 0.1 * rng.normal(size=(3, 3))
    Q = np.diag([0.01, 0.01, 0.001])
    mu2, P2 = ekf_slam_predict(mu.copy(), P.copy(), np.array([1.0, 2.0, 0.5]), G, Q)
    F = np.eye(9)
    F[:3, :3] = G
    Qf = np.zeros((9, 9))
    Qf[:3, :3] = Q
    assert np.allclose(P2, F @ P @ F.T + Qf, rtol=1e-12, atol=1e-12)
    assert np.array_equal(mu2[:3], [1.0, 2.0, 0.5]) and np.array_equal(mu2[3:], mu[3:])
    assert np.array_equal(P2[3:, 3:], P[3:, 3:])
