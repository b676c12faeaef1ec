"""Ctrl-C during graph SLAM: the run stops between scans, and the map and trajectory of the
scans so far are written (exit 130); without --save-partial nothing is written."""

from __future__ import annotations

import signal

import numpy as np
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.pipelines.grid_slam import load_laser_log, run_graph_slam

register(app)


def test_stopped_run_equals_the_run_over_the_scans_it_got_to(tmp_path, sim_log):
    batch = load_laser_log(sim_log(tmp_path / "tour.log"))
    asked = [0]

    def stop() -> bool:
        asked[0] += 1
        return asked[0] > 60  # asked before scans 2, 3, ...: stops before scan 62

    run = run_graph_slam(batch, stop=stop)
    k = len(run.times)
    assert run.interrupted and k == 62 and run.scans_total == len(batch.times)
    assert run.poses.shape == (k, 3) and run.grid.observed.any()
    from dataclasses import replace

    first = replace(
        batch, times=batch.times[:k], ranges=batch.ranges[:k], laser_poses=batch.laser_poses[:k],
        robot_poses=batch.robot_poses[:k],
        angles=batch.angles if np.ndim(batch.angles) == 1 else batch.angles[:k],
        beams=batch.beams[:k],
    )  # fmt: skip
    whole = run_graph_slam(first)
    assert not whole.interrupted
    np.testing.assert_array_equal(run.sensor_poses, whole.sensor_poses)
    np.testing.assert_array_equal(run.grid.log_odds, whole.grid.log_odds)


def _ctrl_c_at(monkeypatch, scan: int) -> None:
    """Deliver SIGINT (as the terminal does on Ctrl-C) while scan ``scan`` is processed."""
    from probmap.slam.graph_slam import GraphSlam

    real = GraphSlam.add_scan
    calls = [0]

    def add_scan(self, *args, **kwargs):
        calls[0] += 1
        if calls[0] == scan:
            signal.raise_signal(signal.SIGINT)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(GraphSlam, "add_scan", add_scan)


def test_ctrl_c_writes_the_partial_map_and_exits_130(tmp_path, sim_log, monkeypatch):
    log = sim_log(tmp_path / "tour.log")
    _ctrl_c_at(monkeypatch, 40)
    out = tmp_path / "out" / "part"
    res = CliRunner().invoke(app, ["slam", "grid", str(log), "-o", str(out)])
    assert res.exit_code == 130, res.output
    assert "interrupted" in res.output and "first 40 of" in res.output
    names = sorted(p.name for p in out.parent.iterdir())
    assert "part.yaml" in names and "part.trajectory.csv" in names
    rows = (out.parent / "part.trajectory.csv").read_text().splitlines()
    assert len(rows) == 1 + 40  # header and one pose per scan it got to
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handler restored


def test_without_save_partial_ctrl_c_writes_nothing(tmp_path, sim_log, monkeypatch):
    log = sim_log(tmp_path / "tour.log")
    _ctrl_c_at(monkeypatch, 40)
    out = tmp_path / "out" / "part"
    res = CliRunner().invoke(app, ["slam", "grid", str(log), "-o", str(out), "--no-save-partial"])
    assert res.exit_code != 0
    assert not out.parent.exists()
