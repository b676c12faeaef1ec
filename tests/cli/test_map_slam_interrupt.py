"""Ctrl-C during ``probmap map`` and landmark SLAM: one line, exit 130, and (with
--save-partial, the default) the map or results of the part run, atomically; --viz-save on both
commands; ``probmap demo --config``; the summary time covers the whole command."""

from __future__ import annotations

import json
import re
import signal

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app

register(app)


def _ctrl_c_on_call(monkeypatch, cls, name: str, call: int) -> None:
    """Deliver SIGINT (as the terminal does on Ctrl-C) during the ``call``-th call of
    ``cls.name``."""
    real = getattr(cls, name)
    calls = [0]

    def wrapped(self, *args, **kwargs):
        calls[0] += 1
        if calls[0] == call:
            signal.raise_signal(signal.SIGINT)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(cls, name, wrapped)


def _time_row(output: str) -> tuple[float, dict[str, float]]:
    text = " ".join(output.split())  # the table wraps long rows
    m = re.search(r"time ([\d.]+) s \(([^)]*)\)", text)
    assert m, output
    phases = {k: float(v) for k, v in re.findall(r"(\w+) ([\d.]+) s", m.group(2))}
    return float(m.group(1)), phases


def test_map_ctrl_c_writes_the_map_so_far_and_the_recording(tmp_path, sim_log, monkeypatch):
    pytest.importorskip("rerun")
    from probmap.grid.io import load_npz
    from probmap.grid.occupancy import OccupancyGrid
    from probmap.pipelines import MappingConfig, map_log
    from probmap.viz.live import read_recording

    log = sim_log(tmp_path / "tour.log")
    n = len(log.read_text().splitlines()) - 1
    # the live view maps 20 scans per call: Ctrl-C in the 3rd call stops after 60 scans
    _ctrl_c_on_call(monkeypatch, OccupancyGrid, "integrate_scans", 3)
    out, rrd = tmp_path / "out" / "part", tmp_path / "rec" / "part.rrd"
    res = CliRunner().invoke(
        app, ["map", str(log), "-o", str(out), "-r", "0.1", "--viz-save", str(rrd)]
    )
    assert res.exit_code == 130, res.output
    assert f"at scan 60 of {n}" in res.output
    assert f"interrupted: wrote the results of the first 60 of {n} scans" in res.output
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handler restored
    monkeypatch.undo()
    # the map written is the map of the first 60 scans
    head = tmp_path / "head.log"
    head.write_text("\n".join(log.read_text().splitlines()[:61]) + "\n")
    ref = map_log(head, MappingConfig(resolution=0.1, chunk=20))
    np.testing.assert_allclose(load_npz(f"{out}.npz").log_odds, ref.grid.log_odds, atol=1e-6)
    assert (out.parent / "part.config.yaml").exists()
    counts = read_recording(rrd)
    assert counts["/world/scan"] == 3 and counts["/world/trajectory"] >= 2
    total, phases = _time_row(res.output)
    assert (
        set(phases) == {"setup", "read", "compute", "write"}
        and total >= sum(phases.values()) - 0.25
    )


def test_map_without_save_partial_writes_nothing(tmp_path, sim_log, monkeypatch):
    from probmap.grid.occupancy import OccupancyGrid

    log = sim_log(tmp_path / "tour.log")
    _ctrl_c_on_call(monkeypatch, OccupancyGrid, "integrate_scans", 1)
    out = tmp_path / "out" / "part"
    res = CliRunner().invoke(app, ["map", str(log), "-o", str(out), "--no-save-partial"])
    assert res.exit_code == 130, res.output
    assert "interrupted: nothing written" in res.output and "Traceback" not in res.output
    assert not out.parent.exists()


def test_slam_ctrl_c_writes_the_steps_so_far(tmp_path, monkeypatch):
    pytest.importorskip("rerun")
    from probmap.slam.landmark.ekf import EKFSLAM
    from probmap.viz.live import read_recording

    _ctrl_c_on_call(monkeypatch, EKFSLAM, "update", 300)
    out, rrd = tmp_path / "out", tmp_path / "ekf.rrd"
    res = CliRunner().invoke(
        app, ["slam", "ekf", "simulation", "-o", str(out), "--no-plot", "--viz-save", str(rrd)]
    )
    assert res.exit_code == 130, res.output
    assert "at step 300 of 2,000" in res.output
    assert "interrupted: wrote the results of the first 300 of 2,000 steps" in res.output
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    tr = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1)
    assert tr.shape == (300, 7)
    m = json.loads((out / "metrics.json").read_text())
    assert m["steps"] == 300 and m["interrupted"] == {"steps": 300, "of": 2000}
    counts = read_recording(rrd)
    # the robot every 5th step (every step has measurements here) and at the end
    assert counts["/world/robot"] == 300 // 5 + 1 and counts["/world/landmark_truth"] == 1
    total, phases = _time_row(res.output)
    assert (
        set(phases) == {"setup", "read", "compute", "write"}
        and total >= sum(phases.values()) - 0.25
    )


