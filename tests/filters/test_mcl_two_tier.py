"""MCL's two tiers: the Table 8.2 array functions driven by hand against
:class:`MonteCarloLocalization`, step by step on a seeded simulation (they must agree exactly);
the constructors that make a filter valid when built, and the deprecated ``initialize_*``."""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.filters.kld import KLDConfig
from probmap.filters.mcl import (
    FreeSpaceSampler,
    MCLConfig,
    MonteCarloLocalization,
    RangeBearingLandmarks,
    mcl_likelihood_averages,
    mcl_random_fraction,
    mcl_resample,
    mcl_sample_and_weight_scan,
    mcl_sample_motion,
    mcl_weight,
    sample_pose_gaussian,
)
from probmap.models.likelihood_field import LikelihoodField
from probmap.models.sampling import OdometryMotionModel, VelocityMotionModel
from probmap.sim.floorplan import simulate_laser_world

COV0 = np.diag([0.02, 0.02, 0.01])


@pytest.fixture(scope="module")
def world():
    return simulate_laser_world(seed=2, n_beams=61, pose_noise=(0.05, 0.02))


@pytest.fixture(scope="module")
def field(world):
    return LikelihoodField(
        world.spec, world.truth, max_range=world.max_range, sigma_hit=0.3, z_hit=0.5, z_rand=0.5
    )


@pytest.fixture(scope="module")
def free(field):
    return FreeSpaceSampler(field.spec, field.distance > 0.2)


def _normalised(lw):
    w = np.exp(lw - lw.max())
    return w / w.sum()


CONFIGS = {
    "plain": MCLConfig(n_particles=400),
    "augmented": MCLConfig(n_particles=400, augmented=True, alpha_slow=0.05, alpha_fast=0.5),
    "kld": MCLConfig(n_particles=800, kld=KLDConfig(n_min=100, n_max=2000), resample_threshold=1.0),
}


@pytest.mark.parametrize("fused", [False, True], ids=["generic", "fused"])
@pytest.mark.parametrize("name", list(CONFIGS))
def test_functions_and_class_agree_step_by_step(world, field, free, name, fused):
    cfg = CONFIGS[name]
    motion = OdometryMotionModel(0.1, 0.1, 0.1, 0.1)
    mcl = MonteCarloLocalization.from_pose(
        field, motion, np.random.default_rng(5), world.poses[0], COV0, cfg, free
    )
    # the function tier, on its own generator with the same seed
    rng = np.random.default_rng(5)
    count_rng = rng.spawn(1)[0]  # KLD's counting draws: the class's own child generator
    p = sample_pose_gaussian(world.poses[0], COV0, cfg.n_particles, rng)
    lw = np.full(p.shape[0], -math.log(p.shape[0]))
    ess, w_slow, w_fast = float(p.shape[0]), 0.0, 0.0
    assert np.array_equal(mcl.particles, p) and np.array_equal(mcl.log_weights, lw)
    resampled = injected = 0
    for k in range(1, 80):
        u = (world.odometry[k - 1], world.odometry[k])
        z = (world.ranges[k], world.angles)
        if fused:
            est = mcl.update_scan(*u, *z)
            lx, ly, valid = field.endpoints(*z)
            ll = mcl_sample_and_weight_scan(p, *u, lx[valid], ly[valid], field, motion, rng)
            count = int(valid.sum())
        else:
            est = mcl.update(u, z)
            p = mcl_sample_motion(p, motion, u, rng)
            ll = field.log_likelihood_sum(p, *z)
            count = len(z[0])
        lw, ess = mcl_weight(lw, ll)
        assert ess > 0.0
        # kept whether augmented or not (the pipeline reads w_fast / w_slow)
        w_slow, w_fast = mcl_likelihood_averages(
            w_slow, w_fast, ll, count, cfg.alpha_slow, cfg.alpha_fast
        )
        assert est.ess == ess
        p_rand = mcl_random_fraction(w_slow, w_fast) if cfg.augmented else 0.0
        if ess < cfg.resample_threshold * p.shape[0] or p_rand > 0:
            p = mcl_resample(p, _normalised(lw), rng, cfg.kld, p_rand, free, count_rng)
            lw = np.full(p.shape[0], -math.log(p.shape[0]))
            ess = float(p.shape[0])
            resampled += 1
            injected += p_rand > 0
        assert np.array_equal(mcl.particles, p)
        assert np.array_equal(mcl.log_weights, lw)
        assert mcl.last_ess == ess and mcl.w_slow == w_slow and mcl.w_fast == w_fast
    assert resampled >= 5  # the comparison covered resampling
    assert np.hypot(*(est.mean[:2] - world.poses[79, :2])) < 0.3  # and it localised
    if name == "augmented":
        assert injected >= 1  # and random particles
    if name == "kld":
        assert mcl.n < cfg.n_particles  # and an adapted particle count


