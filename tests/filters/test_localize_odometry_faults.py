"""Odometry that lies (issue 37).

- Freiburg 079's odometry logs every reversing as forward driving. The scans say otherwise;
  after each update the filter matches the scan against the map near its estimate and follows
  the scan when it fits clearly better (``LocalizeConfig.match_window``). Without that, the cloud
  is carried metres away within seconds.
- A filter whose cloud is tight but in the wrong place must say so: its scans stop fitting the
  map (``LocalizeConfig.lost_matched``), the run reports it lost, and augmented MCL finds the
  robot again.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from probmap.geometry.se2 import between, compose
from probmap.grid.spec import GridSpec
from probmap.models.beam import BeamModel
from probmap.pipelines.localize import LocalizeConfig, localize_scans
from probmap.sim.localization import simulate_localization_world


@pytest.fixture(scope="module")
def world():
    return simulate_localization_world(0)


def _errors(run, true_poses):
    return np.hypot(*(run.poses[:, :2] - true_poses[run.scan_index, :2]).T)


@pytest.mark.parametrize("at", [60, 200])
def test_driving_logged_the_wrong_way_is_followed_by_the_scans(world, at):
    odo = world.odometry
    steps = np.asarray(between(odo[:-1], odo[1:]))
    steps[at : at + 12, 0] *= -1  # 12 steps (3 m) of forward driving logged as reversing
    lying = np.vstack([odo[:1], np.zeros_like(steps)])
    for k, s in enumerate(steps):
        lying[k + 1] = compose(lying[k], s)
    n = world.ranges.shape[0]
    errs = {}
    for window in (None, 0.5):  # without the scan match, and with it (the default)
        cfg = LocalizeConfig(initial_pose=tuple(world.poses[0]), match_window=window)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            run = localize_scans(
                world.spec, world.occupied.astype(float), 0.2 * np.arange(n), world.ranges,
                world.angles, lying, world.max_range, cfg,
            )  # fmt: skip
        errs[window] = _errors(run, world.poses)
    assert errs[None].max() > 1.0  # carried away by the odometry
    assert errs[0.5].max() < 0.3  # the scans keep it on the robot
    assert LocalizeConfig().match_window == 0.5


def _room_in_a_hall(seed):
    """A 5 x 4 m room with things in its corners and one corner cut, in a 24 x 24 m hall whose
    walls lie beyond the laser's 8 m; a robot driving circles in the room, and its scans."""
    rng = np.random.default_rng(seed)
    spec = GridSpec(resolution=0.05, origin=(0.0, 0.0), shape=(480, 480))
    occ = np.zeros(spec.shape, dtype=bool)
    occ[:2, :] = occ[-2:, :] = occ[:, :2] = occ[:, -2:] = True  # the hall
    occ[60:62, 60:162] = occ[140:142, 60:162] = True  # the room: x 3-8 m, y 3-7 m
    occ[60:142, 60:62] = occ[60:142, 160:162] = True
    occ[62:80, 62:90] = True  # a box in its lower left corner
    occ[118:140, 62:76] = True  # and a cupboard in the upper left one
    occ[62:66, 120:124] = True  # a pipe by the lower wall
    iy, ix = np.mgrid[0:480, 0:480]
    occ |= (ix > 60) & (ix < 162) & (iy > 60) & (iy < 142) & (ix + iy > 272)  # a cut corner
    t = np.linspace(0, 4 * np.pi, 300)
    poses = np.column_stack([5.8 + 1.2 * np.cos(t), 5.2 + 0.9 * np.sin(t), t + np.pi / 2])
    poses[:, 2] = (poses[:, 2] + np.pi) % (2 * np.pi) - np.pi
    angles = np.linspace(-np.pi / 2, np.pi / 2, 90)
    ranges = BeamModel(spec, occ, max_range=8.0).expected_ranges(poses, angles)
    ranges = ranges + rng.normal(0.0, 0.02, ranges.shape)
    return spec, occ, poses, angles, ranges


def _run_in_room(seed, **config):
    spec, occ, poses, angles, ranges = _room_in_a_hall(seed)
    odo = poses.copy()
    odo[:, :2] += 8.0  # the odometry (and so the start) 11 m off, in the empty hall
    cfg = LocalizeConfig(initial_pose=tuple(odo[0]), seed=seed, **config)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = localize_scans(
            spec, occ.astype(float), 0.2 * np.arange(poses.shape[0]), ranges, angles, odo, 8.0,
            cfg,
        )  # fmt: skip
    return run, _errors(run, poses)


@pytest.mark.parametrize("seed", [0, 1])
def test_tight_but_wrong_says_lost_and_recovers(seed):
    run, err = _run_in_room(seed)
    assert err[:10].min() > 5.0 and np.median(run.spread[:10]) < 0.5  # tight and wrong
    assert run.episodes, "a tight cloud in the wrong place was never reported lost"
    first = run.episodes[0]
    assert first.reason == "misfit" and "stopped fitting the map" in first.describe()
    assert first.scan_index <= 40  # said within the first 20 updates
    assert first.recovered and not run.ended_lost
    assert err[-20:].max() < 0.2  # found again by augmented MCL
    back = np.searchsorted(run.scan_index, first.recovered_index)
    assert err[back:].max() < 1.5  # near where it says it recovered (a metre off at first)
