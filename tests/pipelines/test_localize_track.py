"""The pose a tracking run reports, and the strays it must report (issue 37).

- The particle cloud's mean jitters by about the cloud's spread; the reported pose is the
  scan's fit to the map with the cloud as prior (``refine_pose``), measurably nearer the
  truth where the scan constrains it, and the cloud's mean where it does not (along a
  corridor, or where the scan fits nowhere).
- Between updates the run follows the odometry (``odometry_track``), not a straight line.
- An estimate that turns against the odometry while its beams cross the map's walls says so
  (``LocalizeConfig.lost_turn``); one that turns with scans that fit (the odometry's heading
  is what is off) does not.
"""

from __future__ import annotations

import math
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from probmap.geometry.se2 import between, compose, inverse
from probmap.models.beam import BeamModel
from probmap.models.likelihood_field import LikelihoodField
from probmap.pipelines._localize_track import (
    RefineConfig,
    odometry_track,
    refine_pose,
    turned_against_odometry,
)
from probmap.pipelines.localize import LocalizeConfig, interpolate_run, localize_scans
from probmap.sim.localization import simulate_localization_world


@pytest.fixture(scope="module")
def world():
    return simulate_localization_world(0)


def _field(w):
    return LikelihoodField(w.spec, w.occupied, max_range=w.max_range, sigma_hit=0.15)


def _mapped(w):
    """A map made as ``slam grid`` makes one: the cells the scans' endpoints fall in, seen from
    the true poses. (The simulator's beams stop at the faces of the world's wall cells, half a
    cell before the centres the distance field measures to: its own map would bias every fit
    by 2.5 cm.)"""
    occ = np.zeros(w.occupied.shape, dtype=bool)
    res = w.spec.resolution
    x0, y0 = w.spec.origin
    for p, r in zip(w.poses, w.ranges, strict=True):
        ok = r < w.max_range
        ex = p[0] + r[ok] * np.cos(p[2] + w.angles[ok])
        ey = p[1] + r[ok] * np.sin(p[2] + w.angles[ok])
        occ[np.floor((ey - y0) / res).astype(int), np.floor((ex - x0) / res).astype(int)] = True
    return occ


def _mapped_field(w):
    return LikelihoodField(w.spec, _mapped(w), max_range=w.max_range, sigma_hit=0.15)


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def test_refined_pose_is_nearer_the_truth_than_the_cloud_mean(world):
    lf = _mapped_field(world)
    rng = np.random.default_rng(1)
    cov = np.diag([0.05**2, 0.05**2, math.radians(2.0) ** 2])
    before, after, used = [], [], 0
    for k in range(0, world.poses.shape[0], 3):
        truth = world.poses[k]
        mean = truth + rng.multivariate_normal(np.zeros(3), cov)  # a cloud mean off by ~5 cm
        lx, ly, ok = lf.endpoints(world.ranges[k], world.angles)
        out = refine_pose(lf, mean, cov, lx[ok], ly[ok])
        used += out.used
        before.append(math.hypot(*(mean[:2] - truth[:2])))
        after.append(math.hypot(*(out.pose[:2] - truth[:2])))
    assert used >= 0.9 * len(before)
    assert np.median(after) < 0.3 * np.median(before)  # 5 cm -> 1 cm
    assert np.percentile(after, 90) < 0.03


def _corridor():
    """Two walls 2 m apart along x (y = 1 and y = 3), 60 m long: nothing to see along it."""
    spec = SimpleNamespace(resolution=0.05, origin=(0.0, 0.0), shape=(80, 1200))
    occ = np.zeros(spec.shape, dtype=bool)
    occ[19, :] = occ[60, :] = True  # cell centres y = 0.975, 3.025
    return spec, occ


def test_refinement_keeps_the_mean_along_a_corridor():
    spec, occ = _corridor()
    truth = np.array([30.0, 2.0, 0.0])
    angles = np.linspace(-np.pi / 2, np.pi / 2, 61)
    ranges = BeamModel(spec, occ, max_range=8.0).expected_ranges(truth[None], angles)[0]
    lf = LikelihoodField(spec, occ, max_range=8.0)
    lx, ly, ok = lf.endpoints(ranges, angles)
    mean = truth + np.array([0.15, 0.06, math.radians(1.5)])  # 15 cm along, 6 cm across
    cov = np.diag([0.09**2, 0.05**2, math.radians(3.0) ** 2])  # longer along the corridor
    out = refine_pose(lf, mean, cov, lx[ok], ly[ok])
    assert out.used
    assert abs(out.pose[1] - truth[1]) < 0.02  # across: the walls say where
    assert abs(out.pose[2]) < math.radians(0.5)
    assert abs(out.pose[0] - mean[0]) < 0.01  # along: the scan says nothing, the prior holds
    # a cloud stretched further along it (0.5 m) reports its mean as it is
    wide = refine_pose(lf, mean, np.diag([0.5**2, 0.05**2, 0.05**2]), lx[ok], ly[ok])
    assert not wide.used
    np.testing.assert_array_equal(wide.pose, mean)


