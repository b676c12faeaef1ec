"""Ctrl-C during graph SLAM: the run stops between scans, and the map and trajectory of the
scans so far are written (exit 130); without --save-partial nothing is written."""

from __future__ import annotations

import signal

import numpy as np
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.pipelines.laser_slam import load_laser_log, run_submap_slam
from probmap.pipelines.sessions import load_session

register(app)


def test_stopped_run_equals_the_run_over_the_scans_it_got_to(tmp_path, sim_log):
    batch = load_laser_log(sim_log(tmp_path / "tour.log"))
    asked = [0]

    def stop() -> bool:
        asked[0] += 1
        return asked[0] > 60  # asked before scans 2, 3, ...: stops before scan 62

    run = run_submap_slam(batch, stop=stop)
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
    whole = run_submap_slam(first)
    assert not whole.interrupted
    np.testing.assert_array_equal(run.sensor_poses, whole.sensor_poses)
    np.testing.assert_array_equal(run.grid.log_odds, whole.grid.log_odds)


def _ctrl_c_at(monkeypatch, scan: int) -> None:
    """Deliver SIGINT (as the terminal does on Ctrl-C) while scan ``scan`` is processed."""
    from probmap.slam.laser.submap_slam import SubmapSlam

    real = SubmapSlam.add_scan
    calls = [0]

    def add_scan(self, *args, **kwargs):
        calls[0] += 1
        if calls[0] == scan:
            signal.raise_signal(signal.SIGINT)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(SubmapSlam, "add_scan", add_scan)


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


def test_resumed_pipeline_run_equals_the_whole_run(tmp_path, sim_log):
    """run_submap_slam on the first half with save_session, then on the second half with
    resume: the same trajectory and map as one run, covering every scan."""
    from dataclasses import replace

    batch = load_laser_log(sim_log(tmp_path / "tour.log"))
    n = len(batch.times)
    h = n // 2

    def part(lo: int, hi: int):
        return replace(
            batch, times=batch.times[lo:hi], ranges=batch.ranges[lo:hi],
            laser_poses=batch.laser_poses[lo:hi], robot_poses=batch.robot_poses[lo:hi],
            angles=batch.angles if np.ndim(batch.angles) == 1 else batch.angles[lo:hi],
            beams=batch.beams[lo:hi],
        )  # fmt: skip

    whole = run_submap_slam(batch)
    first = run_submap_slam(part(0, h), save_session=tmp_path / "s.session")
    assert len(first.times) == h
    second = run_submap_slam(part(h, n), resume=load_session(tmp_path / "s.session"))
    assert len(second.times) == n and second.scans_total == n and not second.interrupted
    np.testing.assert_array_equal(second.times, whole.times)
    np.testing.assert_array_equal(second.poses, whole.poses)
    np.testing.assert_array_equal(second.grid.log_odds, whole.grid.log_odds)


def test_save_session_and_resume_on_the_cli(tmp_path, sim_log):
    """Two halves of a log, the second resuming the first's session: the trajectory file
    equals the whole log's, row for row."""
    lines = sim_log(tmp_path / "tour.log").read_text().splitlines()
    head, scans = lines[:1], lines[1:]
    h = len(scans) // 2
    (tmp_path / "a.log").write_text("\n".join(head + scans[:h]) + "\n")
    (tmp_path / "b.log").write_text("\n".join(head + scans[h:]) + "\n")
    runner = CliRunner()
    whole = runner.invoke(
        app, ["slam", "grid", str(tmp_path / "tour.log"), "-o", str(tmp_path / "w")]
    )
    assert whole.exit_code == 0, whole.output
    session = tmp_path / "s" / "tour.session"
    first = runner.invoke(
        app, ["slam", "grid", str(tmp_path / "a.log"), "-o", str(tmp_path / "a"),
              "--save-session", str(session)],
    )  # fmt: skip
    assert first.exit_code == 0, first.output
    assert session.is_file()
    second = runner.invoke(
        app, ["slam", "grid", str(tmp_path / "b.log"), "-o", str(tmp_path / "b"),
              "--resume", str(session)],
    )  # fmt: skip
    assert second.exit_code == 0, second.output
    assert f"{h:,} scans before this log" in second.output
    assert (tmp_path / "b.trajectory.csv").read_text() == (
        tmp_path / "w.trajectory.csv"
    ).read_text()
    bad = runner.invoke(
        app, ["slam", "grid", str(tmp_path / "b.log"), "-o", str(tmp_path / "c"),
              "--resume", str(tmp_path / "a.log")],
    )  # fmt: skip
    assert bad.exit_code == 1 and "not a probmap graph-SLAM session" in bad.output
    assert not (tmp_path / "c.yaml").exists()
