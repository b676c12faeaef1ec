"""KLD-sampling's batched stopping rule against the one-draw-at-a-time loop of Table 8.4, and
the compiled ESS of adaptive tempering against plain numpy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.filters import _kernels
from probmap.filters.kld import KLDConfig, kld_resample, kld_sample_size


def _table_8_4(poses, weights, uniforms, cfg):
    """Table 8.4 as printed: draw, bin, recompute the bound, stop once it is met."""
    cum = np.cumsum(weights / weights.sum())
    bins = np.floor(poses / np.asarray(cfg.bin_size)).astype(np.int64)
    seen, out = set(), []
    for u in uniforms:
        i = min(int(np.searchsorted(cum, u, side="right")), weights.size - 1)
        out.append(i)
        seen.add(tuple(bins[i]))
        need = max(cfg.n_min, kld_sample_size(len(seen), cfg.epsilon, cfg.delta))
        if len(out) >= min(need, cfg.n_max):
            return np.sort(np.array(out))
    raise AssertionError("ran out of uniforms")


@pytest.mark.parametrize(
    ("scale", "peak", "n_min", "n_max"),
    [((0.1, 0.1, 0.03), 1.0, 100, 5000),  # tight: n_min
     ((1.0, 1.0, 0.5), 2.0, 50, 5000),  # a few hundred bins: the bound decides
     ((4.0, 3.0, 1.0), 1.0, 50, 3000),  # spread: n_max
     ((2.0, 2.0, 1.0), 8.0, 10, 20000)],  # peaked weights over a spread set
)  # fmt: skip
def test_kld_resample_stops_where_table_8_4_stops(scale, peak, n_min, n_max):
    rng = np.random.default_rng(3)
    poses = rng.normal(size=(4000, 3)) * np.asarray(scale)
    weights = rng.random(4000) ** peak
    cfg = KLDConfig(n_min=n_min, n_max=n_max)
    got = kld_resample(poses, weights, np.random.default_rng(11), cfg)
    # the generator's uniforms are one stream however they are batched
    want = _table_8_4(poses, weights, np.random.default_rng(11).uniform(size=n_max), cfg)
    assert np.array_equal(got, want)
    assert n_min <= got.size <= n_max


def test_kld_resample_size_follows_the_bins():
    rng = np.random.default_rng(0)
    cfg = KLDConfig(n_min=10, n_max=100_000)
    one_bin = np.full((500, 3), 0.1)
    assert kld_resample(one_bin, np.ones(500), rng, cfg).size == 10
    spread = rng.uniform(0, 1, size=(20_000, 3)) * [10.0, 10.0, 1.0]  # about 2,400 bins
    m = kld_resample(spread, np.ones(20_000), rng, cfg).size
    k = np.unique(np.floor(spread / np.asarray(cfg.bin_size)), axis=0).shape[0]
    # the bound for the bins the draws hit: nearly all of the set's, after ten draws a bin
    assert kld_sample_size(int(0.95 * k), 0.05, 0.01) <= m <= kld_sample_size(k, 0.05, 0.01)
    assert kld_resample(spread, np.ones(20_000), rng, KLDConfig(n_max=5000)).size == 5000


def _ess_numpy(lw, ll, gamma):
    x = np.where(np.isnan(ll), -np.inf, lw + gamma * ll)
    top = x.max()
    if not math.isfinite(top):
        return 0.0
    w = np.exp(x - top)
    return float(w.sum() ** 2 / np.dot(w, w) / w.size)


@pytest.mark.parametrize("gamma", [0.0, 0.01, 0.3, 1.0])
def test_ess_kernel_matches_numpy(gamma):
    rng = np.random.default_rng(5)
    lw = np.log(rng.dirichlet(np.ones(3000)))
    ll = rng.normal(-200.0, 40.0, size=3000)
    ll[::97] = np.nan  # impossible particles weigh nothing
    assert _kernels.ess_fraction(lw, ll, gamma) == pytest.approx(_ess_numpy(lw, ll, gamma), 1e-12)
    assert _kernels.ess_fraction(lw, np.full(3000, np.nan), gamma) == 0.0
    flat = np.full(3000, -math.log(3000))
    assert _kernels.ess_fraction(flat, np.zeros(3000), gamma) == pytest.approx(1.0)


def test_kld_count_is_table_8_4s_count_and_leaves_a_tight_cloud_alone():
    from probmap.filters.kld import kld_count

    rng = np.random.default_rng(2)
    spread = rng.normal(size=(6000, 3)) * [2.0, 2.0, 1.0]
    w = rng.random(6000)
    cfg = KLDConfig(n_min=100, n_max=50_000)
    want = kld_resample(spread, w, np.random.default_rng(9), cfg).size
    assert kld_count(spread, w, np.random.default_rng(9), cfg) == want > 100
    # a cloud within a few bins: n_min, and the generator is not touched
    tight = rng.normal(size=(2000, 3)) * [0.05, 0.05, 0.02]
    g = np.random.default_rng(4)
    assert kld_count(tight, np.ones(2000), g, KLDConfig(n_min=2000)) == 2000
    assert g.uniform() == np.random.default_rng(4).uniform()
    # only weighted particles count: a spread set whose weight sits on one bin
    peaked = np.zeros(6000)
    peaked[:5] = 1.0
    assert kld_count(spread[:1].repeat(6000, 0), peaked, g, cfg) == 100


def test_pose_bounds_kernel_matches_numpy():
    rng = np.random.default_rng(8)
    for n in (1, 2, 17, 5000):
        p = rng.normal(size=(n, 3)) * [30.0, 5.0, 2.0]
        out = np.empty((2, 3))
        _kernels.pose_bounds(p, out)
        np.testing.assert_array_equal(out, np.stack([p.min(axis=0), p.max(axis=0)]))


def test_adaptive_exponent_kernel_is_the_bisection():
    from probmap.filters.mcl import mcl_adaptive_exponent

    def bisection(lw, ll, exponent, target):  # the plain-Python rule, on numpy's ESS
        if _ess_numpy(lw, ll, exponent) >= target:
            return exponent
        lo, hi = 0.0, exponent
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if _ess_numpy(lw, ll, mid) >= target else (lo, mid)
        return lo

    rng = np.random.default_rng(6)
    for spread in (0.1, 5.0, 50.0, 500.0):
        lw = np.log(rng.dirichlet(np.ones(2000)))
        ll = rng.normal(0.0, spread, size=2000)
        got = mcl_adaptive_exponent(lw, ll, 1.0 / 6.0, 0.3)
        assert got == pytest.approx(bisection(lw, ll, 1.0 / 6.0, 0.3), rel=1e-8)
        assert _ess_numpy(lw, ll, got) >= 0.3 - 1e-12
