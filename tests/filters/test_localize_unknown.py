"""Beams into a part of the building the map never saw are no evidence that the filter is
lost (issue 37: the hospital's robot looks 30-40 m down halls its map lacks, and a right
estimate was reported lost for six minutes).

Room A is mapped; through a 4 m door the laser sees room B, which the map leaves unknown. The
robot approaches the door and lingers in front of it, where most beams end in room B. Oracle:
the truth (the robot is tracked to centimetres) and the rule's own input: counted over all
beams, the scans fit the map too poorly for 10 updates in a row, which is what reported a
misfit before; counted over the beams that end on observed cells, they fit."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from probmap.grid.raycast import cast_rays
from probmap.pipelines.localize import LocalizeConfig, localize_scans
from probmap.sim.laser import walled_box

RES = 0.05


def _door_world():
    occ, spec, _ = walled_box(24.0, 14.0, RES)
    occ[:, round(8.0 / RES) : round(8.15 / RES)] = True  # the wall between A and B
    occ[round(5.0 / RES) : round(9.0 / RES), round(8.0 / RES) : round(8.15 / RES)] = False
    for y0, y1, x0, x1 in [(2, 3, 14, 16), (10, 11.5, 12, 13), (1, 3, 2, 3), (11, 13, 4, 5)]:
        occ[round(y0 / RES) : round(y1 / RES), round(x0 / RES) : round(x1 / RES)] = True
    a = np.linspace(2.0, 7.0, 50)
    s = np.linspace(0, 6 * np.pi, 120)
    poses = np.vstack([
        np.column_stack([a, np.full(50, 7.0), np.zeros(50)]),  # to the door
        np.column_stack([7.0 + 0.3 * np.sin(s), 7.0 + 0.6 * np.sin(0.5 * s), 0.35 * np.sin(s)]),
    ])  # fmt: skip
    angles = np.linspace(-np.pi / 2, np.pi / 2, 91)
    rng = np.random.default_rng(0)
    ranges = cast_rays(occ, spec, poses, angles, 30.0) + rng.normal(0, 0.02, (len(poses), 91))
    known = occ.astype(float)
    known[:, round(8.15 / RES) :] = np.nan  # the map never saw room B
    return spec, known, poses, angles, ranges


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_beams_into_the_unmapped_room_are_no_misfit(seed):
    spec, m, poses, angles, ranges = _door_world()
    n = len(poses)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = localize_scans(
            spec, m, 0.2 * np.arange(n), ranges, angles, poses, 30.0,
            LocalizeConfig(initial_pose=tuple(poses[0]), seed=seed),
        )  # fmt: skip
    err = np.hypot(*(run.poses[:, :2] - poses[run.scan_index, :2]).T)
    assert np.median(err) < 0.1
    # over all beams the scans fit as a lost filter's would, for far longer than 10 updates
    fits10 = np.convolve(run.matched, np.ones(10) / 10, "valid")
    assert np.sum(fits10 < LocalizeConfig().lost_matched) >= 20
    assert not any(e.reason == "misfit" for e in run.episodes)


def test_beams_into_the_unknown_still_count_when_the_map_is_all_known():
    """The same scans in a map that shows room B empty: its walls missing from a known map
    are evidence, and the filter says its scans stopped fitting."""
    spec, m, poses, angles, ranges = _door_world()
    m = np.nan_to_num(m, nan=0.0)  # room B mapped as empty floor, walls and all missing
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = localize_scans(
            spec, m, 0.2 * np.arange(len(poses)), ranges, angles, poses, 30.0,
            LocalizeConfig(initial_pose=tuple(poses[0])),
        )  # fmt: skip
    assert any(e.reason == "misfit" for e in run.episodes)
