"""The self-consistency figure of a trajectory (probmap.metrics.consistency): zero where the
poses are the truth, positive at the seam where half the run is laid off, the length filter,
and the visits cut by travel."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.metrics.consistency import map_consistency, visits_by_travel
from probmap.sim.floorplan import simulate_laser_world


@pytest.fixture(scope="module")
def world():
    return simulate_laser_world(seed=1, size=(20.0, 12.0))


def _figure(world, poses, ranges=None, **kw):
    r = world.ranges if ranges is None else ranges
    return map_consistency(world.times, poses, r, world.angles, world.max_range, **kw)


def test_true_poses_agree_with_themselves(world):
    c = _figure(world, world.poses)
    assert len(c.visits) >= 10 and c.occupied > 5000
    assert c.share == 0.0 and all(v.contradicted == 0 for v in c.visits)


def test_a_misplaced_second_half_contradicts_the_first(world):
    poses = world.poses.copy()
    half = len(poses) // 2
    poses[half:, 0] += 0.6  # a wrong loop closure: the second half laid 0.6 m off
    c = _figure(world, poses)
    assert c.share > 0.005
    worst = c.worst(min_occupied=100)
    assert worst is not None and worst.share > 0.03
    assert worst.first > half // 2  # at the seam, not in the first visits
    assert c.visits[0].contradicted == 0
    # the length filter only removes: short groups first, everything past the longest wall
    loose = _figure(world, poses, min_length=0.0)
    assert loose.share >= c.share
    assert _figure(world, poses, min_length=50.0).share == 0.0
    # within the tolerance (0.3 m) a shift is forgiven
    poses[half:, 0] -= 0.5
    assert _figure(world, poses).share < 0.5 * c.share


def test_visits_are_cut_by_travel():
    poses = np.zeros((7, 3))
    poses[:, 0] = [0.0, 4.0, 8.0, 8.0, 12.0, 25.0, 26.0]  # a stop, then a jump
    assert visits_by_travel(poses, 10.0).tolist() == [0, 0, 0, 0, 1, 2, 2]
    with pytest.raises(ValueError, match="visit_length"):
        visits_by_travel(poses, 0.0)
    with pytest.raises(ValueError, match=r"\(S, 3\)"):
        visits_by_travel(poses[:, :2], 10.0)


def test_bad_shapes_are_refused(world):
    with pytest.raises(ValueError, match="must agree"):
        map_consistency(world.times[:-1], world.poses, world.ranges, world.angles, 8.0)
