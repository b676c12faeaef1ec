"""Global localization that keeps searching until it may claim (issue 37, point 4).

A stuck search starts again: in a map that lacks the room the robot drives in, the particles
settle on the best-fitting place, one tight cloud whose scans do not fit; the run restarts
the search (``LocalizeConfig.restart_updates``) and never claims to know. A claim needs the
cloud to fit over ``converged_updates`` updates, and a run ``until_localized`` stops at it,
the run made without stopping up to there."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from probmap.pipelines.localize import LocalizeConfig, localize_scans
from probmap.sim.laser import drive_route, interpolate_route, walled_box


def _room(boxes):
    occ, spec, _ = walled_box(12.0, 7.0, 0.05)
    for x, y in boxes:
        occ[round((y - 0.4) / 0.05) : round((y + 0.4) / 0.05),
            round((x - 0.4) / 0.05) : round((x + 0.4) / 0.05)] = True  # fmt: skip
    return occ, spec


@pytest.fixture(scope="module")
def world():
    occ, spec = _room([(3.0, 2.0), (9.0, 5.0), (3.0, 5.5)])
    route = interpolate_route(
        np.array([[1.5, 3.5], [6.0, 4.5], [10.5, 3.5], [6.0, 1.2], [1.5, 3.5]]), 0.1
    )
    angles = np.linspace(-np.pi / 2, np.pi / 2, 181)
    return drive_route(
        occ, spec, route, np.random.default_rng(0), angles, max_range=8.0, range_noise=0.02,
        pose_noise=(0.02, 0.02), heading_noise=0.01,
    )  # fmt: skip


def _run(world, occupancy, seed=0, **kw):
    cfg = LocalizeConfig(n_particles=3000, global_localization=True, seed=seed)
    cfg = dataclasses.replace(cfg, **{k: v for k, v in kw.items() if k != "until_localized"})
    return localize_scans(
        world.spec, occupancy.astype(float), world.times, world.ranges, world.angles,
        world.odometry, world.max_range, cfg, until_localized=kw.get("until_localized", False),
    )  # fmt: skip


def test_a_search_stuck_where_the_scans_do_not_fit_starts_again(world):
    # the map: a room of the same size with other furniture, where no pose explains the scans
    other, _ = _room([(6.0, 3.5), (10.0, 1.5)])
    run = _run(world, other)
    assert not run.localized and run.converged_index is None  # never claims
    assert run.restarts >= 1
    assert _run(world, other, restart_updates=None).restarts == 0


def test_the_claim_needs_converged_updates_that_fit_and_is_right(world):
    quick = _run(world, world.truth, converged_updates=1)
    slow = _run(world, world.truth)  # the default, 30
    assert quick.converged_index is not None and slow.converged_index is not None
    assert slow.converged_index >= quick.converged_index + 29 - 10
    assert slow.converged_index >= 29
    c = slow.converged_index
    err = np.hypot(*(slow.poses[c:, :2] - world.poses[slow.scan_index[c:], :2]).T)
    assert slow.localized and err.max() < 0.3


def test_until_localized_stops_at_the_claim_of_the_same_run(world):
    full = _run(world, world.truth)
    stop = _run(world, world.truth, until_localized=True)
    c = full.converged_index
    assert c is not None and stop.localized
    assert stop.times.size == c + 1 and stop.converged_index == c
    assert np.array_equal(stop.poses, full.poses[: c + 1])
    truth = world.poses[stop.scan_index[-1]]
    assert np.hypot(*(stop.poses[-1, :2] - truth[:2])) < 0.3