def test_slam_without_save_partial_writes_nothing(tmp_path, monkeypatch):
    from probmap.slam.landmark.fastslam import FastSLAM

    _ctrl_c_on_call(monkeypatch, FastSLAM, "update", 20)
    out = tmp_path / "out"
    res = CliRunner().invoke(
        app, ["slam", "fastslam", "simulation", "-o", str(out), "-n", "5", "--no-save-partial"]
    )
    assert res.exit_code == 130, res.output
    assert "interrupted: nothing written" in res.output and "Traceback" not in res.output
    assert not out.exists()


def test_viz_options_are_checked_first(tmp_path, sim_log, monkeypatch):
    import builtins

    log = sim_log(tmp_path / "tour.log")
    runner = CliRunner()
    res = runner.invoke(app, ["map", str(log), "-o", str(tmp_path / "a"), "--viz-save", "x.png"])
    assert res.exit_code == 1 and "FILE.rrd" in res.output and "Traceback" not in res.output
    res = runner.invoke(
        app,
        ["map", str(log), "-o", str(tmp_path / "b"), "--method", "map", "--viz-save", "x.rrd"],
    )
    assert res.exit_code == 1 and "log-odds method on one log" in res.output
    real = builtins.__import__

    def no_rerun(name, *args, **kwargs):
        if name == "rerun" or name.startswith("rerun."):
            raise ImportError("No module named 'rerun'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_rerun)
    for args in (
        ["map", str(log), "-o", str(tmp_path / "c"), "--viz"],
        ["slam", "seif", "simulation", "-o", str(tmp_path / "d"), "--viz"],
    ):
        res = runner.invoke(app, args)
        assert res.exit_code == 1, res.output
        assert res.output.strip() == "error: the live view needs rerun: pip install 'probmap[viz]'"
    assert not [p for p in tmp_path.iterdir() if p.name != "tour.log"]


def test_demo_config(tmp_path):
    from probmap.config import load_config
    from probmap.pipelines import MappingConfig

    cfg = tmp_path / "demo.yaml"
    cfg.write_text("resolution: 0.1\np_hit: 0.8\n")
    res = CliRunner().invoke(app, ["demo", "-o", str(tmp_path / "d"), "--config", str(cfg)])
    assert res.exit_code == 0, res.output
    assert "at 0.1 m" in res.output and "accuracy" in res.output
    recorded = load_config(MappingConfig, tmp_path / "d" / "map.config.yaml")
    assert recorded == MappingConfig(resolution=0.1, p_hit=0.8)
    total, phases = _time_row(res.output)
    assert (
        set(phases) == {"setup", "simulate", "compute", "write"}
        and total >= sum(phases.values()) - 0.25
    )
    bad = CliRunner().invoke(
        app, ["demo", "--localize", "-o", str(tmp_path / "e"), "--config", str(cfg)]
    )
    assert bad.exit_code == 1 and "--config sets the mapping demo" in bad.output


def test_slam_ctrl_c_while_writing_leaves_nothing(tmp_path, monkeypatch, capsys):
    """The outputs are all or none: Ctrl-C while they are written removes them."""
    import typer

    import probmap.pipelines.landmark_slam as pipeline
    from probmap.cli.landmark_slam import run_and_report
    from probmap.datasets.simulation import simulate_landmarks
    from probmap.slam.landmark.ekf import EKFSLAM

    real = pipeline.write_slam_outputs

    def write_then_ctrl_c(*args, **kwargs):
        files = real(*args, **kwargs)
        signal.raise_signal(signal.SIGINT)
        return files

    monkeypatch.setattr(pipeline, "write_slam_outputs", write_then_ctrl_c)
    ds = simulate_landmarks(10, 50, seed=0)
    ekf = EKFSLAM(ds.motion_model, ds.measurement_model, ds.initial_pose, ds.initial_covariance)
    out = tmp_path / "out"
    with pytest.raises(typer.Exit) as exit_:
        run_and_report(ekf, ds, out, "EKF SLAM", plot=False)
    assert exit_.value.exit_code == 130
    assert "interrupted: nothing written" in capsys.readouterr().err
    assert not out.exists()
