"""EM fit of the beam model (Table 6.2): recovery of known parameters from seeded samples,
monotone likelihood, the truncated-exponential M-step against a numerical optimum, bad input.
(The fit of a whole log, the Intel corrected one, is in tests/pipelines/test_fit.py.)"""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.models.beam import BeamModelParams, _lambda_step, component_densities, fit_beam_model


def sample_beam_model(p: BeamModelParams, zs: np.ndarray, zmax: float, seed: int) -> np.ndarray:
    """Draw one reading per expected range from the mixture of Table 6.1."""
    rng = np.random.default_rng(seed)
    n = zs.size
    cause = rng.choice(4, size=n, p=[p.z_hit, p.z_short, p.z_max, p.z_rand])
    z = np.empty(n)
    hit = cause == 0
    z[hit] = zs[hit] + rng.normal(0.0, p.sigma_hit, hit.sum())
    short = cause == 1
    u = rng.random(short.sum())
    lam = p.lambda_short
    z[short] = -np.log1p(-u * -np.expm1(-lam * zs[short])) / lam  # inverse CDF on [0, z*]
    z[cause == 2] = zmax
    rand = cause == 3
    z[rand] = rng.uniform(0.0, zmax, rand.sum())
    return z


def test_component_densities_are_normalised():
    zmax, zs = 10.0, 3.0
    z = np.linspace(0, zmax, 200_001)[:-1]
    d = component_densities(z, np.full_like(z, zs), zmax, 0.2, 0.5)
    integrals = np.sum(0.5 * (d[:, 1:] + d[:, :-1]) * np.diff(z), axis=1)
    np.testing.assert_allclose(integrals[[0, 1, 3]], 1.0, atol=1e-3)
    assert component_densities(np.array([zmax]), np.array([zs]), zmax, 0.2, 0.5)[2, 0] == 1.0


def test_em_recovers_known_parameters():
    truth = BeamModelParams(
        z_hit=0.7, z_short=0.15, z_max=0.05, z_rand=0.1, sigma_hit=0.15, lambda_short=0.6
    )
    zmax = 10.0
    zs = np.random.default_rng(7).uniform(1.0, 6.0, 40_000)
    z = sample_beam_model(truth, zs, zmax, seed=8)
    fit = fit_beam_model(z, zs, zmax)
    got = fit.params
    print(f"\nEM fit after {fit.iterations} iterations: {got}")
    assert fit.converged
    assert got.z_hit == pytest.approx(0.7, abs=0.02)
    assert got.z_short == pytest.approx(0.15, abs=0.02)
    assert got.z_max == pytest.approx(0.05, abs=0.005)
    assert got.z_rand == pytest.approx(0.1, abs=0.02)
    assert got.sigma_hit == pytest.approx(0.15, rel=0.05)
    assert got.lambda_short == pytest.approx(0.6, rel=0.15)


def test_em_likelihood_never_decreases():
    truth = BeamModelParams(z_hit=0.6, z_short=0.2, z_max=0.1, z_rand=0.1, sigma_hit=0.3)
    zs = np.random.default_rng(1).uniform(1.0, 7.0, 5000)
    z = sample_beam_model(truth, zs, 10.0, seed=2)
    fit = fit_beam_model(z, zs, 10.0, tol=0.0, max_iterations=60)
    ll = np.array(fit.log_likelihood)
    assert np.all(np.diff(ll) >= -1e-10)
    assert ll[-1] > ll[0]


def test_lambda_step_is_the_weighted_truncated_exponential_optimum():
    rng = np.random.default_rng(3)
    zs = rng.uniform(0.5, 4.0, 300)
    z = zs * rng.random(300)
    e = rng.random(300)

    def objective(lam):
        return np.sum(e * (np.log(lam) - lam * z - np.log(-np.expm1(-lam * zs))))

    lam = _lambda_step(e, z, zs, 1.0)
    grid = np.exp(np.linspace(np.log(1e-3), np.log(50), 20001))
    best = grid[np.argmax([objective(g) for g in grid])]
    assert lam == pytest.approx(best, rel=2e-3)
    assert objective(lam) >= objective(best) - 1e-9


def test_fit_is_finite_with_outliers_and_bad_readings():
    zs = np.random.default_rng(4).uniform(0.5, 5.0, 2000)
    z = zs.copy()
    z[::7] = np.nan
    z[::11] = 1e6  # beyond max range: max-range readings
    z[::13] = 0.0
    fit = fit_beam_model(z, zs, 8.0)
    assert all(math.isfinite(v) for v in fit.log_likelihood)
    assert fit.params.z_max > 0 and fit.params.z_rand > 0


@pytest.mark.parametrize(
    ("z", "zs", "mr", "match"),
    [
        (np.ones(20), np.ones(21), 5.0, "one shape"),
        (np.ones(5), np.ones(5), 5.0, "at least 10"),
        (np.ones(20), np.ones(20), -1.0, "max_range"),
    ],
)
def test_bad_input(z, zs, mr, match):
    with pytest.raises(ValueError, match=match):
        fit_beam_model(z, zs, mr)
