"""The shared steps of the laser simulators (probmap.sim.laser) and the worlds built from them."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.grid.raycast import cast_rays
from probmap.sim.corridor import simulate_corridor_loop
from probmap.sim.floorplan import floor_plan, floor_plan_route, simulate_laser_world
from probmap.sim.laser import drift_odometry, interpolate_route, noisy_ranges, poses_along


def test_interpolate_route_steps_and_keeps_the_corners():
    way = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.25], [1.0, 0.25]])  # a zero-length segment
    xy = interpolate_route(way, 0.3)
    gaps = np.hypot(*np.diff(xy, axis=0).T)
    assert gaps.max() <= 0.3 + 1e-12
    # every corner is visited: 1 m in ceil(1 / 0.3) = 4 parts, then 1 and 1 part
    assert len(xy) == 1 + 4 + 1 + 1
    for corner in way:
        assert np.isclose(np.hypot(*(xy - corner).T), 0.0).any()


def test_poses_head_to_the_next_point():
    xy = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    poses = poses_along(xy, np.random.default_rng(0), 0.0)
    np.testing.assert_allclose(poses[:, 2], [0.0, np.pi / 2, np.pi / 2])
    np.testing.assert_array_equal(poses[:, :2], xy)


def test_noisy_ranges_keep_misses_exact_and_hits_below_max():
    rng = np.random.default_rng(1)
    true = np.where(rng.random((200, 50)) < 0.3, 8.0, rng.uniform(0.0, 8.0, (200, 50)))
    z = noisy_ranges(true, 8.0, rng, 0.5)
    miss = true >= 8.0
    assert (z[miss] == 8.0).all()
    assert (z[~miss] >= 1e-3).all() and (z[~miss] < 8.0).all()
    inner = ~miss & (true > 2.0) & (true < 6.0)  # away from the clipping bounds
    assert abs(np.mean(z[inner] - true[inner])) < 0.02
    assert np.std(z[inner] - true[inner]) == pytest.approx(0.5, rel=0.03)
    dropped = noisy_ranges(true, 8.0, np.random.default_rng(2), 0.01, dropout=0.2)
    assert np.isnan(dropped).mean() == pytest.approx(0.2, abs=0.01)


def test_drift_odometry_without_noise_is_the_truth_and_drifts_with_it():
    xy = interpolate_route(np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 5.0]]), 0.1)
    poses = poses_along(xy, np.random.default_rng(3), 0.05)
    exact = drift_odometry(poses, np.random.default_rng(4), (0.0, 0.0))
    np.testing.assert_allclose(exact, poses, atol=1e-9)
    ends = [drift_odometry(poses, np.random.default_rng(s), (0.05, 0.05))[-1] for s in range(200)]
    err = np.hypot(*(np.asarray(ends)[:, :2] - poses[-1, :2]).T)
    assert 0.05 < np.median(err) < 2.0  # 10 m driven with 5 % drift per metre


def test_floor_plan_world_is_its_true_map_seen_by_a_laser():
    w = simulate_laser_world(seed=0, range_noise=0.0, step=0.5)
    truth, spec = floor_plan()
    np.testing.assert_array_equal(w.truth, truth)
    # the tour keeps inside the building, and noise-free scans are the ranges cast on the truth
    xy = interpolate_route(floor_plan_route(), 0.1)
    assert (xy > 0.5).all() and (xy < np.array([19.5, 11.5])).all()
    cast = cast_rays(truth, spec, w.poses, w.angles, w.max_range)
    hit = cast < w.max_range
    np.testing.assert_allclose(w.ranges[hit], np.clip(cast[hit], 1e-3, w.max_range - 1e-6))
    assert (w.ranges[~hit] == w.max_range).all()
    np.testing.assert_allclose(w.odometry, w.poses, atol=1e-9)  # pose_noise defaults to none


def test_corridor_loop_drives_past_its_start():
    w = simulate_corridor_loop(seed=0, laps=1.2, step=0.2)
    lap = 2 * (40.0 + 10.0) - 4 * 2.0
    travelled = np.hypot(*np.diff(w.poses[:, :2], axis=0).T).sum()
    assert travelled == pytest.approx(1.2 * lap, rel=0.01)
    cells = w.spec.world_to_cell(w.poses[:, :2])
    assert not w.truth[cells[:, 1], cells[:, 0]].any()
