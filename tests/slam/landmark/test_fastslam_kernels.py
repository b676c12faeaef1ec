"""FastSLAM's measurement kernels against slow, obviously-correct references: the range-bearing
``h`` and its Jacobians against the model's own ``predict``, the Gaussian log-density in closed
form, and one whole step (2.0's proposal and draw, landmark initialization and EKF updates,
importance factors) against Tables 13.1 and 13.3 written one particle at a time with
``numpy.linalg``."""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.geometry.se2 import wrap_angle
from probmap.models.measurement import RangeBearingModel
from probmap.slam.landmark._fastslam_kernels import _logpdf2, fastslam_update
from probmap.slam.landmark._kernels import range_bearing

MODEL = RangeBearingModel(sensor_offset=(0.2, -0.1, 0.3), R=np.diag([0.04, 0.002]))
OFFSET = np.asarray(MODEL.sensor_offset, dtype=np.float64)


def test_h_equals_the_models_own():
    rng = np.random.default_rng(1)
    hm, hx = np.empty((2, 2)), np.empty((2, 3))
    for _ in range(20):
        pose, mark = rng.normal(0.0, 2.0, 3), rng.normal(0.0, 5.0, 2)
        r, b = range_bearing(pose[0], pose[1], pose[2], OFFSET, mark[0], mark[1], hm, hx)
        z, H_x, H_m = MODEL.predict(pose, mark)
        np.testing.assert_allclose([r, b], z, atol=1e-12)
        np.testing.assert_allclose(hx, H_x, atol=1e-12)
        np.testing.assert_allclose(hm, H_m, atol=1e-12)


def test_logpdf2_closed_form():
    S = np.array([[2.0, 0.3], [0.3, 0.5]])
    e = np.array([0.4, -0.2])
    want = -0.5 * e @ np.linalg.inv(S) @ e - 0.5 * math.log((2 * math.pi) ** 2 * np.linalg.det(S))
    assert _logpdf2(e[0], e[1], S[0, 0], S[0, 1], S[1, 0], S[1, 1]) == pytest.approx(want, 1e-12)


def _logpdf(e, S):
    return float(-0.5 * e @ np.linalg.solve(S, e) - 0.5 * math.log(np.linalg.det(2 * math.pi * S)))


def _step_reference(particles, predicted, Rt, v2, z, cols, mode, mean, cov, count, noise, new_logw):
    """Tables 13.1 / 13.3, one particle and one observation at a time."""
    R = np.asarray(MODEL.R)
    particles, mean, cov, count = particles.copy(), mean.copy(), cov.copy(), count.copy()
    logw = np.zeros(len(particles))
    for m in range(len(particles)):
        if v2:
            x, P = predicted[m].copy(), Rt + 1e-12 * np.eye(3)
            for i in range(len(z)):
                if mode[i, m] != 1:
                    continue
                zh, H_x, H_m = MODEL.predict(x, mean[i, m])
                Q = H_m @ cov[i, m] @ H_m.T + R
                K = P @ H_x.T @ np.linalg.inv(H_x @ P @ H_x.T + Q)
                e = z[i] - zh
                e[1] = wrap_angle(e[1])
                x = x + K @ e
                x[2] = wrap_angle(x[2])
                P = P - K @ H_x @ P
            L = np.linalg.cholesky(0.5 * (P + P.T) + 1e-15 * np.eye(3))
            particles[m] = x + L @ noise[m]
            particles[m, 2] = wrap_angle(particles[m, 2])
        for i in range(len(z)):
            md = mode[i, m]
            if md == 0:
                continue
            earlier = [j for j in range(i) if mode[j, m] and cols[j, m] == cols[i, m]]
            if earlier:
                j = earlier[-1]
                mean[i, m], cov[i, m], count[i, m], md = mean[j, m], cov[j, m], count[j, m], 1
            if md == 2:
                mean[i, m], _, Jz = MODEL.inverse(particles[m], z[i])
                cov[i, m] = Jz @ R @ Jz.T
                count[i, m] = 1
                logw[m] += new_logw
                continue
            mu, C = mean[i, m].copy(), cov[i, m].copy()
            zh, _, H_m = MODEL.predict(particles[m], mu)
            Q = H_m @ C @ H_m.T + R
            K = C @ H_m.T @ np.linalg.inv(Q)
            e = z[i] - zh
            e[1] = wrap_angle(e[1])
            mean[i, m] = mu + K @ e
            cov[i, m] = (np.eye(2) - K @ H_m) @ C
            count[i, m] += 1
            if v2:
                zp, Hp, _ = MODEL.predict(predicted[m], mu)
                f = z[i] - zp
                f[1] = wrap_angle(f[1])
                logw[m] += _logpdf(f, Q + Hp @ Rt @ Hp.T)
            else:
                logw[m] += _logpdf(e, Q)
    return particles, mean, cov, count, logw


@pytest.mark.parametrize("v2", [False, True])
def test_fastslam_update_equals_the_reference(v2):
    """Six particles, four observations: held landmarks, new ones, a column observed twice
    (the second updates the first's result) and particles that do not see some of them."""
    rng = np.random.default_rng(7)
    m, k = 6, 4
    predicted = np.column_stack([rng.normal(0, 0.5, (m, 2)), rng.normal(0, 0.2, m)])
    particles = predicted + rng.normal(0, 0.05, (m, 3))
    B = rng.normal(0, 0.05, (3, 3))
    Rt = B @ B.T
    marks = rng.uniform(-6, 6, (k, 2))
    z = np.array([MODEL.predict(predicted[0], lm)[0] for lm in marks]) + rng.normal(0, 0.05, (k, 2))
    cols = np.array([[0] * m, [1] * m, [2] * m, [0] * m], dtype=np.int64)  # row 3 = row 0 again
    mode = rng.choice([0, 1, 1, 2], size=(k, m)).astype(np.int64)
    mean = marks[:, None, :] + rng.normal(0, 0.2, (k, m, 2))
    A = rng.normal(0, 0.2, (k, m, 2, 2))
    cov = A @ np.transpose(A, (0, 1, 3, 2)) + 0.01 * np.eye(2)
    count = rng.integers(1, 5, (k, m))
    noise = rng.standard_normal((m, 3))
    want = _step_reference(particles, predicted, Rt, v2, z, cols, mode, mean, cov, count, noise,
                           -7.0)  # fmt: skip
    got_p, got_mean, got_cov, got_count = particles.copy(), mean.copy(), cov.copy(), count.copy()
    logw = np.zeros(m)
    fastslam_update(got_p, predicted, Rt, v2, z, np.asarray(MODEL.R), OFFSET, cols, mode,
                    got_mean, got_cov, got_count, noise, -7.0, logw)  # fmt: skip
    active = mode > 0
    np.testing.assert_allclose(got_p, want[0], atol=1e-10)
    np.testing.assert_allclose(got_mean[active], want[1][active], atol=1e-10)
    np.testing.assert_allclose(got_cov[active], want[2][active], atol=1e-10)
    np.testing.assert_array_equal(got_count[active], want[3][active])
    np.testing.assert_allclose(logw, want[4], rtol=1e-9, atol=1e-9)
    assert (mode == 2).any() and (mode == 1).any()  # both branches were exercised
    assert np.allclose(got_p, particles) != v2  # 2.0 drew new poses, 1.0 kept them
