"""A laser mounted ahead of the robot (issue 21): MCL weighs each scan from the particle (a
robot pose) composed with the mounting, ``between(robot_pose, laser_pose)`` of the log, and
reports the robot's trajectory. A synthetic floor-plan tour with the laser 0.3 m ahead: with
the mounting the robot's track is found in a map built from laser poses and in one built from
robot poses; the laser at the robot centre tracks the laser instead, 0.3 m off."""

from __future__ import annotations

import math

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.geometry.se2 import compose
from probmap.grid.occupancy import OccupancyGrid
from probmap.grid.raycast import cast_rays
from probmap.pipelines.localize import (
    LocalizeConfig,
    laser_offset_of,
    load_localization_map,
    localize_scans,
    trajectory_errors,
)
from probmap.sim.floorplan import simulate_laser_world

register(app)
runner = CliRunner()

MOUNT = np.array([0.3, 0.0, 0.0])  # the laser 0.3 m ahead of the robot centre
SCANS = 200  # 40 m of the tour: the corridor and the first rooms, with their turns


@pytest.fixture(scope="module")
def tour():
    """True robot poses, drifting robot odometry, laser poses and the scans cast from them."""
    w = simulate_laser_world(seed=3, size=(20.0, 12.0), step=0.2, pose_noise=(0.02, 0.02))
    robot = w.poses[:SCANS]
    laser = compose(robot, MOUNT)
    rng = np.random.default_rng(5)
    ranges = cast_rays(w.truth, w.spec, laser, w.angles, w.max_range)
    ranges = np.where(ranges < w.max_range, ranges + rng.normal(0, 0.01, ranges.shape), ranges)
    return w, robot, w.odometry[:SCANS], laser, ranges


def test_offset_of_a_rigid_mounting_and_of_poses_that_are_none():
    rng = np.random.default_rng(0)
    robot = np.column_stack([rng.uniform(-5, 5, (50, 2)), rng.uniform(-3, 3, 50)])
    mount = np.array([0.22, -0.05, 0.1])
    off = laser_offset_of(robot, compose(robot, mount))
    assert off is not None
    np.testing.assert_allclose(off, mount, atol=1e-12)
    np.testing.assert_allclose(compose(robot, off), compose(robot, mount), atol=1e-12)
    # laser poses corrected by SLAM beside raw odometry describe no mounting
    corrected = compose(robot, mount) + rng.normal(0, 0.05, (50, 3))
    assert laser_offset_of(robot, corrected) is None
    with pytest.raises(ValueError, match="robot and laser poses"):
        laser_offset_of(robot, robot[:3])


def _map(poses, ranges, max_range):
    g = OccupancyGrid(0.05)
    g.integrate_scans(
        poses, ranges, np.linspace(-math.pi / 2, math.pi / 2, 181), max_range=max_range
    )
    return g


@pytest.mark.parametrize("built_from", ["laser poses", "robot poses"])
def test_tracking_with_the_mounting_follows_the_robot(tour, built_from):
    w, robot, odo, laser, ranges = tour
    mount = laser_offset_of(robot, laser)
    assert mount is not None
    # "robot poses": the robot's poses composed with the mounting (map --poses odometry)
    g = _map(laser if built_from == "laser poses" else compose(robot, mount), ranges, w.max_range)
    cfg = LocalizeConfig(n_particles=500, initial_pose=tuple(robot[0]))

    def track(offset):
        run = localize_scans(
            g.spec, g.probability(), w.times[:SCANS], ranges, w.angles, odo, w.max_range, cfg,
            laser_offset=offset,
        )  # fmt: skip
        assert run.lost is None
        return run, np.hypot(*(run.poses[:, :2] - robot[run.scan_index, :2]).T)

    run, err = track(mount)
    np.testing.assert_array_equal(run.laser_offset, mount)
    assert run.times.size > 150
    assert np.median(err) < 0.05 and err.max() < 0.25
    # its laser poses are the robot's composed with the mounting: the laser's track
    np.testing.assert_allclose(run.laser_poses, compose(run.poses, mount), atol=1e-12)
    laser_err, _ = trajectory_errors(run, w.times[:SCANS], laser, laser=True)
    assert laser_err.size == run.times.size and np.median(laser_err) < 0.05
    # the laser at the robot centre: the estimate is the laser's pose, 0.3 m ahead
    _, err0 = track((0.0, 0.0, 0.0))
    assert np.median(err0) > 0.25 > 5 * np.median(err)


