"""MCL's robust weighting (probmap.filters.mcl_robust): beams that run through the map's walls
count as random readings, and a few particles follow the odometry reversed (issue 37,
Freiburg 079). Kernels against pure-Python references, and what each part changes."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from probmap.filters import _kernels
from probmap.geometry.se2 import between, compose
from probmap.grid.raycast import cast_rays
from probmap.grid.spec import GridSpec
from probmap.models.likelihood_field import LikelihoodField
from probmap.pipelines.localize import LocalizeConfig, localize_scans
from probmap.sim.localization import simulate_localization_world


@pytest.fixture(scope="module")
def world():
    return simulate_localization_world(0)


@pytest.fixture(scope="module")
def field(world):
    return LikelihoodField(world.spec, world.occupied, max_range=world.max_range)


def _reference_walls(lf, poses, lx, ly, origin, margin):
    """log_likelihood_sum_walls in plain Python: the endpoint's table entry, or the floor where
    the exact cast (cast_rays) from the centre of the laser's 0.1 m block at the nearest whole
    degree meets a wall more than ``margin`` short of the beam's range."""
    f = lf.frame
    h, w = lf.table.shape
    block = round(0.1 / f.resolution)
    out = []
    for x, y, th in poses:
        c, s = math.cos(th), math.sin(th)
        px = x + c * origin[0] - s * origin[1]
        py = y + s * origin[0] + c * origin[1]
        gx, gy = (px - f.x0) / f.resolution, (py - f.y0) / f.resolution
        bx, by = int(gx) // block, int(gy) // block
        cx = f.x0 + min((bx + 0.5) * block, w - 0.5) * f.resolution
        cy = f.y0 + min((by + 0.5) * block, h - 0.5) * f.resolution
        acc = 0.0
        for ex, ey in zip(lx, ly, strict=True):
            ix = math.floor((x + c * ex - s * ey - f.x0) / f.resolution)
            iy = math.floor((y + s * ex + c * ey - f.y0) / f.resolution)
            v = float(lf.table[iy, ix]) if 0 <= ix < w and 0 <= iy < h else lf.outside
            rng = math.hypot(ex - origin[0], ey - origin[1])
            if v > lf.outside and rng > margin:
                k = round((th + math.atan2(ey - origin[1], ex - origin[0])) / math.radians(1.0))
                heading = [math.radians(k % 360)]
                wall = cast_rays(lf.occupied, lf.spec, (cx, cy, 0.0), heading, 1e3)[0]
                if wall + margin < rng:
                    v = lf.outside
            acc += v
        out.append(acc)
    return np.array(out)


def _poses_and_beams(world, lf, seed):
    """Free poses, and beams of random length (some through walls) that no wall meets within
    2 cm of the margin's end (where the cast's 1 cm steps could decide either way)."""
    rng = np.random.default_rng(seed)
    poses = world.poses[rng.choice(world.poses.shape[0], 12, replace=False)].copy()
    poses[:, 2] += rng.normal(0.0, 0.5, 12)
    a = rng.uniform(-math.pi, math.pi, 40)
    r = rng.uniform(0.3, 7.0, 40)
    return poses, r * np.cos(a), r * np.sin(a)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_walls_kernel_matches_the_reference(world, field, seed):
    poses, lx, ly = _poses_and_beams(world, field, seed)
    origin = (0.1, -0.05)
    got = field.log_likelihood_sum_walls(poses, lx, ly, origin, 0.5)
    want = _reference_walls(field, poses, lx, ly, origin, 0.5)
    plain = field.log_likelihood_sum_prepared(poses, lx, ly, np.ones(lx.size, bool))
    close = np.isclose(got, want, atol=1e-3)
    # a beam whose wall lies within 1 cm of the margin's end may be judged either way
    assert close.mean() >= 0.9, np.c_[got, want]
    assert np.all(got <= plain + 1e-3)  # never more than the plain field
    assert np.any(got < plain - 1.0)  # and some beams did run through walls


def test_fused_robust_kernel_matches_its_parts(world, field):
    rng = np.random.default_rng(3)
    n = 30
    p0 = world.poses[rng.choice(world.poses.shape[0], n)].copy()
    noise = rng.standard_normal((n, 3))
    _, lx, ly = _poses_and_beams(world, field, 4)
    origin = np.array([0.1, 0.0])
    angle, length = field.wall_beams(lx, ly, origin)
    f = field.frame
    r1, tr, r2, s1, st, s2 = 0.1, 0.3, -0.2, 0.02, 0.05, 0.03
    for walls, every in ((True, 0), (False, 4), (True, 4)):
        parts = p0.copy()
        lw = np.zeros(n)
        _kernels.odometry_predict_and_weight_robust(
            parts, noise, r1, tr, r2, s1, st, s2, lx, ly, field.table, f.x0, f.y0,
            1 / f.resolution, field.outside, walls, 0.1, 0.0, angle, length, 0.5 / f.resolution,
            *field.wall_cache(), every, 1, lw,
        )  # fmt: skip
        want = p0.copy()
        for k in range(n):  # Table 5.6 with the translation reversed for every 4th particle
            h1 = r1 - s1 * noise[k, 0]
            ht = (tr - st * noise[k, 1]) * (-1 if every and (k + 1) % every == 0 else 1)
            th = p0[k, 2] + h1
            want[k, :2] += ht * np.array([math.cos(th), math.sin(th)])
            want[k, 2] = math.remainder(th + r2 - s2 * noise[k, 2], 2 * math.pi)
        np.testing.assert_allclose(parts, want, atol=1e-9)
        ll = (
            field.log_likelihood_sum_walls(want, lx, ly, origin, 0.5)
            if walls
            else field.log_likelihood_sum_prepared(want, lx, ly, np.ones(lx.size, bool))
        )
        np.testing.assert_allclose(lw, ll, atol=1e-3)


