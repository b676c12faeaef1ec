"""Monte Carlo localization on a simulated world: fused kernel against a pure-Python
reference, tracking, global localization, kidnapping, KLD-sampling, landmarks, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.filters import _kernels
from probmap.filters.kld import KLDConfig, kld_resample, kld_sample_size
from probmap.filters.mcl import (
    FreeSpaceSampler,
    MCLConfig,
    MonteCarloLocalization,
    RangeBearingLandmarks,
)
from probmap.filters.particle import ParticleFilterWarning
from probmap.models.likelihood_field import LikelihoodField
from probmap.models.sampling import OdometryMotionModel, VelocityMotionModel
from probmap.sim.localization import simulate_localization_world


@pytest.fixture(scope="module")
def world():
    return simulate_localization_world(0)


@pytest.fixture(scope="module")
def field(world):
    return LikelihoodField(
        world.spec, world.occupied, max_range=world.max_range, sigma_hit=0.3, z_hit=0.5, z_rand=0.5
    )


def _mcl(field, seed, start, **cfg):
    """MCL on the simulated floor plan: ``start`` is ``(mean, cov)`` to track from a known pose
    or ``"global"`` for particles uniform over the free space."""
    free = FreeSpaceSampler(field.spec, field.distance > 0.2)
    motion = OdometryMotionModel(0.1, 0.1, 0.1, 0.1)
    rng = np.random.default_rng(seed)
    if isinstance(start, str) and start == "global":
        return MonteCarloLocalization.uniform(field, motion, rng, free, MCLConfig(**cfg))
    mean, cov = start
    return MonteCarloLocalization.from_pose(field, motion, rng, mean, cov, MCLConfig(**cfg), free)


def test_fused_kernel_matches_reference(field):
    rng = np.random.default_rng(0)
    n = 40
    p0 = np.column_stack([rng.uniform(1, 19, n), rng.uniform(1, 11, n), rng.uniform(-3, 3, n)])
    noise = rng.standard_normal((n, 3))
    lx, ly = rng.uniform(-6, 6, 25), rng.uniform(-6, 6, 25)
    r1, tr, r2, s1, st, s2 = 0.1, 0.3, -0.2, 0.02, 0.05, 0.03
    parts = p0.copy()
    lw = np.full(n, -1.5)
    f = field.frame
    _kernels.odometry_predict_and_weight(
        parts,
        noise,
        r1,
        tr,
        r2,
        s1,
        st,
        s2,
        lx,
        ly,
        field.table,
        f.x0,
        f.y0,
        1 / f.resolution,
        field.outside,
        lw,
    )
    h, w = field.table.shape
    for k in range(n):
        x, y, th = p0[k]
        th1 = th + r1 - s1 * noise[k, 0]
        t = tr - st * noise[k, 1]
        x, y = x + t * math.cos(th1), y + t * math.sin(th1)
        th = (th1 + r2 - s2 * noise[k, 2] + math.pi) % (2 * math.pi) - math.pi
        assert np.allclose(parts[k], [x, y, th])
        acc = -1.5
        for b in range(25):
            ex = x + math.cos(th) * lx[b] - math.sin(th) * ly[b]
            ey = y + math.sin(th) * lx[b] + math.cos(th) * ly[b]
            ix, iy = math.floor((ex - f.x0) / f.resolution), math.floor((ey - f.y0) / f.resolution)
            acc += float(field.table[iy, ix]) if 0 <= ix < w and 0 <= iy < h else field.outside
        assert lw[k] == pytest.approx(acc, rel=1e-9)


def test_fused_update_equals_generic_update(world, field):
    # same noise draws -> same particles and weights through both code paths
    cov = np.diag([0.01, 0.01, 0.005])
    a = _mcl(field, 3, (world.poses[0], cov), n_particles=300)
    b = _mcl(field, 3, (world.poses[0], cov), n_particles=300)
    a.update_scan(world.odometry[0], world.odometry[1], world.ranges[1], world.angles)
    b.predict(world.odometry[0], world.odometry[1])
    b.correct(world.ranges[1], world.angles)
    b.resample_if_needed()
    assert np.allclose(a.particles, b.particles) and np.allclose(a.log_weights, b.log_weights)


def test_tracking_from_known_start(world, field):
    mcl = _mcl(field, 0, (world.poses[0], np.diag([0.02, 0.02, 0.01])), n_particles=500)
    err, dr = [], []
    for k in range(1, len(world.poses)):
        est = mcl.update_scan(
            world.odometry[k - 1], world.odometry[k], world.ranges[k], world.angles
        )
        err.append(np.hypot(*(est.mean[:2] - world.poses[k, :2])))
        dr.append(np.hypot(*(world.odometry[k, :2] - world.poses[k, :2])))
    assert np.median(err) < 0.06 and np.percentile(err, 95) < 0.15
    assert np.median(dr) > 5 * np.median(err)  # odometry alone drifts far more
    assert est.spread < 0.3


def test_global_localization_converges(world, field):
    # The floor plan repeats every 4 m (only the clutter differs), so start in a room, where
    # 100 updates see enough of it; the corridor alone is genuinely ambiguous.
    start, converged = 200, 0
    for seed in range(5):
        mcl = _mcl(field, seed, "global", n_particles=8000, augmented=True)
        errs = []
        for k in range(start + 1, start + 101):
            est = mcl.update_scan(
                world.odometry[k - 1], world.odometry[k], world.ranges[k], world.angles
            )
            errs.append(np.hypot(*(est.best_cluster[:2] - world.poses[k, :2])))
        converged += int(max(errs[-10:]) < 0.3)
    assert converged >= 4


def test_kidnapped_robot_recovers_only_with_augmented_mcl(world, field):
    # the pose jumps 10 m; recovery takes ~70 updates here (the rooms look much alike)
    jump_from, jump_to = 100, 240
    assert np.hypot(*(world.poses[jump_from, :2] - world.poses[jump_to, :2])) > 5.0
    for seed in (1, 2):
        final = {}
        for augmented in (True, False):
            start = (world.poses[0], np.diag([0.02, 0.02, 0.01]))
            mcl = _mcl(field, seed, start, n_particles=3000, augmented=augmented)
            steps = list(range(1, jump_from)) + list(range(jump_to + 1, jump_to + 90))
            for k in steps:
                est = mcl.update_scan(
                    world.odometry[k - 1], world.odometry[k], world.ranges[k], world.angles
                )
            final[augmented] = np.hypot(*(est.best_cluster[:2] - world.poses[steps[-1], :2]))
        assert final[True] < 0.3
        assert final[False] > 1.0


def test_kld_sampling_adapts_the_particle_count(world, field):
    from scipy.stats import chi2

    assert kld_sample_size(1, 0.05, 0.01) == 1
    # Wilson-Hilferty approximates chi2_{k-1, 1-delta} / (2 eps) (Fox 2003) to within 1 %
    for k in (2, 10, 100, 1000):
        exact = chi2.ppf(0.99, k - 1) / (2 * 0.05)
        assert abs(kld_sample_size(k, 0.05, 0.01) / exact - 1) < 0.01
    # Table 8.4 bound grows roughly linearly in the number of bins
    assert 2.5 < kld_sample_size(200, 0.05, 0.01) / kld_sample_size(60, 0.05, 0.01) < 4.0
    cfg = KLDConfig(epsilon=0.05, delta=0.01, n_min=200, n_max=8000)
    rng = np.random.default_rng(0)
    free = FreeSpaceSampler(field.spec, field.distance > 0.2)
    spread = free.sample(8000, rng)
    uniform = np.full(8000, 1 / 8000)
    assert kld_resample(spread, uniform, rng, cfg).size > 4000  # many bins: many particles
    peaked = np.zeros(8000)
    peaked[:3] = 1 / 3
    assert kld_resample(spread, peaked, rng, cfg).size == 200  # three bins: n_min
    # tracking with KLD-sampling keeps the count near n_min and stays accurate
    start = (world.poses[0], np.diag([0.02, 0.02, 0.01]))
    mcl = _mcl(field, 1, start, n_particles=2000, kld=cfg, resample_threshold=1.0)
    errs, counts = [], []
    for k in range(1, 150):
        est = mcl.update_scan(
            world.odometry[k - 1], world.odometry[k], world.ranges[k], world.angles
        )
        errs.append(np.hypot(*(est.mean[:2] - world.poses[k, :2])))
        counts.append(mcl.n)
    assert np.median(counts) < 1000 and np.median(errs) < 0.08


def test_landmark_mcl_with_velocity_model():
    rng = np.random.default_rng(4)
    lm = RangeBearingLandmarks(np.arange(6) + 10, rng.uniform(-5, 5, (6, 2)), 0.1, 0.05)
    model = VelocityMotionModel(0.05, 0.01, 0.01, 0.05, 0.001, 0.001)
    true = np.array([0.0, 0.0, 0.0])
    odo = true.copy()
    mcl = MonteCarloLocalization.from_pose(
        lm, model, np.random.default_rng(0), true, np.diag([0.01, 0.01, 0.01]),
        MCLConfig(n_particles=1000),
    )  # fmt: skip
    err, dr = [], []
    for t in range(300):
        u = np.array([0.5, 0.3 * math.sin(t / 20)])
        noisy = u + rng.normal(0, [0.1, 0.1])
        true = VelocityMotionModel(0, 0, 0, 0, 0, 0).sample(true[None], noisy, 0.2, rng)[0]
        odo = VelocityMotionModel(0, 0, 0, 0, 0, 0).sample(odo[None], u, 0.2, rng)[0]
        ids = rng.choice(lm.ids, 3, replace=False)
        d = lm.positions[ids - 10] - true[:2]
        z = np.column_stack(
            [
                np.hypot(d[:, 0], d[:, 1]) + rng.normal(0, 0.1, 3),
                np.arctan2(d[:, 1], d[:, 0]) - true[2] + rng.normal(0, 0.05, 3),
            ]
        )
        est = mcl.update((u, 0.2), (z, ids))
        err.append(np.hypot(*(est.mean[:2] - true[:2])))
        dr.append(np.hypot(*(odo[:2] - true[:2])))
    assert np.median(err) < 0.15
    assert np.median(dr) > 3 * np.median(err)


def test_landmark_log_likelihood_closed_form():
    lm = RangeBearingLandmarks(np.array([7]), np.array([[3.0, 4.0]]), 0.2, 0.1)
    z = np.array([[5.1, np.arctan2(4, 3) - 0.5 + 0.05]])
    ll = lm.log_likelihood(np.array([[0.0, 0.0, 0.5]]), z, [7])
    expect = -0.5 * ((0.1 / 0.2) ** 2 + (0.05 / 0.1) ** 2) - math.log(2 * math.pi * 0.02)
    assert ll[0, 0] == pytest.approx(expect)
    robust = RangeBearingLandmarks(np.array([7]), np.array([[3.0, 4.0]]), 0.2, 0.1, 0.1, 20.0)
    got = robust.log_likelihood(np.array([[0.0, 0.0, 0.5]]), z, [7])[0, 0]
    assert got == pytest.approx(math.log(0.9 * math.exp(expect) + 0.1 / (20 * 2 * math.pi)))
    with pytest.raises(ValueError, match="unknown landmark id 3"):
        lm.log_likelihood(np.zeros((1, 3)), z, [3])


class _Impossible:
    def log_likelihood_sum(self, poses, *z):
        return np.full(poses.shape[0], -np.inf)


def test_all_zero_weights_reinitialise_and_warn(field):
    free = FreeSpaceSampler(field.spec, field.distance > 0.2)
    mcl = MonteCarloLocalization.from_pose(
        _Impossible(),
        OdometryMotionModel(),
        np.random.default_rng(0),
        [5.0, 6.0, 0.0],
        np.eye(3) * 0.01,
        MCLConfig(n_particles=100),
        free,
    )
    with pytest.warns(ParticleFilterWarning, match="reinitialised"):
        mcl.correct(None)
    est = mcl.estimate()
    assert np.all(np.isfinite(est.mean)) and np.all(np.isfinite(mcl.weights))
    assert est.spread > 2.0  # spread over the building again
    plain = MonteCarloLocalization(
        _Impossible(),
        OdometryMotionModel(),
        np.random.default_rng(0),
        MCLConfig(n_particles=10),
        particles=np.zeros((10, 3)),
    )
    with pytest.warns(ParticleFilterWarning, match="weights reset"):
        plain.correct(None)
    assert np.allclose(plain.weights, 0.1)


def test_bad_configuration(field):
    with pytest.raises(ValueError, match="n_particles"):
        MCLConfig(n_particles=0)
    with pytest.raises(ValueError, match="alpha_slow"):
        MCLConfig(alpha_slow=0.5, alpha_fast=0.1)
    with pytest.raises(ValueError, match="free_space"):
        MonteCarloLocalization(
            field,
            OdometryMotionModel(),
            np.random.default_rng(0),
            MCLConfig(augmented=True),
            particles=np.zeros((10, 3)),
        )
    with pytest.raises(ValueError, match="no free cell"):
        FreeSpaceSampler(field.spec, np.zeros(field.spec.shape, dtype=bool))


def test_random_fraction_capped_and_switchable(world, field):
    start = (world.poses[0], np.eye(3) * 0.01)
    mcl = _mcl(field, 0, start, n_particles=100, augmented=True, max_random_fraction=0.05)
    mcl.w_slow, mcl.w_fast = 1.0, 0.2  # the book's fraction: 1 - 0.2 = 0.8
    assert mcl.random_fraction() == 0.05
    mcl.augment = False  # as the pipeline switches it while tracking well
    assert mcl.random_fraction() == 0.0
    off = _mcl(field, 0, start, n_particles=100)  # not augmented: averages kept, none injected
    off.update_scan(world.odometry[0], world.odometry[1], world.ranges[1], world.angles)
    assert off.w_slow > 0 and off.random_fraction() == 0.0
    with pytest.raises(ValueError, match="max_random_fraction"):
        MCLConfig(max_random_fraction=1.5)


def test_standing_still_changes_nothing(world, field):
    """No weighting and no resampling while the odometry has not moved (particle deprivation)."""
    mcl = _mcl(field, 0, (world.poses[0], np.eye(3) * 0.01), n_particles=200)
    before = mcl.particles.copy()
    for _ in range(100):
        mcl.update_scan(world.odometry[0], world.odometry[0], world.ranges[0], world.angles)
    assert np.array_equal(mcl.particles, before) and np.allclose(mcl.weights, 1 / 200)


def test_likelihood_exponent():
    from probmap.filters.mcl import mcl_likelihood_exponent

    assert mcl_likelihood_exponent(60, 10.0) == pytest.approx(1 / 6)
    assert mcl_likelihood_exponent(8, 10.0) == 1.0 and mcl_likelihood_exponent(60, None) == 1.0
    with pytest.raises(ValueError, match="independent_measurements"):
        MCLConfig(independent_measurements=0.0)


def test_restart_draws_a_fresh_uniform_set_over_free_space(field):
    """A stuck global localization starts again: every particle on a free cell, as many as
    configured, uniform weights, augmented MCL's averages cleared; the old set is gone."""
    free_mask = field.distance > 0.2
    free = FreeSpaceSampler(field.spec, free_mask)
    cfg = MCLConfig(n_particles=4000)
    rng = np.random.default_rng(3)
    mcl = MonteCarloLocalization.from_pose(
        field, OdometryMotionModel(), rng, [5.0, 5.0, 0.0], np.diag([1e-4, 1e-4, 1e-4]), cfg, free
    )
    mcl.particles = mcl.particles[:1000].copy()  # KLD-sampling may have shrunk the set
    mcl.log_weights = np.log(np.r_[1.0, np.full(999, 1e-9)])
    mcl.w_slow, mcl.w_fast = 0.3, 0.1
    mcl.restart()
    p = mcl.particles
    assert p.shape == (4000, 3)
    res = field.spec.resolution
    ix = np.floor((p[:, 0] - field.spec.origin[0]) / res).astype(int)
    iy = np.floor((p[:, 1] - field.spec.origin[1]) / res).astype(int)
    assert free_mask[iy, ix].all()
    assert np.hypot(p[:, 0] - 5.0, p[:, 1] - 5.0).mean() > 2.0  # no longer at the old pose
    assert np.allclose(mcl.weights, 1 / 4000)
    assert (mcl.w_slow, mcl.w_fast) == (0.0, 0.0)
    assert np.ptp(p[:, 2]) > 6.0  # headings over the whole circle
    with pytest.raises(ValueError, match="free_space"):
        MonteCarloLocalization.from_pose(
            field, OdometryMotionModel(), rng, [5.0, 5.0, 0.0], np.eye(3) * 1e-4, cfg
        ).restart()


def test_resize_draws_the_weighted_set_to_a_new_count(world, field):
    rng = np.random.default_rng(3)
    free = FreeSpaceSampler(field.spec, field.distance > 0.2)
    mcl = MonteCarloLocalization.uniform(
        field, OdometryMotionModel(0.1, 0.1, 0.1, 0.1), rng, free, MCLConfig(n_particles=400)
    )
    w = np.zeros(400)
    w[:4] = [0.1, 0.2, 0.3, 0.4]  # four particles carry all the weight
    mcl.log_weights = np.log(np.maximum(w, 1e-300))
    kept = mcl.particles[:4].copy()
    mcl.resize(5000)
    assert mcl.n == 5000 and np.allclose(mcl.weights, 1 / 5000)
    # low-variance: each of the four appears in proportion to its weight, to one particle
    for i, wi in enumerate(w[:4]):
        assert abs(np.sum(np.all(mcl.particles == kept[i], axis=1)) - wi * 5000) <= 1
    with pytest.raises(ValueError, match="at least 1"):
        mcl.resize(0)
