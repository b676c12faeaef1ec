"""``probmap localize`` end to end on a simulated CARMEN log, and its bad-input errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.models.beam import BeamModel
from probmap.sim.localization import simulate_localization_world

register(app)
runner = CliRunner()


def run(*args: str):
    return runner.invoke(app, [str(a) for a in args])


def _write_log(path, world, n, *, odometry=True):
    """A CARMEN log: FLASER lines with the true laser pose and drifting (or no) odometry."""
    angles = -math.pi / 2 + np.arange(60) * math.pi / 60
    rng = np.random.default_rng(0)
    ranges = BeamModel(world.spec, world.occupied, max_range=8.0).expected_ranges(
        world.poses[:n], angles
    )
    ranges = np.where(ranges < 8.0, ranges + rng.normal(0, 0.01, ranges.shape), 8.0)
    lines = []
    for k in range(n):
        t = 100.0 + 0.2 * k
        odo = world.odometry[k] if odometry else np.zeros(3)
        r = " ".join(f"{v:.3f}" for v in ranges[k])
        x, y, th = world.poses[k]
        lines.append(
            f"FLASER 60 {r} {x:.4f} {y:.4f} {th:.5f} {odo[0]:.4f} {odo[1]:.4f} {odo[2]:.5f} "
            f"{t:.6f} sim {t:.6f}"
        )
    path.write_text("PARAM robot_front_laser_max 8.0\n" + "\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("loc")
    world = simulate_localization_world(0)
    log = _write_log(d / "sim.log", world, 150)
    res = run("map", log, "-o", d / "map", "--max-range", "8.0")
    assert res.exit_code == 0, res.output
    ref = d / "truth.csv"
    rows = np.column_stack([100.0 + 0.2 * np.arange(150), world.poses[:150]])
    np.savetxt(ref, rows, delimiter=",", header="time,x,y,theta", comments="")
    return d, world


def test_localize_tracks_and_reports_errors(sim):
    d, world = sim
    out = d / "out"
    res = run(
        "localize",
        d / "map.yaml",
        d / "sim.log",
        "-o",
        out,
        "--particles",
        "500",
        "--reference",
        d / "truth.csv",
    )
    assert res.exit_code == 0, res.output
    assert "position" in res.output and "median" in res.output
    traj = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1)
    assert traj.shape[1] == 5 and traj.shape[0] > 50
    t_idx = np.rint((traj[:, 0] - 100.0) / 0.2).astype(int)
    err = np.hypot(*(traj[:, 1:3] - world.poses[t_idx, :2]).T)
    assert np.median(err) < 0.1
    assert (out / "trajectory.png").stat().st_size > 1000


def test_localize_errors(sim, tmp_path):
    d, world = sim
    res = run("localize", tmp_path / "missing.yaml", d / "sim.log", "-o", tmp_path / "o")
    assert res.exit_code == 1 and "missing.yaml" in res.output
    bad = tmp_path / "bad.yaml"
    bad.write_text("image: map.pgm\nresolution: 0.05\n")  # no origin
    res = run("localize", bad, d / "sim.log", "-o", tmp_path / "o")
    assert res.exit_code == 1 and "error:" in res.output and "Traceback" not in res.output
    # image size inconsistent with the YAML's image: a truncated PGM
    (tmp_path / "m.pgm").write_bytes((d / "map.pgm").read_bytes()[:200])
    (tmp_path / "m.yaml").write_text((d / "map.yaml").read_text().replace("map.pgm", "m.pgm"))
    res = run("localize", tmp_path / "m.yaml", d / "sim.log", "-o", tmp_path / "o")
    assert res.exit_code == 1 and "error:" in res.output
    no_odo = _write_log(tmp_path / "noodo.log", world, 20, odometry=False)
    res = run("localize", d / "map.yaml", no_odo, "-o", tmp_path / "o")
    assert res.exit_code == 1 and "no odometry" in res.output
    res = run("localize", d / "map.yaml", d / "sim.log", "-o", tmp_path / "o", "--particles", "0")
    assert res.exit_code == 1 and "particles" in res.output
    res = run(
        "localize",
        d / "map.yaml",
        d / "sim.log",
        "-o",
        tmp_path / "o",
        "--reference",
        d / "truth.csv",
        "--reference-offset",
        "1000",
    )
    assert res.exit_code == 1 and "reference-offset" in res.output
    assert not (tmp_path / "o" / "trajectory.csv").exists()


def _write_log_with_stop(path, world, n, stop_at, stop_scans):
    """As :func:`_write_log`, with the robot standing still for ``stop_scans`` scans (0.2 s
    apart) after scan ``stop_at``: the same odometry, fresh range noise."""
    angles = -math.pi / 2 + np.arange(60) * math.pi / 60
    rng = np.random.default_rng(1)
    order = np.r_[np.arange(stop_at + 1), np.full(stop_scans, stop_at), np.arange(stop_at + 1, n)]
    clean = BeamModel(world.spec, world.occupied, max_range=8.0).expected_ranges(
        world.poses[order], angles
    )
    ranges = np.where(clean < 8.0, clean + rng.normal(0, 0.01, clean.shape), 8.0)
    lines, times = [], 100.0 + 0.2 * np.arange(order.size)
    for k, i in enumerate(order):
        r = " ".join(f"{v:.3f}" for v in ranges[k])
        x, y, th = world.poses[i]
        o = world.odometry[i]
        lines.append(
            f"FLASER 60 {r} {x:.4f} {y:.4f} {th:.5f} {o[0]:.4f} {o[1]:.4f} {o[2]:.5f} "
            f"{times[k]:.6f} sim {times[k]:.6f}"
        )
    path.write_text("PARAM robot_front_laser_max 8.0\n" + "\n".join(lines) + "\n")
    truth = path.with_suffix(".csv")
    rows = np.column_stack([times, world.poses[order]])
    np.savetxt(truth, rows, delimiter=",", header="time,x,y,theta", comments="")
    return path, truth, times[stop_at], times[stop_at + stop_scans]


def test_standing_still_and_a_reference_change_nothing(sim):
    """A 60 s stop neither shrinks the particle cloud nor, with a reference given, adds
    updates: the trajectory with --reference is the one without, byte for byte."""
    d, world = sim
    log, truth, t_stop, t_go = _write_log_with_stop(d / "stop.log", world, 120, 60, 300)
    outs = []
    for extra in ((), ("--reference", truth)):
        out = d / f"stop{len(extra)}"
        res = run("localize", d / "map.yaml", log, "-o", out, "--particles", "500", *extra)
        assert res.exit_code == 0, res.output
        outs.append(out / "trajectory.csv")
    assert outs[0].read_bytes() == outs[1].read_bytes()
    traj = np.loadtxt(outs[0], delimiter=",", skiprows=1)
    t, spread = traj[:, 0], traj[:, 4]
    assert not np.any((t > t_stop) & (t < t_go))  # no update while standing still
    before = spread[t <= t_stop][-1]
    after = spread[t >= t_go][0]  # the first update after the stop: one motion step on
    assert before > 0.005 and after > 0.5 * before
    # the reference run measured errors at the reference's times, interpolated
    res = run("localize", d / "map.yaml", log, "-o", d / "stop9", "--particles", "500",
              "--reference", truth)  # fmt: skip
    assert "position" in res.output


def test_reference_on_another_clock_is_lined_up_by_itself(sim, tmp_path):
    """A reference stamped 12,345.6 s off the log's clock: localize finds the offset from
    the motion, says it, and scores against it; --reference-offset overrides it."""
    d, world = sim
    ref = tmp_path / "shifted.csv"
    rows = np.column_stack([100.0 - 12345.6 + 0.2 * np.arange(150), world.poses[:150]])
    np.savetxt(ref, rows[::3], delimiter=",", header="time,x,y,theta", comments="")
    out = tmp_path / "o"
    res = run("localize", d / "map.yaml", d / "sim.log", "-o", out, "-n", "500",
              "--reference", ref)  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "note: reference time offset +12345.600000 s" in res.output
    assert "position" in res.output and "median" in res.output
    res = run("localize", d / "map.yaml", d / "sim.log", "-o", out, "-n", "500",
              "--reference", ref, "--reference-offset", "0")  # fmt: skip
    assert res.exit_code == 1 and "reference-offset" in res.output
