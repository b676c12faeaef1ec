"""General particle filter: Kalman-filter posterior on a linear-Gaussian problem, degenerate
weights, pose statistics."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from probmap.filters.particle import (
    ParticleFilter,
    ParticleFilterWarning,
    circular_mean,
    weighted_pose_covariance,
    weighted_pose_mean,
)
from probmap.filters.resampling import residual_resample


def test_posterior_matches_kalman_filter():
    # x_t = a x_{t-1} + u_t + N(0, q);  z_t = x_t + N(0, r): closed-form Kalman posterior
    a, q, r = 0.9, 0.3, 0.5
    rng = np.random.default_rng(11)
    n = 20000
    x0_mean, x0_var = 1.0, 2.0

    def motion(p, u, rng):
        return a * p + u + rng.normal(0.0, np.sqrt(q), p.shape)

    def loglik(p, z):
        return -0.5 * (z - p[:, 0]) ** 2 / r

    pf = ParticleFilter(
        rng.normal(x0_mean, np.sqrt(x0_var), (n, 1)),
        motion,
        loglik,
        rng,
        resample_threshold=0.5,
        resampler=residual_resample,
    )
    m, P = x0_mean, x0_var
    truth = 1.0
    for t in range(15):
        u = 0.2 * np.sin(t)
        truth = a * truth + u + rng.normal(0, np.sqrt(q))
        z = truth + rng.normal(0, np.sqrt(r))
        pf.step((u,), (z,))
        m, P = a * m + u, a * a * P + q  # predict
        K = P / (P + r)  # update
        m, P = m + K * (z - m), (1 - K) * P
        # Monte-Carlo error of a weighted mean: sqrt(P / ESS); allow 5 sigma plus the
        # resampling noise carried from earlier steps (a factor 2 on the variance).
        assert abs(pf.mean()[0] - m) < 5 * np.sqrt(2 * P / pf.ess)
        assert abs(pf.covariance()[0, 0] / P - 1) < 0.1


def test_all_impossible_particles_warn_and_recover():
    rng = np.random.default_rng(0)
    pf = ParticleFilter(
        np.zeros((50, 2)), lambda p, rng: p, lambda p: np.full(p.shape[0], -np.inf), rng
    )
    with pytest.warns(ParticleFilterWarning, match="zero likelihood"):
        pf.correct()
    assert np.all(np.isfinite(pf.weights)) and np.isclose(pf.weights.sum(), 1.0)
    assert np.isclose(pf.ess, 50)


def test_resampling_only_below_threshold():
    rng = np.random.default_rng(0)
    pf = ParticleFilter(
        np.arange(10.0), lambda p, rng: p, lambda p, ll: ll, rng, resample_threshold=0.5
    )
    pf.correct(np.zeros(10))
    assert not pf.resample_if_needed()
    pf.correct(np.array([0.0] + [-50.0] * 9))
    assert pf.resample_if_needed()
    assert np.all(pf.particles[:, 0] == 0.0)


def test_bad_construction():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="non-empty"):
        ParticleFilter(np.zeros((0, 3)), lambda p, rng: p, lambda p: p[:, 0], rng)
    with pytest.raises(ValueError, match="resample_threshold"):
        ParticleFilter(
            np.zeros((3, 3)), lambda p, rng: p, lambda p: p[:, 0], rng, resample_threshold=2.0
        )
    pf = ParticleFilter(np.zeros((3, 3)), lambda p, rng: p, lambda p: np.zeros(2), rng)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match="shape"):
            pf.correct()


def test_pose_statistics_use_circular_heading():
    poses = np.array([[0.0, 0.0, np.pi - 0.1], [2.0, 4.0, -np.pi + 0.1]])
    w = np.array([0.5, 0.5])
    mu = weighted_pose_mean(poses, w)
    assert np.allclose(mu[:2], [1.0, 2.0])
    assert np.isclose(abs(mu[2]), np.pi)
    cov = weighted_pose_covariance(poses, w)
    assert np.isclose(cov[2, 2], 0.01)  # not (pi - 0.1)^2
    assert np.isclose(cov[0, 0], 1.0) and np.isclose(cov[1, 1], 4.0) and np.isclose(cov[0, 1], 2.0)
    assert np.isclose(
        circular_mean([0.1, 0.3], [0.25, 0.75]),
        np.arctan2(
            0.25 * np.sin(0.1) + 0.75 * np.sin(0.3), 0.25 * np.cos(0.1) + 0.75 * np.cos(0.3)
        ),
    )
