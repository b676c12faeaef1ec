"""Property tests (hypothesis, few examples for a fast suite): the posterior is a distribution
under any log odds and long update sequences, and scans commute while clamping is not reached."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from probmap.grid.semantic import (
    LabelledInverseModel,
    SemanticGrid,
    class_entropy,
    class_posterior,
)
from probmap.grid.spec import GridSpec

FAST = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FAST
@given(
    arrays(
        np.float64,
        st.tuples(st.integers(1, 6), st.integers(1, 5)),
        elements=st.floats(-1e6, 1e6, allow_nan=False),
    )
)
def test_posterior_is_a_distribution_for_any_log_odds(l):
    p = class_posterior(l)
    assert p.shape == (l.shape[0], l.shape[1] + 1)
    assert np.isfinite(p).all() and (p >= 0).all()
    np.testing.assert_allclose(p.sum(axis=-1), 1.0, rtol=0, atol=1e-12)
    h = class_entropy(l)
    assert np.isfinite(h).all() and (h >= 0).all()
    assert (h <= np.log(l.shape[1] + 1) + 1e-9).all()


def _scans(seed, n_scans, K):
    rng = np.random.default_rng(seed)
    poses = np.column_stack(
        [rng.uniform(-0.5, 0.5, (n_scans, 2)), rng.uniform(-np.pi, np.pi, n_scans)]
    )
    ranges = rng.uniform(0.1, 1.5, (n_scans, 16))
    ranges[rng.random(ranges.shape) < 0.1] = 2.0  # max-range readings
    angles = np.round(np.linspace(-1.5, 1.5, 16), 1)
    labels = rng.integers(1, K + 1, ranges.shape)
    probs = rng.dirichlet(np.full(K, 0.3), ranges.shape)
    return poses, ranges, angles, labels, probs


SPEC = GridSpec(0.1, (-2.5, -2.5), (50, 50))


@FAST
@given(st.integers(0, 2**32 - 1), st.integers(1, 5), st.booleans(), st.floats(0.51, 0.999))
def test_long_update_sequences_stay_finite(seed, K, soft, p_max):
    poses, ranges, angles, labels, probs = _scans(seed, 80, K)
    classes = ["free", *[f"c{k}" for k in range(K)]]
    grid = SemanticGrid(classes, spec=SPEC, fixed=True, clamp=(1 - p_max, p_max))
    kw = {"probabilities": probs} if soft else {"labels": labels}
    grid.integrate_scans(poses, ranges, angles, max_range=2.0, **kw)
    p = grid.probabilities()
    assert np.isfinite(grid.log_odds).all() and np.isfinite(p).all()
    np.testing.assert_allclose(p.sum(axis=-1), 1.0, rtol=0, atol=1e-12)
    assert (grid.log_odds <= np.float32(grid.l_max)).all()
    assert (grid.log_odds >= np.float32(grid.l_min)).all()


@FAST
@given(st.integers(0, 2**32 - 1), st.integers(1, 4), st.booleans())
def test_scan_order_does_not_matter_within_clamping(seed, K, soft):
    poses, ranges, angles, labels, probs = _scans(seed, 12, K)
    classes = ["free", *[f"c{k}" for k in range(K)]]
    # bounds far away: 12 scans can move a log odds by at most ~12 * 10
    model = LabelledInverseModel(label_floor=1e-3)
    clamp = (1e-80, 1 - 1e-16)
    order = np.random.default_rng(seed + 1).permutation(len(poses))
    grids = []
    for idx in (np.arange(len(poses)), order):
        g = SemanticGrid(classes, spec=SPEC, fixed=True, clamp=clamp, model=model)
        for s in idx:  # one scan at a time, in this order
            kw = {"probabilities": probs[s : s + 1]} if soft else {"labels": labels[s : s + 1]}
            g.integrate_scans(poses[s : s + 1], ranges[s : s + 1], angles, max_range=2.0, **kw)
        grids.append(g)
    a, b = grids
    assert (a.log_odds > np.float32(a.l_min)).all() and (a.log_odds < np.float32(a.l_max)).all()
    np.testing.assert_array_equal(a.observed, b.observed)
    # sums of the same float64 increments in another order: equal up to float32 rounding
    np.testing.assert_allclose(a.log_odds, b.log_odds, rtol=1e-5, atol=1e-4)