def test_refinement_reports_the_mean_where_the_scan_fits_nowhere(world):
    lf = _field(world)
    k = 40
    lx, ly, ok = lf.endpoints(world.ranges[k], world.angles)
    mean = world.poses[k] + np.array([0.0, 0.0, np.pi / 2])  # the scan turned by 90 deg
    cov = np.diag([0.05**2, 0.05**2, 0.03**2])
    out = refine_pose(lf, mean, cov, lx[ok], ly[ok])
    assert not out.used and out.inliers < RefineConfig().min_inliers
    np.testing.assert_array_equal(out.pose, mean)


def _circle(n, radius=2.0, arc=np.pi):
    t = np.linspace(0.0, arc, n)
    return np.column_stack([radius * np.sin(t), radius * (1 - np.cos(t)), t])


def test_odometry_track_follows_the_curve_between_updates():
    odo = _circle(41)
    shift = np.array([5.0, -1.0, 0.3])  # the map frame: the odometry moved and turned
    truth = np.asarray(compose(shift, odo))
    idx = np.arange(0, 41, 8)
    est = truth[idx] + np.array([0.01, -0.01, 0.002])  # the updates' estimates, a bit off
    scans, track = odometry_track(odo, idx, est)
    np.testing.assert_array_equal(scans, np.arange(41))
    np.testing.assert_allclose(track[idx], est, atol=1e-12)  # exact at the updates
    err = np.hypot(*(track[:, :2] - truth[:, :2]).T)
    chord = np.column_stack([np.interp(scans, idx, est[:, i]) for i in range(2)])
    chord_err = np.hypot(*(chord - truth[:, :2]).T)
    assert err.max() < 0.02  # the estimates' own offset, no more
    assert chord_err.max() > 0.05  # a straight line cuts the curve by several centimetres


def test_odometry_track_follows_the_filter_where_the_odometry_drives_the_wrong_way():
    truth = np.column_stack([np.linspace(0.0, -1.0, 11), np.zeros(11), np.zeros(11)])  # back
    odo = truth.copy()
    odo[:, 0] *= -1  # logged as forward driving
    _, track = odometry_track(odo, np.array([0, 10]), truth[[0, 10]])
    np.testing.assert_allclose(track, truth, atol=1e-9)


def test_run_reports_refined_poses_and_follows_the_odometry_between_updates(world):
    n = world.ranges.shape[0]
    times = 0.2 * np.arange(n)
    runs = {}
    for refine in (False, True):
        cfg = LocalizeConfig(initial_pose=tuple(world.poses[0]), refine=refine)
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # neither may lose track
            runs[refine] = localize_scans(
                world.spec, _mapped(world).astype(float), times, world.ranges, world.angles,
                world.odometry, world.max_range, cfg,
            )  # fmt: skip
    # the same cloud: refinement leaves the particles alone
    np.testing.assert_array_equal(runs[False].spread, runs[True].spread)
    err = {
        r: np.hypot(*(run.poses[:, :2] - world.poses[run.scan_index, :2]).T)
        for r, run in runs.items()
    }
    assert np.median(err[True]) < 0.5 * np.median(err[False])  # 3.3 cm -> 0.9 cm
    run = runs[True]
    assert run.track_times.size == run.scan_index[-1] - run.scan_index[0] + 1  # every scan
    # exact at the updates; between them by the odometry (test_odometry_track_* above)
    np.testing.assert_allclose(interpolate_run(run, run.times), run.poses, atol=1e-9)
    assert np.isnan(interpolate_run(run, [run.times[0] - 1.0])).all()


def test_turned_against_odometry_sums_over_its_window():
    odo = np.zeros((30, 3))
    odo[:, 2] = np.radians(np.arange(30))  # the odometry turns 1 deg per scan
    turns: list[tuple[int, float]] = []
    prev = None
    for k in range(30):
        pose = np.array([0.0, 0.0, math.radians(3.0 * k)])  # the estimate 3 deg per scan
        first, turned = turned_against_odometry(turns, k, pose, odo, prev, 5)
        prev = (k, pose)
    assert first == 25 and turned == pytest.approx(math.radians(10.0))
    assert turned_against_odometry(turns, 30, pose, odo, None, 5) == (30, 0.0)
    assert turns == []


