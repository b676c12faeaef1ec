"""A localization run that loses track says so: where, and why (off the map, or spread), in
the Python API (a FilterLostWarning and ``run.lost``) and on the command line (an error and
nothing written, unless --allow-lost)."""

from __future__ import annotations

import importlib.util
import warnings
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.pipelines.localize import FilterLostWarning, LocalizeConfig, localize_scans
from probmap.sim.localization import simulate_localization_world

register(app)


@pytest.fixture(scope="module")
def world():
    return simulate_localization_world(0)


def _run(world, n=120, **cfg):
    probability = world.occupied.astype(float)
    config = LocalizeConfig(n_particles=300, **cfg)
    times = 0.2 * np.arange(n)
    return localize_scans(
        world.spec, probability, times, world.ranges[:n], world.angles, world.odometry[:n],
        world.max_range, config,
    )  # fmt: skip


def test_tracking_run_is_not_lost(world):
    with warnings.catch_warnings():
        warnings.simplefilter("error", FilterLostWarning)
        run = _run(world, initial_pose=tuple(world.poses[0]))
    assert run.lost is None


def test_run_started_a_kilometre_off_the_map_is_lost(world):
    far = tuple(world.poses[0] + [1000.0, 0.0, 0.0])
    with pytest.warns(FilterLostWarning, match=r"lost track at scan \d+ .*left the map") as rec:
        run = _run(world, initial_pose=far)
    assert len(rec) == 1  # once
    assert run.lost is not None and run.lost.reason == "off the map"
    # the first of lost_updates (10) lost updates in a row: the run's first update
    assert run.lost.scan_index == run.scan_index[0]


def test_blind_run_with_wild_odometry_spreads_and_is_lost(world):
    blind = world.max_range * np.ones_like(world.ranges)  # no return: nothing to correct
    probability = world.occupied.astype(float)
    # lost_jump out of the way: the spreading cloud's best cluster also jumps about
    cfg = LocalizeConfig(
        n_particles=300, initial_pose=tuple(world.poses[0]), alphas=(2.0, 2.0, 2.0, 2.0),
        lost_jump=100.0,
    )  # fmt: skip
    with pytest.warns(FilterLostWarning, match="spread"):
        run = localize_scans(
            world.spec, probability, 0.2 * np.arange(120), blind[:120], world.angles,
            world.odometry[:120], world.max_range, cfg,
        )  # fmt: skip
    assert run.lost is not None and run.lost.reason == "spread" and run.lost.value > 3.0
    with pytest.raises(ValueError, match="lost_spread"):
        LocalizeConfig(lost_spread=0.0)
    with pytest.raises(ValueError, match="lost_updates"):
        LocalizeConfig(lost_updates=0)
    with pytest.raises(ValueError, match="lost_jump"):
        LocalizeConfig(lost_jump=0.0)


def test_cli_refuses_a_lost_run_unless_allowed(tmp_path, world):
    spec = importlib.util.spec_from_file_location(
        "_loc_cli", Path(__file__).parent / "test_localize_cli.py"
    )
    assert spec is not None and spec.loader is not None
    helpers = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(helpers)
    log = helpers._write_log(tmp_path / "sim.log", world, 120)
    runner = CliRunner()
    res = runner.invoke(app, ["map", str(log), "-o", str(tmp_path / "map"), "--max-range", "8"])
    assert res.exit_code == 0, res.output
    # the first 15 scans of the same run, its odometry 1 km away: the robot starts off the
    # map, and is not found again so soon (with 40, random particles find it at scan 25)
    lines = log.read_text().splitlines()
    moved = [lines[0]]
    for line in lines[1:16]:
        f = line.split()
        f[-6] = f"{float(f[-6]) + 1000.0:.4f}"  # odometry x
        moved.append(" ".join(f))
    far = tmp_path / "far.log"
    far.write_text("\n".join(moved) + "\n")
    args = ["localize", str(tmp_path / "map.yaml"), str(far), "-o", str(tmp_path / "out")]
    res = runner.invoke(app, [*args, "--particles", "300"])
    assert res.exit_code == 1, res.output
    line = res.output.strip().splitlines()
    assert len(line) == 1 and "lost track at scan" in line[0] and "far.log" in line[0]
    assert not (tmp_path / "out").exists()
    res = runner.invoke(app, [*args, "--particles", "300", "--allow-lost"])
    assert res.exit_code == 0, res.output
    assert "lost" in res.output and (tmp_path / "out" / "trajectory.csv").is_file()
