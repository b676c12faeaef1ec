"""Honest uncertainty along a corridor (issue 37): a corridor of look-alike doors, in a map
whose doors are a little off. Counting 60 beams as independent evidence, MCL's cloud shrinks
to a few centimetres while its estimate is pulled along the corridor to where the map's doors
fit: its error is often more than twice its spread. Tempered (the defaults: a scan worth 10
beams, ``LocalizeConfig.independent_beams``, and never fewer than 30 % effective particles
after a scan, ``min_ess_fraction``), the cloud keeps its extent along the corridor and the
estimate stays nearer the truth that the odometry gives: the cloud is stretched along the
corridor, not across it, and the estimate steps along it as the odometry does."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from probmap.pipelines.localize import LocalizeConfig, localize_scans
from probmap.sim.corridor import simulate_door_corridor


def _along(corridor, **tempering):
    w = corridor.world
    cfg = LocalizeConfig(n_particles=1000, initial_pose=tuple(w.poses[0]), **tempering)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # neither run may lose track
        run = localize_scans(
            w.spec, corridor.map_occupied.astype(float), w.times, w.ranges, w.angles,
            w.odometry, w.max_range, cfg,
        )  # fmt: skip
    err = np.abs(run.poses[:, 0] - w.poses[run.scan_index, 0])  # the corridor runs along x
    return err, run.spread


@pytest.mark.parametrize("seed", [0, 1])
def test_tempered_cloud_keeps_its_extent_in_a_corridor(seed):
    corridor = simulate_door_corridor(seed=seed)
    w = corridor.world
    odo_err = np.abs(w.odometry[:, 0] - w.odometry[0, 0] + w.poses[0, 0] - w.poses[:, 0])
    assert odo_err.max() < 0.2  # odometry alone knows where along the corridor it is
    err0, spread0 = _along(corridor, independent_beams=None, min_ess_fraction=None)
    err1, spread1 = _along(corridor)  # the defaults
    # every beam independent: collapsed (a few cm) and confidently wrong
    assert np.median(spread0) < 0.09
    assert np.mean(err0 > 2 * spread0) > 0.25
    assert err0.max() > 0.5
    # tempered: wider, and its error mostly within two spreads
    assert np.median(spread1) > 1.4 * np.median(spread0)
    assert np.mean(err1 > 2 * spread1) < 0.5 * np.mean(err0 > 2 * spread0)
    assert err1.max() < 0.55 and err1.max() < err0.max() - 0.1


def _cloud_along(corridor, **tempering):
    """Per update: the particles' standard deviation along (x) and across (y) the corridor, and
    how far the estimate's step along it differs from the odometry's."""
    w = corridor.world
    sd = []
    cfg = LocalizeConfig(n_particles=1000, initial_pose=tuple(w.poses[0]), **tempering)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run = localize_scans(
            w.spec, corridor.map_occupied.astype(float), w.times, w.ranges, w.angles,
            w.odometry, w.max_range, cfg,
            observer=lambda k, est, p, r, a: sd.append((p[:, 0].std(), p[:, 1].std())),
        )  # fmt: skip
    step = np.diff(run.poses[:, 0]) - np.diff(w.odometry[run.scan_index, 0])
    return np.array(sd), float(np.sqrt(np.mean(step**2)))


@pytest.mark.parametrize("seed", [0, 1])
def test_cloud_stretches_along_the_corridor_and_follows_the_odometry(seed):
    corridor = simulate_door_corridor(seed=seed)
    sd, follow = _cloud_along(corridor)  # the defaults
    sd0, follow0 = _cloud_along(corridor, independent_beams=None, min_ess_fraction=None)
    along, across = np.median(sd[:, 0]), np.median(sd[:, 1])
    # the laser fixes the pose across the corridor, not along it: the cloud says so
    assert along > 0.1 and along > 4 * across
    assert along > 1.4 * np.median(sd0[:, 0])  # every beam independent: shrunk along it too
    # between updates the estimate moves along the corridor as the odometry does
    assert follow < 0.025 and follow < follow0
