"""Resampling: unbiasedness against N*w, variance structure, log-sum-exp, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.filters import _kernels
from probmap.filters.resampling import (
    effective_sample_size,
    log_normalize,
    low_variance_resample,
    multinomial_resample,
    residual_resample,
    stratified_resample,
)

RESAMPLERS = [low_variance_resample, stratified_resample, residual_resample, multinomial_resample]


@pytest.mark.parametrize("resample", RESAMPLERS, ids=lambda f: f.__name__)
def test_expected_copies_equal_n_times_weight(resample):
    rng = np.random.default_rng(7)
    w = rng.dirichlet(np.full(12, 0.7))
    n, reps = 12, 4000
    counts = np.zeros((reps, n))
    for r in range(reps):
        counts[r] = np.bincount(resample(w, rng), minlength=n)
    assert np.all(counts.sum(axis=1) == n)
    # Every scheme's count variance is at most the multinomial one, N w (1 - w).
    se = np.sqrt(n * w * (1 - w) / reps)
    assert np.all(np.abs(counts.mean(axis=0) - n * w) <= 5 * se + 1e-12)


@pytest.mark.parametrize("resample", RESAMPLERS, ids=lambda f: f.__name__)
def test_weighted_mean_unchanged_in_expectation(resample):
    rng = np.random.default_rng(3)
    x = rng.normal(size=200)
    w = rng.exponential(size=200)
    w /= w.sum()
    target = float(w @ x)
    means = np.array([x[resample(w, rng)].mean() for _ in range(2000)])
    # Multinomial bound on the standard error of a resampled mean.
    se = np.sqrt(float(w @ (x - target) ** 2) / 200 / 2000)
    assert abs(means.mean() - target) < 5 * se


def test_systematic_and_residual_copy_counts_are_floor_or_ceil():
    rng = np.random.default_rng(0)
    w = rng.dirichlet(np.ones(50))
    for _ in range(200):
        c = np.bincount(low_variance_resample(w, rng), minlength=50)
        assert np.all(c >= np.floor(50 * w)) and np.all(c <= np.ceil(50 * w))
        r = np.bincount(residual_resample(w, rng), minlength=50)
        assert np.all(r >= np.floor(50 * w))


def test_low_variance_kernel_matches_reference():
    rng = np.random.default_rng(1)
    for n in (1, 2, 17, 300):
        w = rng.dirichlet(np.ones(n) * 0.3)
        for m in (n, 2 * n + 1):
            u = float(rng.uniform())
            out = np.empty(m, dtype=np.int64)
            _kernels.low_variance_indexes(w, u, out)
            # Table 4.4 written out in plain Python.
            ref, c, i = [], w[0], 0
            for k in range(m):
                target = (u + k) / m
                while target >= c and i < n - 1:
                    i += 1
                    c += w[i]
                ref.append(i)
            assert out.tolist() == ref
            # same offset through the public numpy function
            assert np.array_equal(
                np.minimum(
                    np.searchsorted(np.cumsum(w), (u + np.arange(m)) / m, side="right"), n - 1
                ),
                out,
            )  # noqa: E501


def test_drawing_a_different_count():
    rng = np.random.default_rng(0)
    idx = stratified_resample([0.5, 0.5], rng, n=7)
    assert idx.shape == (7,)
    with pytest.raises(ValueError, match="positive"):
        multinomial_resample([1.0], rng, n=0)


@pytest.mark.parametrize(
    ("weights", "msg"),
    [
        ([], "non-empty"),
        ([0.0, 0.0], "sum to zero"),
        ([1.0, -1.0], "non-negative"),
        ([np.nan, 1.0], "finite"),
        ([[1.0]], "1-D"),
    ],
)
def test_bad_weights(weights, msg):
    with pytest.raises(ValueError, match=msg):
        low_variance_resample(weights, np.random.default_rng(0))


def test_log_normalize_matches_direct_and_survives_extremes():
    lw = np.array([-1.0, 0.5, 2.0])
    w, total = log_normalize(lw)
    assert np.allclose(w, np.exp(lw) / np.exp(lw).sum())
    assert np.isclose(total, np.log(np.exp(lw).sum()))
    w, total = log_normalize(lw + 5000.0)  # exp would overflow
    assert np.allclose(w, np.exp(lw) / np.exp(lw).sum()) and np.isclose(total, total)
    w, total = log_normalize([-np.inf, -np.inf])
    assert total == -np.inf and not np.any(np.isnan(w))


def test_effective_sample_size():
    assert effective_sample_size(np.ones(10)) == pytest.approx(10.0)
    assert effective_sample_size([0, 0, 1.0]) == pytest.approx(1.0)
    assert effective_sample_size([1.0, 3.0]) == pytest.approx(1.0 / (1 / 16 + 9 / 16))
