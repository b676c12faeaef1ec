"""Far closure searches match against a submap merged with its neighbours
(``ClosureConfig.far_neighbours``): a robot that comes back the other way sees, from one
place, walls that several submaps of the first pass hold between them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from probmap.geometry.se2 import between
from probmap.grid.occupancy import InverseSensorModel
from probmap.slam.laser.closures import ClosureConfig, LoopClosing
from probmap.slam.laser.scan_matching import laser_slam_matcher, normal_equations
from probmap.slam.laser.submaps import Submap

RES, SIGMA, RADIUS = 0.05, 0.05, 6
ANGLES = np.linspace(-np.pi / 2, np.pi / 2, 181)
MAX_RANGE = 6.0


def _walls() -> list[tuple[float, float, float]]:
    """Wall pieces ``(y, x_from, x_to)`` (metres) along both sides of a corridor along x,
    1.2 m long with doors of 0.8 m between them, offset by 1 m from one side to the other."""
    xs = np.arange(-4.0, 40.0, 2.0)
    return [(1.5, x, x + 1.2) for x in xs] + [(-1.5, x + 1.0, x + 2.2) for x in xs]


def _scan(pose: np.ndarray) -> np.ndarray:
    """Ranges from ``pose`` (x, y, heading) to the walls (no return: inf)."""
    out = np.full(ANGLES.shape, np.inf)
    dx, dy = np.cos(ANGLES + pose[2]), np.sin(ANGLES + pose[2])
    for y, x0, x1 in _walls():
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (y - pose[1]) / dy
        x = pose[0] + t * dx
        hit = (t > 0) & (x >= x0) & (x <= x1)
        out = np.where(hit, np.minimum(out, t), out)
    return np.where(out < MAX_RANGE, out, np.inf)


class _Graph:
    def __init__(self, poses: list[np.ndarray]) -> None:
        self.poses = np.asarray(poses)

    def pose(self, i: int) -> np.ndarray:
        return self.poses[i]


def _setup(n_neighbours: int) -> tuple[LoopClosing, list[Submap], _Graph]:
    """Three finished submaps along the corridor, driven east: submap i holds the scans
    from x = 4i to 4i + 3 (anchored at its first one); the anchors' poses are the truth."""
    model = InverseSensorModel(0.7, 0.4, max_clear_range=MAX_RANGE)
    poses: list[np.ndarray] = []
    submaps: list[Submap] = []
    for i in range(3):
        sm = Submap(i, len(poses), RES, SIGMA, RADIUS, model)
        for x in np.arange(4.0 * i, 4.0 * i + 4.0, 0.5):
            pose = np.array([x, 0.0, 0.0])
            poses.append(pose)
            sm.insert(len(poses) - 1, between(poses[sm.anchor], pose), _scan(pose), ANGLES, 8.0)
        sm.finish()
        submaps.append(sm)
    graph = _Graph(poses)
    config = dataclasses.replace(ClosureConfig(), far_neighbours=n_neighbours)
    loops = LoopClosing(
        config, graph=graph, submaps=submaps, active=[], travel=[], matcher=laser_slam_matcher(),
        min_match_score=0.25, grid_cache=4, full_points=lambda k: np.zeros((0, 2)),
    )  # fmt: skip
    return loops, submaps, graph


def _at(field, pts: np.ndarray) -> np.ndarray:
    """The field at the cells holding ``pts`` (nearest cell, as the searches look it up)."""
    ox, oy = field.origin
    ix = np.floor((pts[:, 0] - ox) / field.resolution).astype(int)
    iy = np.floor((pts[:, 1] - oy) / field.resolution).astype(int)
    h, w = field.values.shape
    inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
    out = np.zeros(len(pts))
    out[inside] = field.values[iy[inside], ix[inside]]
    return out


def test_the_merged_field_holds_the_neighbours_walls_where_they_are():
    loops, submaps, graph = _setup(2)
    single, _ = loops._grids(submaps[1])
    merged, _ = loops._grids(submaps[1], merged=True)
    base = graph.pose(submaps[1].anchor)
    for other in submaps:  # every submap's occupied cells, moved into submap 1's frame
        rel = between(base, graph.pose(other.anchor))
        c, s = np.cos(rel[2]), np.sin(rel[2])
        oc = other.occupied_centres()
        assert len(oc) > 20
        pts = np.c_[rel[0] + c * oc[:, 0] - s * oc[:, 1], rel[1] + s * oc[:, 0] + c * oc[:, 1]]
        assert _at(merged, pts).min() == pytest.approx(1.0)  # each is an occupied cell there
    # the middle of the corridor, beyond the field's radius from every post: nothing
    assert _at(merged, np.array([[5.5, 0.0]]))[0] == pytest.approx(0.0)
    # walls submap 0 saw west of x = 4 (x = 0.5 and 2.5, submap 1's frame starts at x = 4),
    # behind every laser of submap 1
    west = np.array([[0.5 - 4.0, 1.5], [2.5 - 4.0, 1.5]])
    assert _at(single, west).max() == pytest.approx(0.0)
    assert _at(merged, west).min() > 0.5


def test_a_scan_looking_back_scores_higher_on_the_merged_submaps():
    """The return drive, facing west from x = 6: most of its returns end on walls west of
    x = 4, which submap 0 holds and submap 1, its nearest, never saw (they lay behind its
    lasers)."""
    loops, submaps, graph = _setup(2)
    pose = np.array([6.0, 0.0, np.pi])
    r = _scan(pose)
    ok = np.isfinite(r)
    pts = np.c_[r[ok] * np.cos(ANGLES[ok]), r[ok] * np.sin(ANGLES[ok])]
    in_sub = between(graph.pose(submaps[1].anchor), pose)
    single, _ = loops._grids(submaps[1])
    merged, _ = loops._grids(submaps[1], merged=True)
    s1 = normal_equations(single, pts, in_sub)[0] / len(pts)
    s2 = normal_equations(merged, pts, in_sub)[0] / len(pts)
    assert s1 < 0.6
    assert s2 > 0.75 and s2 > s1 + 0.2
    # without neighbours the far search keeps the single submap
    loops0, submaps0, _ = _setup(0)
    fld0, _ = loops0._grids(submaps0[1], merged=loops0.config.far_neighbours > 0)
    assert normal_equations(fld0, pts, in_sub)[0] / len(pts) == pytest.approx(s1)


def test_config_checks_far_neighbours():
    with pytest.raises(ValueError, match="far_neighbours"):
        ClosureConfig(far_neighbours=-1)