def test_landmark_functions_and_class_agree_step_by_step():
    rng_w = np.random.default_rng(4)
    lm = RangeBearingLandmarks(np.arange(6) + 10, rng_w.uniform(-5, 5, (6, 2)), 0.1, 0.05)
    model = VelocityMotionModel(0.05, 0.01, 0.01, 0.05, 0.001, 0.001)
    cfg = MCLConfig(n_particles=300)
    mcl = MonteCarloLocalization.from_pose(
        lm, model, np.random.default_rng(1), np.zeros(3), np.eye(3) * 0.01, cfg
    )
    rng = np.random.default_rng(1)
    p = sample_pose_gaussian(np.zeros(3), np.eye(3) * 0.01, 300, rng)
    lw = np.full(300, -math.log(300))
    true = np.zeros(3)
    for t in range(60):
        u = (np.array([0.5, 0.3 * math.sin(t / 20)]), 0.2)
        true = VelocityMotionModel(0, 0, 0, 0, 0, 0).sample(true[None], u[0], 0.2, rng_w)[0]
        ids = rng_w.choice(lm.ids, 3, replace=False)
        d = lm.positions[ids - 10] - true[:2]
        z = (
            np.column_stack([np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0]) - true[2]]),
            ids,
        )
        mcl.update(u, z)
        p = mcl_sample_motion(p, model, u, rng)
        lw, ess = mcl_weight(lw, lm.log_likelihood_sum(p, *z))
        if ess < 0.5 * 300:
            p = mcl_resample(p, _normalised(lw), rng)
            lw = np.full(300, -math.log(300))
        assert np.array_equal(mcl.particles, p) and np.array_equal(mcl.log_weights, lw)


def test_weight_and_random_fraction_edge_cases():
    lw = np.log(np.full(4, 0.25))
    out, ess = mcl_weight(lw, np.array([0.0, np.nan, -np.inf, 0.0]))
    assert np.allclose(np.exp(out), [0.5, 0.0, 0.0, 0.5]) and ess == pytest.approx(2.0)
    out, ess = mcl_weight(lw, np.full(4, -np.inf))
    assert ess == 0.0 and np.all(out == -np.inf)
    assert mcl_random_fraction(0.0, 0.0) == 0.0
    assert mcl_random_fraction(2.0, 1.0) == 0.5 and mcl_random_fraction(1.0, 2.0) == 0.0
    # averages start at the first w_avg, which is the per-measurement geometric mean
    s, f = mcl_likelihood_averages(0.0, 0.0, np.log(np.full(3, 0.01)), 2, 0.1, 0.5)
    assert s == pytest.approx(0.1) and f == pytest.approx(0.1)


def test_filter_is_valid_when_built(world, field, free):
    motion = OdometryMotionModel(0.1, 0.1, 0.1, 0.1)
    cfg = MCLConfig(n_particles=200)
    tracked = MonteCarloLocalization.from_pose(
        field, motion, np.random.default_rng(0), world.poses[0], COV0, cfg, free
    )
    est = tracked.estimate()
    assert np.hypot(*(est.mean[:2] - world.poses[0, :2])) < 0.05 and 0 < est.spread < 0.5
    glob = MonteCarloLocalization.uniform(field, motion, np.random.default_rng(0), free, cfg)
    assert glob.n == 200 and glob.estimate().spread > 2.0
    given = np.tile(world.poses[0], (50, 1))
    mcl = MonteCarloLocalization(field, motion, np.random.default_rng(0), cfg, particles=given)
    assert mcl.n == 50 and np.allclose(mcl.weights, 1 / 50)
    mcl.update_scan(world.odometry[0], world.odometry[1], world.ranges[1], world.angles)
    assert np.array_equal(given, np.tile(world.poses[0], (50, 1)))  # the input is not moved
    with pytest.raises(ValueError, match="particles must have shape"):
        MonteCarloLocalization(field, motion, np.random.default_rng(0), particles=np.zeros((5, 2)))
    with pytest.raises(ValueError, match="finite"):
        MonteCarloLocalization(
            field, motion, np.random.default_rng(0), particles=np.full((5, 3), np.nan)
        )
    with pytest.raises(ValueError, match="mean must be"):
        MonteCarloLocalization.from_pose(
            field, motion, np.random.default_rng(0), np.zeros(2), np.eye(3)
        )


@pytest.mark.parametrize("unit", [None, 0.1])
def test_fused_and_generic_sampling_share_the_unit_step(field, unit):
    """The compiled predict-and-weight pass and the numpy sampler draw a 1 m step with the same
    noise: with ``unit_step``, the heading variance of ten 0.1 m steps (Table 5.6 as printed:
    ten times that)."""
    motion = OdometryMotionModel(0.3, 0.1, 0.1, 0.3, unit_step=unit)
    n = 40000
    start = np.tile([5.0, 5.0, 0.0], (n, 1))
    u = (np.zeros(3), np.array([1.0, 0.0, 0.0]))
    fused = np.ascontiguousarray(start.copy())
    no_beams = np.zeros(0)
    mcl_sample_and_weight_scan(
        fused, *u, no_beams, no_beams, field, motion, np.random.default_rng(3)
    )
    generic = mcl_sample_motion(start, motion, u, np.random.default_rng(4))
    expected = 2 * 0.1 * 1.0**2 / (10 if unit else 1)
    for p in (fused, generic):
        assert abs(np.var(p[:, 2]) / expected - 1) < 5 * math.sqrt(2 / n)