def test_a_bad_offset_is_refused(tour):
    w, robot, odo, _, ranges = tour
    with pytest.raises(ValueError, match="laser_offset must be 3 finite numbers"):
        localize_scans(
            w.spec, w.truth, w.times[:SCANS], ranges, w.angles, odo, w.max_range,
            laser_offset=(0.3, float("nan"), 0.0),
        )  # fmt: skip


def _write_log(path, robot, laser, ranges, *, param_offset):
    """A raw CARMEN log: FLASER lines carrying the laser pose and the robot pose of each scan."""
    lines = ["PARAM robot_front_laser_max 8.0"]
    if param_offset is not None:
        lines.append(f"PARAM robot_frontlaser_offset {param_offset}")
    for k, (rb, ls, r) in enumerate(zip(robot, laser, ranges, strict=True)):
        t = 100.0 + 0.2 * k
        rs = " ".join(f"{v:.3f}" for v in r)
        lp = " ".join(f"{v:.6f}" for v in ls)
        rp = " ".join(f"{v:.6f}" for v in rb)
        lines.append(f"FLASER {len(r)} {rs} {lp} {rp} {t:.6f} sim {t:.6f}")
    path.write_text("\n".join(lines) + "\n")
    return path


def _robot_error(out, robot):
    traj = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1)
    k = np.rint((traj[:, 0] - 100.0) / 0.2).astype(int)
    return np.hypot(*(traj[:, 1:3] - robot[k, :2]).T)


CLI_SCANS = 100  # the command-line runs take the first 20 m


def test_localize_command_reads_the_mounting_from_the_log(tour, tmp_path):
    _, robot, _, laser, ranges = (v[:CLI_SCANS] if i else v for i, v in enumerate(tour))
    # the odometry is the truth here, so that the map is exact; the log names no PARAM offset:
    # the mounting is between(robot pose, laser pose) of its lines
    log = _write_log(tmp_path / "tour.log", robot, laser, ranges, param_offset=None)
    res = runner.invoke(app, ["map", str(log), "-o", str(tmp_path / "laser")])
    assert res.exit_code == 0, res.output
    out = tmp_path / "out"
    res = runner.invoke(
        app, ["localize", str(tmp_path / "laser.yaml"), str(log), "-o", str(out), "-n", "300"]
    )
    assert res.exit_code == 0, res.output
    assert "0.300, 0.000 m" in res.output
    err = _robot_error(out, robot)
    assert err.size > 80 and np.median(err) < 0.05


def test_localize_in_a_session_and_a_map_of_robot_poses_with_a_param_offset(tour, tmp_path):
    _, robot, _, laser, ranges = (v[:CLI_SCANS] if i else v for i, v in enumerate(tour))
    log = _write_log(tmp_path / "tour.log", robot, laser, ranges, param_offset=0.3)
    # map --poses odometry: the robot's poses composed with PARAM robot_frontlaser_offset
    res = runner.invoke(
        app, ["map", str(log), "-o", str(tmp_path / "robot"), "--poses", "odometry"]
    )
    assert res.exit_code == 0, res.output
    session = tmp_path / "tour.session"
    res = runner.invoke(
        app,
        ["slam", "grid", str(log), "-o", str(tmp_path / "slam"), "--save-session", str(session)],
    )
    assert res.exit_code == 0, res.output
    for name, where in (("map", tmp_path / "robot.yaml"), ("session", session)):
        out = tmp_path / f"out-{name}"
        res = runner.invoke(
            app, ["localize", str(log), "--map", str(where), "-o", str(out), "-n", "300"]
        )
        assert res.exit_code == 0, res.output
        assert "0.300, 0.000 m" in res.output
    # the map of robot poses composed with the mounting is exact: the truth is the oracle
    err = _robot_error(tmp_path / "out-map", robot)
    assert err.size > 80 and np.median(err) < 0.05
    # the session holds laser poses, its own SLAM estimate (some centimetres off the truth):
    # the robot's track composed with the mounting is on them
    assert "error against the session's trajectory" in res.output
    m = load_localization_map(session)
    assert m.poses is not None
    traj = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1)
    k = np.rint((traj[:, 0] - 100.0) / 0.2).astype(int)
    gap = np.hypot(*(compose(traj[:, 1:4], MOUNT)[:, :2] - m.poses[k, :2]).T)
    assert np.median(gap) < 0.05
