"""SEIF SLAM: each table against the dense information-form equations, the unbounded filter
against our EKF (exact oracle), the bounded filter's sparsity, memory and accuracy."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from probmap.datasets.simulation import simulate_landmarks
from probmap.geometry.se2 import wrap_angle
from probmap.models.measurement import RangeBearingModel
from probmap.models.motion import VelocityModel
from probmap.slam.landmark.base import LandmarkSLAM
from probmap.slam.landmark.ekf import EKFSLAM
from probmap.slam.landmark.seif import (
    SeifConfig,
    SEIFSlam,
    SingularInformationError,
    build_seif,
)
from probmap.slam.landmark.seif_steps import (
    measurement_update_information,
    motion_update_information,
    robot_link_information,
    sparsify_information,
    update_mean_information,
)


def _spd(rng: np.random.Generator, d: int) -> np.ndarray:
    A = rng.standard_normal((d, d))
    return A @ A.T + d * np.eye(d)


def _ekf_and_seif(ds, **kw):
    ekf = EKFSLAM(ds.motion_model, ds.measurement_model, ds.initial_pose, ds.initial_covariance)
    seif = SEIFSlam(
        ds.motion_model, ds.measurement_model, ds.initial_pose, ds.initial_covariance, **kw
    )
    return ekf, seif


def _assert_spd(Omega: np.ndarray) -> None:
    assert np.allclose(Omega, Omega.T, atol=1e-9 * np.abs(Omega).max())
    np.linalg.cholesky(Omega)  # raises when not positive definite


def _slot_order(ekf: EKFSLAM, seif: SEIFSlam) -> np.ndarray:
    """Rows of the EKF state in SEIF slot order (both keyed by landmark id)."""
    ekf_slot = {int(i): s for s, i in enumerate(ekf._ids)}
    slots = [ekf_slot[int(i)] for i in seif.slot_ids()]
    return np.concatenate([np.arange(3), (3 + 2 * np.array(slots)[:, None] + np.arange(2)).ravel()])


# ----------------------------------------------------------------------------- Table 12.2
def test_motion_update_equals_ekf_prediction_in_information_form():
    rng = np.random.default_rng(0)
    d = 3 + 2 * 4
    Sigma = np.linalg.inv(_spd(rng, d))
    mu = rng.standard_normal(d)
    model = VelocityModel()
    u, dt = np.array([1.2, 0.4]), 0.5
    x_new, G, V = model.predict(mu[:3], u, dt)
    Q = V @ model.control_covariance(u, dt) @ V.T  # rank 2: Q^-1 does not exist
    Omega = np.linalg.inv(Sigma)
    xi = Omega @ mu
    delta = x_new - mu[:3]
    delta[2] = wrap_angle(delta[2])
    Omega_bar, xi_bar = motion_update_information(Omega, xi, mu, delta, G, Q)
    # EKF prediction (Table 10.1 lines 3-5) converted to information form
    Gf = np.eye(d)
    Gf[:3, :3] = G
    Sigma_bar = Gf @ Sigma @ Gf.T
    Sigma_bar[:3, :3] += Q
    mu_bar = mu.copy()
    mu_bar[:3] += delta
    assert np.allclose(Omega_bar, np.linalg.inv(Sigma_bar), rtol=1e-9, atol=1e-9)
    assert np.allclose(xi_bar, np.linalg.inv(Sigma_bar) @ mu_bar, rtol=1e-9, atol=1e-9)
    _assert_spd(Omega_bar)


def test_motion_update_matches_book_psi_lambda_phi_kappa_form():
    """Table 12.2 lines 5-11 written literally (needs an invertible Q, the book's R_t)."""
    rng = np.random.default_rng(1)
    d = 3 + 2 * 3
    Omega = _spd(rng, d)
    mu = rng.standard_normal(d)
    xi = Omega @ mu + 0.1 * rng.standard_normal(d)  # a stale mean: xi != Omega mu
    G = np.eye(3)
    G[0, 2], G[1, 2] = -0.3, 0.7
    Q = np.diag([0.01, 0.02, 0.003])
    delta = np.array([0.5, 0.2, 0.1])
    F = np.zeros((3, d))
    F[:, :3] = np.eye(3)
    Delta = G - np.eye(3)
    Psi = F.T @ (np.linalg.inv(np.eye(3) + Delta) - np.eye(3)) @ F
    lam = Psi.T @ Omega + Omega @ Psi + Psi.T @ Omega @ Psi
    Phi = Omega + lam
    kappa = Phi @ F.T @ np.linalg.inv(np.linalg.inv(Q) + F @ Phi @ F.T) @ F @ Phi
    Omega_ref = Phi - kappa
    xi_ref = xi + (lam - kappa) @ mu + Omega_ref @ F.T @ delta
    Omega_bar, xi_bar = motion_update_information(Omega, xi, mu, delta, G, Q)
    assert np.allclose(Omega_bar, Omega_ref, rtol=1e-10, atol=1e-10)
    assert np.allclose(xi_bar, xi_ref, rtol=1e-10, atol=1e-10)


# ----------------------------------------------------------------------------- Table 12.3
def test_measurement_update_equals_kalman_update():
    rng = np.random.default_rng(2)
    d = 3 + 2 * 3
    Omega = _spd(rng, d)
    Sigma = np.linalg.inv(Omega)
    mu = rng.uniform(-5, 5, d)
    sensor = RangeBearingModel()
    rows = [3, 7]
    lm = np.stack([mu[r : r + 2] for r in rows])
    z_hat, H_x, H_m = sensor.predict_many(mu[:3], lm)
    z = z_hat + np.array([[0.1, 0.02], [-0.05, -0.01]])
    nu = z - z_hat
    Omega_new, xi_new = measurement_update_information(
        Omega, Omega @ mu, mu, rows, H_x, H_m, nu, sensor.R
    )
    H = np.zeros((4, d))
    for i, r in enumerate(rows):
        H[2 * i : 2 * i + 2, :3] = H_x[i]
        H[2 * i : 2 * i + 2, r : r + 2] = H_m[i]
    Rb = np.kron(np.eye(2), sensor.R)
    K = Sigma @ H.T @ np.linalg.inv(H @ Sigma @ H.T + Rb)
    mu_ekf = mu + K @ nu.ravel()
    Sigma_ekf = (np.eye(d) - K @ H) @ Sigma
    assert np.allclose(np.linalg.inv(Omega_new), Sigma_ekf, atol=1e-10)
    assert np.allclose(np.linalg.solve(Omega_new, xi_new), mu_ekf, atol=1e-10)


# ----------------------------------------------------------------------------- Table 12.4
def _book_sparsification(Omega, xi, mu, x, mp, m0, ctx=None):
    """Table 12.4 with projection matrices over the full state (dense, slow, literal).

    ``ctx``: context landmarks, marginalised with ``m0`` in Omega1 and Omega2 (the
    ``context_hops`` extension); None or empty = the book's table.
    """
    d = Omega.shape[0]
    ctx = np.zeros(0, dtype=int) if ctx is None else ctx

    def F(idx):
        out = np.zeros((d, len(idx)))
        out[idx, np.arange(len(idx))] = 1.0
        return out

    Fx, Fall = F(x), F(np.concatenate([x, mp, m0, ctx]))
    Fc, Fxc = F(np.concatenate([m0, ctx])), F(np.concatenate([x, m0, ctx]))
    Omega0 = Fall @ Fall.T @ Omega @ Fall @ Fall.T
    Omega1 = Omega0 - Omega0 @ Fc @ np.linalg.inv(Fc.T @ Omega0 @ Fc) @ Fc.T @ Omega0
    Omega2 = Omega0 - Omega0 @ Fxc @ np.linalg.inv(Fxc.T @ Omega0 @ Fxc) @ Fxc.T @ Omega0
    Omega3 = Omega - Omega @ Fx @ np.linalg.inv(Fx.T @ Omega @ Fx) @ Fx.T @ Omega
    Omega_t = Omega1 - Omega2 + Omega3
    return Omega_t, xi + (Omega_t - Omega) @ mu


def test_sparsify_equals_dense_three_matrix_formula():
    rng = np.random.default_rng(3)
    # robot, 3 active (m+: 0..2, m0: the first of them), 3 passive (m-)
    n = 6
    d = 3 + 2 * n
    Omega = _spd(rng, d)
    passive = np.arange(3 + 2 * 3, d)
    Omega[np.ix_(np.arange(3), passive)] = 0.0  # the robot links only to active landmarks
    Omega[np.ix_(passive, np.arange(3))] = 0.0
    Omega += 5 * d * np.eye(d)
    mu = rng.standard_normal(d)
    xi = Omega @ mu
    x = np.arange(3)
    m0 = np.array([3, 4])
    mp = np.arange(5, 9)
    ref_O, ref_xi = _book_sparsification(Omega, xi, mu, x, mp, m0)
    # the function takes the robot's Markov blanket (x, m+, m0); m- links stay as they are
    loc = np.arange(9)
    O_l, xi_l = sparsify_information(Omega[np.ix_(loc, loc)], xi[loc], mu[loc], [3])
    assert np.allclose(O_l, ref_O[np.ix_(loc, loc)], atol=1e-9)
    assert np.allclose(xi_l, ref_xi[loc], atol=1e-9)
    assert np.allclose(ref_O[np.ix_(loc, passive)], Omega[np.ix_(loc, passive)])
    assert np.allclose(ref_O[np.ix_(passive, passive)], Omega[np.ix_(passive, passive)])
    assert np.allclose(ref_xi[passive], xi[passive])
    assert np.all(O_l[:3, 3:5] == 0.0)
    O_t = Omega.copy()
    O_t[np.ix_(loc, loc)] = O_l
    _assert_spd(O_t)


def test_class_sparsify_matches_book_formula_on_a_run():
    ds = simulate_landmarks(60, 60, seed=4, density=0.1)
    seif = build_seif(ds, SeifConfig(max_active=None))
    for step in ds:
        seif.predict(step.control, step.dt)
        seif.update(step.z, step.ids)
    active = list(seif._active)
    assert len(active) > 4
    Omega, xi, mu = seif.information_matrix(), seif.information_vector(), seif.mean_vector()
    seif.config = SeifConfig(max_active=3, deactivation="oldest")
    m0_slots = active[: len(active) - 3]
    seif.sparsify()
    rows = lambda slots: np.concatenate([3 + 2 * np.array(slots)[:, None] + np.arange(2)]).ravel()  # noqa: E731
    ref_O, ref_xi = _book_sparsification(
        Omega, xi, mu, np.arange(3), rows(active[len(active) - 3 :]), rows(m0_slots)
    )
    assert np.allclose(seif.information_matrix(), ref_O, atol=1e-6 * np.abs(Omega).max())
    assert np.allclose(seif.information_vector(), ref_xi, atol=1e-6 * np.abs(xi).max())
    assert set(seif.store.robot_links) == set(active[len(active) - 3 :])
    _assert_spd(seif.information_matrix())


def _blanket_system(seed: int, n_active: int, n_passive: int, ridge: float = 5.0):
    rng = np.random.default_rng(seed)
    d = 3 + 2 * (n_active + n_passive)
    Omega = _spd(rng, d)
    passive = np.arange(3 + 2 * n_active, d)
    Omega[np.ix_(np.arange(3), passive)] = 0.0  # the robot links only to active landmarks
    Omega[np.ix_(passive, np.arange(3))] = 0.0
    Omega += ridge * d * np.eye(d)
    np.linalg.cholesky(Omega)
    mu = rng.standard_normal(d)
    return Omega, Omega @ mu, mu


def test_sparsify_with_all_passive_as_context_keeps_exact_marginals():
    # context = every passive landmark: the result is p(m) p(x | m+), whose covariance over
    # (x, m+) and over the map is the posterior's (closed form); Table 12.4 (no context) is not
    Omega, xi, mu = _blanket_system(21, 4, 5, ridge=0.0)
    d = Omega.shape[0]
    Sigma = np.linalg.inv(Omega)
    xmp = np.r_[0:3, 5:11]  # robot and m+ (landmarks 1-3); m0 = landmark 0 (rows 3, 4)
    mapr = np.arange(3, d)
    O_t, xi_t = sparsify_information(Omega, xi, mu, [3], n_context=5)
    S_t = np.linalg.inv(O_t)
    assert np.all(O_t[:3, 3:5] == 0.0)
    assert np.allclose(S_t[np.ix_(xmp, xmp)], Sigma[np.ix_(xmp, xmp)], atol=1e-12)
    assert np.allclose(S_t[np.ix_(mapr, mapr)], Sigma[np.ix_(mapr, mapr)], atol=1e-12)
    assert np.allclose(np.linalg.solve(O_t, xi_t), mu, atol=1e-10)  # the mean is kept
    assert np.array_equal(O_t[11:, :], Omega[11:, :])  # context rows untouched
    _assert_spd(O_t)
    # the literal three-matrix formula with the context marginalised gives the same matrix
    ref_O, ref_xi = _book_sparsification(
        Omega, xi, mu, np.arange(3), np.arange(5, 11), np.array([3, 4]), np.arange(11, d)
    )
    assert np.allclose(O_t, ref_O, atol=1e-9)
    assert np.allclose(xi_t, ref_xi, atol=1e-9)
    # Table 12.4 takes the blanket only, conditioning on the passive landmarks: the robot's
    # marginal covariance shrinks (overconfidence)
    loc = np.arange(11)
    O_b = Omega.copy()
    O_b[np.ix_(loc, loc)] = sparsify_information(Omega[np.ix_(loc, loc)], xi[loc], mu[loc], [3])[0]
    S_b = np.linalg.inv(O_b)
    assert np.linalg.det(S_b[:3, :3]) < 0.999 * np.linalg.det(Sigma[:3, :3])
    assert np.abs(S_b[:3, :3] - Sigma[:3, :3]).max() > 1e-5


def test_sparsify_context_partial_equals_dense_formula_and_validates():
    Omega, xi, mu = _blanket_system(22, 5, 6)
    d = Omega.shape[0]
    # context = the first 3 passive landmarks; the last 3 are conditioned on (dropped)
    keep = np.arange(3 + 2 * 8)
    O_t, xi_t = sparsify_information(
        Omega[np.ix_(keep, keep)], xi[keep], mu[keep], [5, 9], n_context=3
    )
    ref_O, ref_xi = _book_sparsification(
        Omega[np.ix_(keep, keep)],
        xi[keep],
        mu[keep],
        np.arange(3),
        np.r_[3:5, 7:9, 11:13],
        np.r_[5:7, 9:11],
        np.arange(13, 19),
    )
    assert np.allclose(O_t, ref_O, atol=1e-9)
    assert np.allclose(xi_t, ref_xi, atol=1e-9)
    assert np.all(O_t[:3, 5:7] == 0.0) and np.all(O_t[:3, 9:11] == 0.0)
    with pytest.raises(ValueError, match="n_context"):
        sparsify_information(Omega, xi, mu, [3], n_context=d)
    with pytest.raises(ValueError, match="before the context"):
        sparsify_information(Omega, xi, mu, [d - 2], n_context=2)
    with pytest.raises(ValueError, match="context_hops"):
        SeifConfig(context_hops=-1)


def test_class_context_sparsify_matches_dense_formula_on_a_run():
    ds = simulate_landmarks(60, 80, seed=4, density=0.1)
    seif = build_seif(ds, SeifConfig(max_active=6))
    for step in ds:
        seif.predict(step.control, step.dt)
        seif.update(step.z, step.ids)
    seif.config = dataclasses.replace(seif.config, max_active=None)
    for step in list(ds)[:5]:  # grow the active set past 3 without sparsifying
        seif.predict(step.control, step.dt)
        seif.update(step.z, step.ids)
    active = list(seif._active)
    assert len(active) > 4
    Omega, xi, mu = seif.information_matrix(), seif.information_vector(), seif.mean_vector()
    rows = lambda slots: (3 + 2 * np.array(slots, dtype=int)[:, None] + np.arange(2)).ravel()  # noqa: E731
    # one hop: every passive landmark linked to an active one (from the dense matrix)
    link = np.abs(Omega[3:, 3:]).reshape(seif.n_landmarks, 2, seif.n_landmarks, 2).sum((1, 3))
    hop1 = sorted({int(t) for s in active for t in np.flatnonzero(link[s]) if t not in active})
    assert hop1, "the run should link active landmarks to passive ones"
    seif.config = SeifConfig(max_active=3, deactivation="oldest", context_hops=1)
    m0 = active[: len(active) - 3]
    seif.sparsify()
    ref_O, ref_xi = _book_sparsification(
        Omega, xi, mu, np.arange(3), rows(active[-3:]), rows(m0), rows(hop1)
    )
    assert np.allclose(seif.information_matrix(), ref_O, atol=1e-6 * np.abs(Omega).max())
    assert np.allclose(seif.information_vector(), ref_xi, atol=1e-6 * np.abs(xi).max())
    _assert_spd(seif.information_matrix())


# ----------------------------------------------------------------------------- Table 12.5
def test_coordinate_descent_converges_to_exact_mean():
    rng = np.random.default_rng(5)
    d = 3 + 2 * 5
    Omega = _spd(rng, d)
    xi = rng.standard_normal(d)
    exact = np.linalg.solve(Omega, xi)
    blocks = [0, 3, 5, 7, 9, 11]
    mu1 = update_mean_information(Omega, xi, np.zeros(d), blocks, sweeps=1)
    mu50 = update_mean_information(Omega, xi, np.zeros(d), blocks, sweeps=200)
    assert np.linalg.norm(mu50 - exact) < 1e-8
    assert np.linalg.norm(mu50 - exact) < np.linalg.norm(mu1 - exact)
    # one step leaves block 0 satisfying its own equation exactly
    mu = update_mean_information(Omega, xi, np.ones(d), [0], sweeps=1)
    assert np.allclose((Omega @ mu - xi)[:3], 0.0, atol=1e-12)


def test_local_mean_update_solves_the_active_rows():
    ds = simulate_landmarks(200, 120, seed=6, density=0.1)
    seif = build_seif(ds, SeifConfig(max_active=5, passive_sweeps=0))
    for step in ds:
        seif.predict(step.control, step.dt)
        seif.update(step.z, step.ids)
    Omega, xi, mu = seif.information_matrix(), seif.information_vector(), seif.mean_vector()
    r = Omega @ mu - xi
    act = np.concatenate([np.arange(3)] + [3 + 2 * s + np.arange(2) for s in seif._active])
    # sparsification after the solve keeps Omega mu - xi unchanged on those rows (xi~ update)
    assert np.abs(r[act]).max() < 1e-6 * np.abs(xi).max()


# ----------------------------------------------------------------------------- EKF oracle
@pytest.mark.parametrize("unbounded", [None, 1000])
def test_seif_without_sparsification_equals_ekf(unbounded):
    ds = simulate_landmarks(40, 150, seed=7, density=0.05)
    ekf, seif = _ekf_and_seif(ds, max_active=unbounded)
    assert isinstance(seif, LandmarkSLAM)
    for k, step in enumerate(ds):
        for f in (ekf, seif):
            f.predict(step.control, step.dt)
            f.update(step.z, step.ids)
        assert np.allclose(seif.pose, ekf.pose, atol=1e-6)
        if k % 30 == 0:
            _assert_spd(seif.information_matrix())
    assert seif.n_landmarks == ekf.n_landmarks > 10
    order = _slot_order(ekf, seif)
    mu = seif.recover_mean_exact()
    mu[2] = wrap_angle(mu[2])
    P = np.linalg.inv(seif.information_matrix())
    assert np.allclose(mu, ekf.mean[order], atol=1e-6)
    assert np.allclose(P, ekf.covariance[np.ix_(order, order)], atol=1e-6)
    assert np.allclose(seif.pose_covariance, ekf.pose_covariance, atol=1e-9)
    ids_e, xy_e, cov_e = ekf.landmarks()
    ids_s, xy_s, cov_s = seif.landmarks()
    oe, os_ = np.argsort(ids_e), np.argsort(ids_s)
    assert np.array_equal(ids_e[oe], ids_s[os_])
    assert np.allclose(xy_e[oe], xy_s[os_], atol=1e-6)
    assert np.allclose(cov_e[oe], cov_s[os_], atol=1e-6)


# ----------------------------------------------------------------------------- sparsity, memory
@pytest.mark.parametrize("context_hops", [0, 1, 3])
def test_active_set_bounded_and_every_step_spd(context_hops):
    ds = simulate_landmarks(300, 150, seed=8, density=0.1)
    seif = build_seif(ds, SeifConfig(max_active=4, context_hops=context_hops))
    for k, step in enumerate(ds):
        seif.predict(step.control, step.dt)
        seif.update(step.z, step.ids)
        assert len(seif.active_ids) <= 4
        assert set(seif.store.robot_links) <= set(seif._active)
        if k % 25 == 0:
            _assert_spd(seif.information_matrix())
    assert seif.n_landmarks > 20


def test_robot_link_information_matches_covariance_form():
    rng = np.random.default_rng(21)
    d = 3 + 2 * 5
    Omega = _spd(rng, d)
    Omega[:3, 7:9] = Omega[7:9, :3] = 0.0  # landmark 2 (rows 7-8) not linked to the robot
    Omega += 20 * np.eye(d)  # keep it positive definite after cutting the link
    rows = [3, 5, 7, 9, 11]
    got = robot_link_information(Omega, rows)
    for k, r in enumerate(rows):
        # conditioned on the rest, (x, m) has covariance inv(Omega_[x,m]); mutual information
        # from its covariance blocks: 1/2 log(det S_xx det S_mm / det S)
        idx = [0, 1, 2, r, r + 1]
        S = np.linalg.inv(Omega[np.ix_(idx, idx)])
        ref = 0.5 * (
            np.linalg.slogdet(S[:3, :3])[1]
            + np.linalg.slogdet(S[3:, 3:])[1]
            - np.linalg.slogdet(S)[1]
        )
        assert got[k] == pytest.approx(ref, rel=1e-9, abs=1e-12)
    assert got[2] == pytest.approx(0.0, abs=1e-12)
    assert np.all(got[[0, 1, 3, 4]] > 1e-6)


def test_weakest_deactivation_cuts_the_least_informative_links():
    ds = simulate_landmarks(300, 120, seed=8, density=0.1)
    seif = build_seif(ds, SeifConfig(max_active=30, deactivation="weakest"))
    for step in ds:
        seif.predict(step.control, step.dt)
        seif.update(step.z, step.ids)
    active = list(seif._active)
    assert len(active) > 8
    Omega = seif.information_matrix()
    score = robot_link_information(Omega, [3 + 2 * s for s in active])
    expected = {active[i] for i in np.argsort(score)[: len(active) - 5]}
    seif.config = dataclasses.replace(seif.config, max_active=5)
    seif.sparsify()
    assert set(seif._active) == set(active) - expected
    after = seif.information_matrix()
    for s in expected:
        assert np.all(after[:3, 3 + 2 * s : 5 + 2 * s] == 0.0)
    _assert_spd(after)


def _bytes_per_landmark(n_landmarks: int) -> tuple[float, int]:
    ds = simulate_landmarks(n_landmarks, 200, seed=9, density=0.05)
    seif = build_seif(ds, SeifConfig(max_active=6))
    for step in ds:
        seif.predict(step.control, step.dt)
        seif.update(step.z, step.ids)
    degree = max(len(a) for a in seif.store.adjacency)
    return seif.state_nbytes() / seif.n_landmarks, degree


def test_memory_per_landmark_constant():
    small, deg_small = _bytes_per_landmark(500)
    large, deg_large = _bytes_per_landmark(20000)
    # same trajectory density: the stored blocks per landmark do not grow with the world
    assert large < 1.5 * small
    assert max(deg_small, deg_large) < 60


# ----------------------------------------------------------------------------- accuracy, ANEES
# The accuracy tests below compare filters run over the same seeded worlds (150 landmarks, 600
# steps): each (filter, seed) run is made once per module and its per-step errors kept, so every
# test reads the same numbers it would compute on its own (the filters are deterministic).
_SEIF_KW: dict[str, dict[str, Any]] = {
    "seif": {},
    "context": {"context_hops": 1},
    "weakest": {"deactivation": "weakest"},
}


def _run_errors(f, ds, with_nees: bool) -> dict[str, np.ndarray]:
    """Run ``f`` over ``ds``: squared position error (m^2) per step, pose NEES per step (when
    asked; empty otherwise) and squared landmark error (m^2) per mapped landmark."""
    err, nees = [], []
    for step in ds:
        f.predict(step.control, step.dt)
        f.update(step.z, step.ids)
        e = f.pose - step.gt_pose
        e[2] = wrap_angle(e[2])
        err.append(e[0] ** 2 + e[1] ** 2)
        if with_nees:
            nees.append(e @ np.linalg.solve(f.pose_covariance, e))
    ids, xy, _ = f.landmarks()
    lm = np.sum((xy - ds.landmarks_xy[ids]) ** 2, axis=1)
    return {"err": np.array(err), "nees": np.array(nees), "lm": lm}


@pytest.fixture(scope="module")
def sim_runs():
    """``get(kind, seed) -> errors`` with kind ``ekf`` or one of ``_SEIF_KW`` (all at
    ``max_active = 10``), computed once per (kind, seed) for the whole module."""
    cache: dict[tuple[object, int], dict[str, np.ndarray]] = {}

    def get(kind: str, seed: int) -> dict[str, np.ndarray]:
        ds = simulate_landmarks(150, 600, seed=seed, density=0.05)
        ekf, seif = _ekf_and_seif(ds, max_active=10, **_SEIF_KW.get(kind, {}))
        # keyed by the SEIF's whole configuration: kinds that resolve to the same filter (the
        # default deactivation is "weakest") share one run
        key = ("ekf" if kind == "ekf" else seif.config, seed)
        if key not in cache:
            # NEES (the pose covariance each step) only where a test reads it: seeds 0-5
            cache[key] = _run_errors(ekf if kind == "ekf" else seif, ds, seed < 6)
        return cache[key]

    return get


def _run(r):
    """(robot RMSE m, landmark RMSE m, pose ANEES) of one run."""
    return np.sqrt(np.mean(r["err"])), np.sqrt(np.mean(r["lm"])), np.mean(r["nees"])


def _rmse(r):
    """(robot MSE m^2, landmark MSE m^2) of one run."""
    return np.mean(r["err"]), np.mean(r["lm"])


def test_seif_accuracy_beside_ekf_and_overconfidence(sim_runs):
    rob_e, rob_s, lm_e, lm_s, an_e, an_s = [], [], [], [], [], []
    for seed in range(3):
        r, lm, an = _run(sim_runs("ekf", seed))
        rob_e.append(r), lm_e.append(lm), an_e.append(an)
        r, lm, an = _run(sim_runs("seif", seed))
        rob_s.append(r), lm_s.append(lm), an_s.append(an)
    # the goal at max_active = 10: robot RMSE within 1.3x of the EKF's
    assert np.mean(rob_s) <= 1.3 * np.mean(rob_e)
    assert np.mean(lm_s) <= 1.5 * np.mean(lm_e)
    # EKF is near-consistent (ANEES ~ 3 for 3 dof); sparsification makes SEIF overconfident
    assert 1.5 < np.mean(an_e) < 6.0
    assert np.mean(an_s) > 2 * np.mean(an_e)


def test_context_sparsification_removes_most_overconfidence(sim_runs):
    # seeds 3-5: Table 12.4 at max_active = 10 is overconfident (pose ANEES 6.5-37 where the EKF
    # gives 1.9-4.7); marginalising the one-hop neighbours instead brings it near the EKF's
    an = np.zeros(3)
    for seed in (3, 4, 5):
        an += [_run(sim_runs(kind, seed))[2] for kind in ("ekf", "seif", "context")]
    an /= 3
    assert an[1] > 3 * an[0], an
    assert an[2] < 1.4 * an[0], an


def test_weakest_deactivation_within_1_3x_of_ekf_on_hard_seeds(sim_runs):
    # seeds 3-5 are those on which the least-recently-observed policy misses the goal (landmark
    # RMSE up to 3x on seed 3); pooled over them, weakest-link deactivation meets it
    mse = np.zeros((2, 2))
    for seed in (3, 4, 5):
        mse[0] += _rmse(sim_runs("ekf", seed))
        mse[1] += _rmse(sim_runs("weakest", seed))
    ratio = np.sqrt(mse[1] / mse[0])  # (robot, landmark), RMS over the three runs
    assert np.all(ratio <= 1.3), ratio


@pytest.mark.slow
@pytest.mark.parametrize(
    "kind, seeds", [("seif", tuple(range(10))), ("context", (3, 4, 5))], ids=["seif", "context"]
)
def test_monte_carlo_rmse_within_1_3x_of_ekf(sim_runs, kind, seeds):
    # the goal at max_active = 10, as the Monte Carlo RMSE over seeded runs (the mean
    # squared error over runs; single-run ratios scatter 0.4x-4x, BENCHMARKS.md). Table 12.4
    # (seif) over ten seeds: robot 1.22x, landmark 1.22x. The one-hop context (context_hops = 1;
    # each run costs 3-4 EKF runs) over the hard seeds 3-5, where the bound tells it from
    # Table 12.4 (context 1.07x / 0.81x; Table 12.4 1.18x / 1.43x fails), which ten seeds do not
    # (context 0.98x / 0.95x; Table 12.4 passes as well)
    mse = np.zeros((2, 2))
    for seed in seeds:
        mse[0] += _rmse(sim_runs("ekf", seed))
        mse[1] += _rmse(sim_runs(kind, seed))
    ratio = np.sqrt(mse[1] / mse[0])
    assert np.all(ratio <= 1.3), ratio
    assert np.all(ratio >= 0.7), ratio  # and not better than the exact filter by much


def test_unknown_correspondences_on_simulation():
    ds = simulate_landmarks(150, 250, seed=10, density=0.05, known_correspondences=False)
    truth = simulate_landmarks(150, 250, seed=10, density=0.05)
    seif = build_seif(ds, SeifConfig(max_active=10))
    err = []
    for step in ds:
        seif.predict(step.control, step.dt)
        seif.update(step.z, step.ids)
        err.append(np.hypot(*(seif.pose[:2] - step.gt_pose[:2])))
    seen = np.unique(np.concatenate([s.ids for s in truth]))
    assert abs(seif.n_landmarks - seen.size) <= 0.1 * seen.size
    assert np.sqrt(np.mean(np.square(err))) < 1.0


# ----------------------------------------------------------------------------- bad input
def test_bad_input_is_rejected_clearly():
    ds = simulate_landmarks(20, 5, seed=11)
    seif = build_seif(ds)
    with pytest.raises(ValueError, match="rows but ids"):
        seif.update(np.zeros((2, 2)) + 1, np.array([1]))
    with pytest.raises(ValueError, match="finite"):
        seif.update(np.array([[np.nan, 0.1]]), np.array([1]))
    with pytest.raises(ValueError, match="ids must be"):
        seif.update(np.array([[1.0, 0.1]]), np.array([-3]))
    with pytest.raises(ValueError, match="control"):
        seif.predict([1.0], 0.1)
    with pytest.raises(ValueError, match="dt"):
        seif.predict([1.0, 0.0], -1.0)
    with pytest.raises(ValueError, match="positive definite"):
        SEIFSlam(ds.motion_model, ds.measurement_model, np.zeros(3), -np.eye(3))
    with pytest.raises(ValueError, match="max_active"):
        SeifConfig(max_active=0)


class _BrokenSensor(RangeBearingModel):
    """A sensor whose R is indefinite: its information blocks are not positive definite."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "R", np.diag([0.01, -1e-6]))


def test_indefinite_information_block_rejected_state_unchanged():
    ds = simulate_landmarks(30, 20, seed=12, density=0.1)
    seif = build_seif(ds)
    for step in list(ds)[:10]:
        seif.predict(step.control, step.dt)
        seif.update(step.z, step.ids)
    seif.measurement_model = _BrokenSensor()
    seif._R = seif.measurement_model.R
    Omega, n = seif.information_matrix(), seif.n_landmarks
    step = next(s for s in list(ds)[10:] if s.z.shape[0])
    with pytest.raises(SingularInformationError, match="not positive definite"):
        seif.update(step.z, step.ids)
    assert seif.n_landmarks == n
    assert np.array_equal(seif.information_matrix(), Omega)


def test_prior_landmarks_are_independent_gaussians():
    ds = simulate_landmarks(50, 5, seed=13)
    seif = build_seif(ds)
    cov = np.array([[[0.5, 0.1], [0.1, 0.3]], [[0.2, 0.0], [0.0, 0.2]]])
    seif.add_landmarks([7, 9], [[1.0, 2.0], [-3.0, 4.0]], cov)
    ids, xy, c = seif.landmarks()
    assert ids.tolist() == [7, 9]
    assert np.allclose(xy, [[1.0, 2.0], [-3.0, 4.0]])
    assert np.allclose(c, cov)
    with pytest.raises(ValueError, match="already in the state"):
        seif.add_landmarks([7], [[0.0, 0.0]], cov[:1])
    with pytest.raises(ValueError, match="positive definite"):
        seif.add_landmarks([8], [[0.0, 0.0]], -cov[:1])