def test_a_turned_pose_whose_beams_cross_walls_loses_its_lead():
    """A corridor-like room whose end wall the map lacks (seen through a glass door by other
    passes), and, 0.8 m behind its side wall, a wall where the end wall's beams end when the
    robot is turned by 40 degrees. From the right pose most beams end in the map's free space;
    the likelihood field prefers the turned pose, whose beams run through the side wall.
    Counting beams through walls as random readings, the right heading wins again."""
    spec = GridSpec(resolution=0.05, origin=(0.0, 0.0), shape=(200, 200))
    truth = np.zeros(spec.shape, dtype=bool)
    truth[130:132, 40:170] = truth[68:70, 40:170] = True  # side walls: y 3.4-3.5, 6.5-6.6 m
    truth[68:132, 100:102] = True  # the end wall: x 5.0-5.1 m
    mapped = truth.copy()
    mapped[70:130, 100:102] = False  # missing from the map
    robot = np.array([2.0, 5.0, 0.0])
    for a in np.radians(np.linspace(-27, 27, 400)):  # the end wall turned by 40 degrees
        p = robot[:2] + 3.0 / math.cos(a) * np.array([math.cos(a + 0.698), math.sin(a + 0.698)])
        if p[1] > 7.3 and p[0] < 8.0:  # where it lies behind the side wall
            mapped[int(p[1] / 0.05), int(p[0] / 0.05)] = True
    lf = LikelihoodField(spec, mapped, max_range=8.0)
    a = np.radians(np.linspace(-30, 30, 61))
    r = cast_rays(truth, spec, robot, a, 8.0)
    lx, ly = r * np.cos(a), r * np.sin(a)
    grid = np.mgrid[-60:61:5, -2:3, -2:3].reshape(3, -1).T
    cand = np.column_stack(
        [robot[0] + 0.125 * grid[:, 1], robot[1] + 0.125 * grid[:, 2], np.radians(grid[:, 0])]
    )
    plain = cand[np.argmax(lf.log_likelihood_sum_prepared(cand, lx, ly, np.ones(a.size, bool)))]
    walls = cand[np.argmax(lf.log_likelihood_sum_walls(cand, lx, ly))]
    assert abs(plain[2]) > math.radians(30)  # the field alone: a turned pose
    assert abs(walls[2]) < math.radians(3)  # beams through walls counted: the right heading
    assert abs(walls[1] - robot[1]) < 0.2  # (along the room, the scan cannot tell)


def _lying_odometry(world, at, n):
    odo = world.odometry
    steps = np.asarray(between(odo[:-1], odo[1:]))
    steps[at : at + n, 0] *= -1  # forward driving logged as reversing
    lying = np.vstack([odo[:1], np.zeros_like(steps)])
    for k, s in enumerate(steps):
        lying[k + 1] = compose(lying[k], s)
    return lying


@pytest.mark.parametrize("at", [60, 200])
def test_reversed_odometry_carries_the_cloud_less_far(world, at):
    """2 m of driving logged the wrong way (8 steps), without the scan match near the estimate
    (``match_window``) that also follows it: the cloud that moves only as the odometry says is
    carried 4.9-18 m off; once the scans stop fitting, the few particles moved by the odometry
    reversed keep it within 1.6-2.9 m."""
    lying = _lying_odometry(world, at, 8)
    n = world.ranges.shape[0]
    errs = {}
    for frac in (0.0, LocalizeConfig().reverse_fraction):
        cfg = LocalizeConfig(
            initial_pose=tuple(world.poses[0]), match_window=None, reverse_fraction=frac
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            run = localize_scans(
                world.spec, world.occupied.astype(float), 0.2 * np.arange(n), world.ranges,
                world.angles, lying, world.max_range, cfg,
            )  # fmt: skip
        errs[frac] = np.hypot(*(run.poses[:, :2] - world.poses[run.scan_index, :2]).T).max()
    assert errs[0.0] > 4.0  # carried away by the odometry
    assert errs[LocalizeConfig().reverse_fraction] < 0.6 * errs[0.0]


def test_robust_parts_are_off_outside_tracking_and_validated():
    with pytest.raises(ValueError, match="reverse_fraction"):
        LocalizeConfig(reverse_fraction=0.7)
    with pytest.raises(ValueError, match="wall_margin"):
        LocalizeConfig(wall_margin=-1.0)
