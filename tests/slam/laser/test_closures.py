"""Closure verification (probmap.slam.laser.closures): a far match is dropped when another
distinct pose in the window scores nearly as well (the place repeats), and on a simulated floor
of identical offices no wrong closure is accepted, where the same run without the test accepts
dozens."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from probmap.geometry.se2 import between
from probmap.sim.offices import simulate_office_floor
from probmap.slam.laser.closures import ClosureConfig, LoopClosing
from probmap.slam.laser.loop_closure import PrecomputedGrids, branch_and_bound_search
from probmap.slam.laser.scan_matching import MatchField, laser_slam_matcher
from probmap.slam.laser.submap_slam import SubmapSlam, SubmapSlamConfig

RES = 0.05


def _corner_points() -> np.ndarray:
    """An L of endpoints (a room's corner), sensor frame."""
    a = np.stack([np.linspace(0.5, 2.0, 31), np.full(31, 1.0)], axis=1)
    b = np.stack([np.full(31, 2.0), np.linspace(-1.0, 1.0, 31)], axis=1)
    return np.concatenate([a, b])


def _field(copies: list[float]) -> MatchField:
    """A match field holding the corner at the origin pose, and again shifted by each x in
    ``copies`` (metres)."""
    w, h = round(12.0 / RES), round(6.0 / RES)
    values = np.zeros((h, w))
    origin = (-2.0, -3.0)
    for dx in [0.0, *copies]:
        for x, y in _corner_points():
            ix = int(np.floor((x + dx - origin[0]) / RES))
            iy = int(np.floor((y - origin[1]) / RES))
            values[iy - 1 : iy + 2, ix - 1 : ix + 2] = 1.0  # a cell either way: no edge cases
    return MatchField(np.ascontiguousarray(values), origin, RES)


def _loops(config: ClosureConfig) -> LoopClosing:
    return LoopClosing(
        config, graph=None, submaps=[], active=[], travel=[], matcher=laser_slam_matcher(),
        min_match_score=0.25, grid_cache=1, full_points=lambda k: np.zeros((0, 2)),
    )  # fmt: skip


@pytest.mark.parametrize(("copies", "ambiguous"), [([], False), ([4.0], True), ([0.3], False)])
def test_a_second_place_scoring_as_well_makes_the_match_ambiguous(copies, ambiguous):
    grids = PrecomputedGrids.from_field(_field(copies))
    pts = _corner_points()
    guess = np.array([0.1, 0.05, 0.0])
    found = branch_and_bound_search(grids, pts, guess, 5.0, 0.1, min_score=0.5)
    assert found is not None and found.score == pytest.approx(1.0)
    loops = _loops(ClosureConfig())
    # a copy 4 m away is another place; one 0.3 m away is within ambiguity_distance
    assert loops._ambiguous(grids, pts, guess, found, 5.0, 0.1) is ambiguous
    # a window that cannot hold a second place, or the test off: never ambiguous
    assert not loops._ambiguous(grids, pts, guess, found, 0.4, 0.1)
    off = _loops(ClosureConfig(ambiguity=0.0))
    assert not off._ambiguous(grids, pts, guess, found, 5.0, 0.1)


def test_config_checks_the_ambiguity_settings():
    with pytest.raises(ValueError, match="ambiguity must lie in"):
        ClosureConfig(ambiguity=1.5)
    with pytest.raises(ValueError, match="ambiguity_distance"):
        ClosureConfig(ambiguity_distance=0.0)


def _wrong_closures(config: SubmapSlamConfig, seed: int) -> tuple[int, int]:
    """(closures accepted, of them further than 1 m from the true relative pose)."""
    w = simulate_office_floor(seed=seed, pose_noise=(0.05, 0.02))
    slam = SubmapSlam(config, max_range=w.max_range)
    for i in range(len(w.poses)):
        slam.add_scan(w.times[i], w.ranges[i], w.angles, w.odometry[i])
    slam.finish()
    wrong = 0
    for c in slam.closures:
        a, k = slam.node_scan[c.anchor], slam.node_scan[c.node]
        truth = between(w.poses[a], w.poses[k])
        wrong += bool(np.hypot(*(truth[:2] - np.asarray(c.pose)[:2])) > 1.0)
    return len(slam.closures), wrong


def test_identical_offices_fool_no_closure():
    default = SubmapSlamConfig()
    accepted, wrong = _wrong_closures(default, seed=0)
    assert accepted > 200 and wrong == 0
    # the same run without the ambiguity test (the code before it) accepts wrong ones
    closures = dataclasses.replace(default.closures, ambiguity=0.0)
    _, wrong_before = _wrong_closures(dataclasses.replace(default, closures=closures), seed=0)
    assert wrong_before >= 20
