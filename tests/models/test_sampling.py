"""Sampled motion models: closed forms, sample moments against the model's variances,
densities at constructed poses, noise-free limits and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.models.sampling import (
    OdometryMotionModel,
    VelocityMotionModel,
    motion_model_odometry,
    odometry_deltas,
    odometry_step_count,
    wrap_angle,
)


def _normal(a, var):
    return np.exp(-0.5 * a * a / var) / np.sqrt(2 * np.pi * var)


def _compose_odometry(pose, rot1, trans, rot2):
    x, y, th = pose
    h = th + rot1
    return np.array([x + trans * np.cos(h), y + trans * np.sin(h), th + rot1 + rot2])


def test_odometry_deltas_closed_form():
    r1, tr, r2 = odometry_deltas(
        [1.0, 2.0, 0.3], [1.0 + 2 * np.cos(0.5), 2.0 + 2 * np.sin(0.5), 1.4]
    )
    assert np.isclose(r1, 0.2) and np.isclose(tr, 2.0) and np.isclose(r2, 0.9)
    r1, tr, r2 = odometry_deltas([0, 0, 0.1], [0, 0, 0.6])  # rotation in place
    assert r1 == 0.0 and tr == 0.0 and np.isclose(r2, 0.5)


def test_odometry_sample_moments_match_table_5_6():
    alphas = (0.02, 0.01, 0.03, 0.05)
    model = OdometryMotionModel(*alphas)
    start = np.array([2.0, -1.0, 0.4])
    u0, u1 = np.array([0.0, 0.0, 0.0]), _compose_odometry([0.0, 0.0, 0.0], 0.3, 1.5, -0.2)
    n = 40000
    out = model.sample(np.tile(start, (n, 1)), u0, u1, np.random.default_rng(0))
    # Recover the sampled (rot1, trans, rot2) per particle and compare with the model.
    h1, ht, h2 = odometry_deltas(np.tile(start, (n, 1)), out)
    r1, tr, r2 = 0.3, 1.5, -0.2
    var = [
        alphas[0] * r1**2 + alphas[1] * tr**2,
        alphas[2] * tr**2 + alphas[3] * (r1**2 + r2**2),
        alphas[0] * r2**2 + alphas[1] * tr**2,
    ]
    for s, mu, v in zip((h1, ht, h2), (r1, tr, r2), var, strict=True):
        assert abs(s.mean() - mu) < 5 * np.sqrt(v / n)
        # sample variance of n normals: relative standard error sqrt(2/n)
        assert abs(s.var() / v - 1) < 5 * np.sqrt(2 / n)


def test_odometry_density_at_constructed_pose():
    alphas = (0.05, 0.02, 0.04, 0.01)
    u0 = np.array([1.0, 1.0, 0.5])
    u1 = _compose_odometry(u0, 0.2, 0.8, 0.1)
    old = np.array([3.0, -2.0, 1.0])
    h1, ht, h2 = 0.25, 0.7, 0.05
    new = _compose_odometry(old, h1, ht, h2)
    expected = (
        _normal(0.2 - h1, alphas[0] * h1**2 + alphas[1] * ht**2)
        * _normal(0.8 - ht, alphas[2] * ht**2 + alphas[3] * (h1**2 + h2**2))
        * _normal(0.1 - h2, alphas[0] * h2**2 + alphas[1] * ht**2)
    )
    got = OdometryMotionModel(*alphas).probability(new, u0, u1, old)
    assert np.isclose(got, expected, rtol=1e-10)
    # batched form agrees
    both = motion_model_odometry(np.stack([new, new]), u0, u1, np.stack([old, old]), alphas)
    assert np.allclose(both, expected)


def test_odometry_noise_free_is_exact():
    u0, u1 = np.array([0.0, 0.0, 0.0]), np.array([1.0, 1.0, np.pi / 2])
    poses = np.array([[5.0, 5.0, np.pi], [0.0, 0.0, 0.0]])
    out = OdometryMotionModel(0, 0, 0, 0).sample(poses, u0, u1, np.random.default_rng(0))
    assert np.allclose(out[1], [1.0, 1.0, np.pi / 2])
    assert np.allclose(out[0], [4.0, 4.0, wrap_angle(3 * np.pi / 2)])


def _arc(pose, v, w, dt):
    x, y, th = pose
    r = v / w
    return np.array(
        [
            x - r * np.sin(th) + r * np.sin(th + w * dt),
            y + r * np.cos(th) - r * np.cos(th + w * dt),
            th + w * dt,
        ]
    )


def test_velocity_noise_free_follows_the_arc():
    m = VelocityMotionModel(0, 0, 0, 0, 0, 0)
    pose = np.array([1.0, 2.0, 0.3])
    out = m.sample(pose[None], [1.0, 0.5], 2.0, np.random.default_rng(0))[0]
    # centre of the circle is (x - r sin th, y + r cos th) with r = v / w = 2: stays at distance 2
    cx, cy = 1.0 - 2 * np.sin(0.3), 2.0 + 2 * np.cos(0.3)
    assert np.isclose(np.hypot(out[0] - cx, out[1] - cy), 2.0)
    assert np.isclose(out[2], 1.3)
    straight = m.sample(pose[None], [1.0, 0.0], 2.0, np.random.default_rng(0))[0]
    assert np.allclose(straight, [1 + 2 * np.cos(0.3), 2 + 2 * np.sin(0.3), 0.3])


@pytest.mark.parametrize(("v", "w"), [(1.0, 0.5), (1.0, -0.4), (-0.5, 0.3), (0.8, 1e-14)])
def test_velocity_density_at_constructed_pose(v, w):
    alphas = (0.1, 0.05, 0.05, 0.1, 0.02, 0.02)
    old = np.array([0.5, -1.0, 0.7])
    dt = 1.0
    vp, wp, gp = v * 1.05 + 0.01, w + 0.03, 0.02
    new = _arc(old, vp, wp, dt)
    new[2] += gp * dt
    expected = (
        _normal(v - vp, alphas[0] * v * v + alphas[1] * w * w)
        * _normal(w - wp, alphas[2] * v * v + alphas[3] * w * w)
        * _normal(-gp, alphas[4] * v * v + alphas[5] * w * w)
    )
    got = VelocityMotionModel(*alphas).probability(new, [v, w], dt, old)
    assert np.isclose(got, expected, rtol=1e-6)


def test_velocity_sample_recovers_velocity_moments():
    alphas = (0.05, 0.02, 0.03, 0.04, 0.0, 0.0)
    v, w, dt, n = 1.0, 0.6, 0.5, 20000
    out = VelocityMotionModel(*alphas).sample(
        np.zeros((n, 3)), [v, w], dt, np.random.default_rng(2)
    )
    w_hat = out[:, 2] / dt  # gamma is zero, so heading change is w_hat dt
    var_w = alphas[2] * v * v + alphas[3] * w * w
    assert abs(w_hat.mean() - w) < 5 * np.sqrt(var_w / n)
    assert abs(w_hat.var() / var_w - 1) < 5 * np.sqrt(2 / n)


@pytest.mark.parametrize(
    "make",
    [lambda: OdometryMotionModel(-0.1), lambda: VelocityMotionModel(alpha6=float("nan"))],
)
def test_bad_alphas(make):
    with pytest.raises(ValueError, match="alpha"):
        make()


def test_bad_shapes_and_controls():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        OdometryMotionModel().sample(np.zeros((4, 2)), np.zeros(3), np.ones(3), rng)
    with pytest.raises(ValueError, match="dt"):
        VelocityMotionModel().sample(np.zeros((4, 3)), [1.0, 0.0], 0.0, rng)
    with pytest.raises(ValueError, match="control"):
        VelocityMotionModel().sample(np.zeros((4, 3)), [1.0], 1.0, rng)


def test_reversing_is_not_noisier_than_driving_forwards():
    # Backing up 1 m reads as rot1 = pi, trans = 1, rot2 = -pi; the rotation noise must scale
    # with the small turn relative to reversing (0 here), not with pi.
    alphas = (0.1, 0.0, 0.0, 0.1)
    model = OdometryMotionModel(*alphas)
    rng = np.random.default_rng(0)
    start = np.zeros((2000, 3))
    back = model.sample(start, [0.0, 0.0, 0.0], [-1.0, 0.0, 0.0], rng)
    fwd = model.sample(start, [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], rng)
    assert np.allclose(back[:, :2].mean(axis=0), [-1.0, 0.0], atol=0.01)
    assert np.std(back[:, 2]) < 1e-9 and np.std(fwd[:, 2]) < 1e-9
    # a turn in place with encoder jitter of 5 mm: no phantom rotations of order pi
    # (sideways, so a naive atan2 would read it as rot1 = pi/2 then rot2 = -pi/2 + 0.5)
    jitter = model.sample(start, [0.0, 0.0, 0.0], [0.0, 0.005, 0.5], rng)
    expected = 0.5 * np.sqrt(0.1)  # only rot2 = 0.5 is noisy: sd sqrt(alpha1) * 0.5
    assert abs(np.std(jitter[:, 2]) / expected - 1) < 0.1


def test_unit_step_gives_a_long_step_the_noise_of_its_chain_of_short_ones():
    """A 1 m straight step with ``unit_step = 0.1``: its heading variance is that of ten
    0.1 m steps sampled one after another (Table 5.6 as printed: ten times more)."""
    alphas = (0.3, 0.1, 0.1, 0.3)
    n = 40000
    start = np.zeros((n, 3))
    u0, u1 = np.zeros(3), np.array([1.0, 0.0, 0.0])
    assert odometry_step_count(1.0, 0.1) == pytest.approx(10.0)
    assert odometry_step_count(0.05, 0.1) == 1.0  # never more noise than as printed
    assert odometry_step_count(1.0, None) == 1.0
    rng = np.random.default_rng(1)
    one = OdometryMotionModel(*alphas, unit_step=0.1).sample(start, u0, u1, rng)
    printed = OdometryMotionModel(*alphas).sample(start, u0, u1, rng)
    chain = start.copy()
    short = OdometryMotionModel(*alphas)
    for k in range(10):
        chain = short.sample(chain, [0.1 * k, 0.0, 0.0], [0.1 * (k + 1), 0.0, 0.0], rng)
    # heading: rot1 + rot2, each of variance alpha2 trans^2 per step, k steps of trans / k
    var_chain = 2 * alphas[1] * 1.0**2 / 10
    tol = 5 * np.sqrt(2 / n)
    assert abs(np.var(chain[:, 2]) / var_chain - 1) < tol
    assert abs(np.var(one[:, 2]) / var_chain - 1) < tol
    assert abs(np.var(printed[:, 2]) / (10 * var_chain) - 1) < tol
    # the density is the sampler's: the same variances divided by the same count
    new = np.array([1.02, 0.03, 0.05])
    h1, ht, h2 = odometry_deltas(np.zeros(3), new)
    expected = (
        _normal(0.0 - h1, (alphas[0] * h1**2 + alphas[1] * ht**2) / 10)
        * _normal(1.0 - ht, (alphas[2] * ht**2 + alphas[3] * (h1**2 + h2**2)) / 10)
        * _normal(0.0 - h2, (alphas[0] * h2**2 + alphas[1] * ht**2) / 10)
    )
    got = motion_model_odometry(new, u0, u1, np.zeros(3), alphas, 0.1)
    assert np.isclose(got, expected, rtol=1e-10)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_unit_step(bad):
    with pytest.raises(ValueError, match="unit_step"):
        OdometryMotionModel(unit_step=bad)