def _turning_scans(world, lo, hi, through):
    """Scans from poses that turn away from the true ones by up to 40 deg over scans
    ``lo..hi`` (and stay turned), with ``through`` of each such scan's beams 2.5 m longer than
    the map allows (beams through its walls)."""
    turn = np.clip((np.arange(world.poses.shape[0]) - lo) / (hi - lo), 0.0, 1.0)
    seen = world.poses.copy()
    seen[:, 2] = _wrap(seen[:, 2] + math.radians(40.0) * turn)
    model = BeamModel(world.spec, world.occupied, max_range=world.max_range)
    ranges = model.expected_ranges(seen, world.angles)
    rng = np.random.default_rng(2)
    ranges = ranges + rng.normal(0.0, 0.02, ranges.shape)
    if through:
        longer = (rng.uniform(size=ranges.shape) < through) & (ranges < world.max_range - 3.0)
        longer[:lo] = False
        ranges[longer] += 2.5
    return seen, np.maximum(ranges, 0.0)


def _run(world, odometry, ranges):
    cfg = LocalizeConfig(initial_pose=tuple(world.poses[0]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return localize_scans(
            world.spec, world.occupied.astype(float), 0.2 * np.arange(ranges.shape[0]), ranges,
            world.angles, odometry, world.max_range, cfg,
        )  # fmt: skip


def test_estimate_turning_against_the_odometry_through_walls_is_reported(world):
    """The odometry drives as the robot does; the scans fit a pose turned by 40 deg, save a
    third of their beams, which run through that pose's walls. The estimate follows the
    scans (it cannot know better), and the run says that it lost track there."""
    lo, hi = 60, 80
    _, ranges = _turning_scans(world, lo, hi, through=0.35)
    truth = world.poses  # the odometry, noise-free, is the truth here
    run = _run(world, truth, ranges)
    off = np.abs(_wrap(run.poses[:, 2] - truth[run.scan_index, 2])) > math.radians(20.0)
    assert off.any()  # the estimate did turn away
    turns = [e for e in run.episodes if e.reason == "turn"]
    assert turns, [e.describe() for e in run.episodes]
    first = turns[0]
    assert lo - 25 <= first.scan_index <= hi + 5
    # every update that is off by more than 20 deg lies inside a reported span
    spans = [(e.scan_index, e.recovered_index or 10**9) for e in run.episodes]
    for k in run.scan_index[off]:
        assert any(a <= k < b for a, b in spans), k


def test_odometry_heading_fault_with_scans_that_fit_is_not_reported(world):
    """The odometry claims a turn of 40 deg that the robot did not make (2 deg on each of 20
    steps); the scans, from the true poses, fit the map. The estimate follows the scans and so
    turns 40 deg against the odometry, which is right: no episode is reported."""
    lo, hi = 60, 80
    steps = np.asarray(between(world.poses[:-1], world.poses[1:]))
    steps[lo:hi, 2] += math.radians(2.0)
    odo = np.vstack([world.poses[:1], np.zeros_like(steps)])
    for k, step in enumerate(steps):
        odo[k + 1] = compose(odo[k], step)
    run = _run(world, odo, world.ranges)
    assert not run.episodes, [e.describe() for e in run.episodes]
    err = np.abs(_wrap(run.poses[:, 2] - world.poses[run.scan_index, 2]))
    assert np.degrees(np.median(err[run.scan_index > hi])) < 2.0
    drift = np.abs(_wrap(odo[-1, 2] - world.poses[-1, 2]))
    assert np.degrees(drift) > 35.0  # the odometry did turn away


def test_lost_turn_must_be_positive():
    with pytest.raises(ValueError, match="lost_turn"):
        LocalizeConfig(lost_turn=0.0)
    assert LocalizeConfig().lost_turn == pytest.approx(math.radians(20.0))
    assert LocalizeConfig().refine


def test_refined_pose_of_a_run_with_a_laser_offset(world):
    """The laser mounted 0.2 m ahead: refinement works on the robot pose, like the filter."""
    mount = np.array([0.2, 0.0, 0.0])
    lf = _mapped_field(world)
    k = 30
    laser = world.poses[k]  # the world's scans are seen from this pose: the laser's
    robot = np.asarray(compose(laser, inverse(mount)))
    lx, ly, ok = lf.endpoints(world.ranges[k], world.angles, mount)
    mean = robot + np.array([0.04, -0.03, 0.01])
    out = refine_pose(lf, mean, np.diag([0.05**2, 0.05**2, 0.02**2]), lx[ok], ly[ok])
    assert out.used and math.hypot(*(out.pose[:2] - robot[:2])) < 0.02
