"""``--tum`` on ``slam grid``, ``localize`` and ``slam ekf|seif``: the TUM file holds the same
poses as the command's trajectory CSV, and is written with the other files (all or none)."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.datasets.tum import read_tum
from probmap.metrics.relations import read_trajectory

register(app)
runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def _same_poses(csv_path, tum_path) -> None:
    t_csv, p_csv = read_trajectory(csv_path)
    t_tum, p_tum = read_tum(tum_path)
    assert t_tum.shape == t_csv.shape and len(t_tum) > 10
    np.testing.assert_allclose(t_tum, t_csv, rtol=0, atol=2e-6)
    np.testing.assert_allclose(p_tum[:, :2], p_csv[:, :2], rtol=0, atol=2e-6)
    dtheta = (p_tum[:, 2] - p_csv[:, 2] + np.pi) % (2 * np.pi) - np.pi
    assert np.abs(dtheta).max() < 2e-6
    t_again, p_again = read_trajectory(tum_path)  # the metrics read .tum files too
    np.testing.assert_array_equal(t_again, t_tum)
    np.testing.assert_array_equal(p_again, p_tum)


@pytest.fixture(scope="module")
def log_and_map(tmp_path_factory):
    from probmap.sim.floorplan import simulate_laser_world

    d = tmp_path_factory.mktemp("tum")
    w = simulate_laser_world(seed=1, size=(12.0, 8.0), step=0.2, range_noise=0.01)
    lines = [f"PARAM robot_front_laser_max {w.max_range}"]
    for i, (p, r) in enumerate(zip(w.poses, w.ranges, strict=True)):
        rs = " ".join(f"{v:.3f}" for v in r)
        pose = f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}"
        lines.append(f"FLASER {len(r)} {rs} {pose} {pose} {i * 0.2:.3f} sim {i * 0.2:.3f}")
    log = d / "sim.log"
    log.write_text("\n".join(lines) + "\n")
    res = run("map", log, "-o", d / "map")
    assert res.exit_code == 0, res.output
    return log, d / "map.yaml"


@pytest.mark.parametrize("method", ["graph", "rbpf"])
def test_slam_grid_tum(log_and_map, tmp_path, method):
    log, _ = log_and_map
    fast = ["--particles", "5", "--end-time", "12"] if method == "rbpf" else []
    res = run("slam", "grid", log, "-o", tmp_path / "run", "--method", method, "--tum", *fast)
    assert res.exit_code == 0, res.output
    assert (tmp_path / "run.tum").exists()
    _same_poses(tmp_path / "run.trajectory.csv", tmp_path / "run.tum")


def test_slam_grid_without_tum_writes_none(log_and_map, tmp_path):
    log, _ = log_and_map
    res = run("slam", "grid", log, "-o", tmp_path / "run")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "run.trajectory.csv").exists() and not (tmp_path / "run.tum").exists()


@pytest.mark.filterwarnings("ignore:the filter lost track")
def test_localize_tum(log_and_map, tmp_path):
    log, map_yaml = log_and_map
    out = tmp_path / "loc"
    args = ["--particles", "300", "--stop", "140", "--allow-lost"]  # TUM vs CSV, not tracking
    res = run("localize", map_yaml, log, "-o", out, *args, "--tum")
    assert res.exit_code == 0, res.output
    _same_poses(out / "trajectory.csv", out / "trajectory.tum")


@pytest.mark.parametrize("command", ["ekf", "seif"])
def test_landmark_slam_tum(tmp_path, monkeypatch, command):
    from dataclasses import replace

    from probmap.datasets import registry

    small = replace(registry.DATASETS["simulation"], options={"n_landmarks": 40, "n_steps": 300})
    monkeypatch.setitem(registry.DATASETS, "simulation", small)  # a short run
    out = tmp_path / command
    res = run("slam", command, "simulation", "-o", out, "--no-plot", "--tum")
    assert res.exit_code == 0, res.output
    assert len(read_tum(out / "trajectory.tum")[0]) == 300
    _same_poses(out / "trajectory.csv", out / "trajectory.tum")
