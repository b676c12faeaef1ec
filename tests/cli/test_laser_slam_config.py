"""CLI: ``probmap slam grid --config FILE.yaml`` runs with the file's configuration and writes
the resolved one, with the package version, to PREFIX.config.yaml; a bad file is one line and
exit code 1, before any output is written."""

from __future__ import annotations

import dataclasses
import importlib.metadata
import math
import re

import pytest
import yaml
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.config import load_config
from probmap.sim.floorplan import simulate_laser_world
from probmap.slam.laser.rbpf import RbpfConfig
from probmap.slam.laser.submap_slam import SubmapSlamConfig

register(app)
runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory):
    world = simulate_laser_world(
        seed=2, n_beams=180, fov=math.pi - math.pi / 180, max_range=8.0, pose_noise=(0.05, 0.05)
    )
    path = tmp_path_factory.mktemp("log") / "sim.clf"
    lines = []
    for i in range(120):
        r = " ".join(f"{v:.3f}" for v in world.ranges[i])
        pose = " ".join(f"{v:.6f}" for v in world.odometry[i])
        t = 1000.0 + world.times[i]
        lines.append(f"FLASER {len(world.ranges[i])} {r} {pose} {pose} {t:.6f} sim {t:.6f}")
    path.write_text("\n".join(lines) + "\n")
    return path


def _summary_int(output: str, key: str) -> int:
    m = re.search(rf"^\s*{key}\s+([\d,]+)", output, flags=re.MULTILINE)
    assert m, output
    return int(m.group(1).replace(",", ""))


def test_graph_config_takes_effect_and_is_recorded(sim_log, tmp_path):
    res = run("slam", "grid", sim_log, "-o", tmp_path / "d")
    assert res.exit_code == 0, res.output
    default_submaps = _summary_int(res.output, "submaps")
    # the run without --config records the defaults
    assert load_config(SubmapSlamConfig, tmp_path / "d.config.yaml") == SubmapSlamConfig()
    cfg_file = tmp_path / "small.yaml"
    cfg_file.write_text("submaps: {scans: 5}\nlocal:\n  matcher:\n    linear_window: 0.2\n")
    res = run("slam", "grid", sim_log, "-o", tmp_path / "s", "--config", cfg_file)
    assert res.exit_code == 0, res.output
    assert _summary_int(res.output, "submaps") > default_submaps
    assert len(re.findall(r"^\s*wrote\s", res.output, flags=re.MULTILINE)) == 9  # 8 + config
    suffixes = (".yaml", ".pgm", ".npz", ".png", ".trajectory.csv", ".g2o", ".plot.png")
    suffixes += (".report.json",)
    names = sorted(p.name for p in tmp_path.glob("s.*"))
    assert names == sorted(f"s{x}" for x in (*suffixes, ".config.yaml"))
    written = tmp_path / "s.config.yaml"
    doc = yaml.safe_load(written.read_text())
    assert doc["probmap_version"] == importlib.metadata.version("probmap")
    assert doc["config_class"] == "SubmapSlamConfig"
    default = SubmapSlamConfig()
    local = dataclasses.replace(
        default.local, matcher=dataclasses.replace(default.local.matcher, linear_window=0.2)
    )
    expected = dataclasses.replace(
        default, submaps=dataclasses.replace(default.submaps, scans=5), local=local
    )
    assert load_config(SubmapSlamConfig, written) == expected
    # the recorded file runs again, to the same trajectory
    res = run("slam", "grid", sim_log, "-o", tmp_path / "r", "--config", written)
    assert res.exit_code == 0, res.output
    assert (tmp_path / "r.trajectory.csv").read_text() == (
        tmp_path / "s.trajectory.csv"
    ).read_text()


def test_rbpf_config_and_options_over_it(sim_log, tmp_path):
    cfg_file = tmp_path / "rbpf.yaml"
    cfg_file.write_text("particles: 3\nseed: 7\ndegeneracy_guard: false\n")
    res = run(
        "slam", "grid", sim_log, "-o", tmp_path / "p", "--method", "rbpf",
        "--config", cfg_file, "--seed", "2", "--end-time", "5",
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert re.search(r"particles\s+3 \(", res.output), res.output
    cfg = load_config(RbpfConfig, tmp_path / "p.config.yaml")
    assert cfg == RbpfConfig(particles=3, seed=2, degeneracy_guard=False)
    assert (tmp_path / "p.trajectory.csv").exists()


def _one_line_error(res, *words):
    assert res.exit_code == 1, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    assert "Traceback" not in res.output
    for w in words:
        assert w in lines[0], (w, lines[0])


@pytest.mark.parametrize(
    ("method", "text", "words"),
    [
        ("graph", "local: {matcher: {linear_window: x}}\n", ["bad.yaml", "local.matcher", "'x'"]),
        ("graph", "submaps: {scan: 5}\n", ["bad.yaml", "submaps.scan", "scans?"]),
        ("graph", "submaps: {scans: 0}\n", ["bad.yaml", "scans"]),
        ("graph", "submap_scans: 5\n", ["bad.yaml", "submap_scans", "now submaps.scans"]),
        ("graph", "particles: 3\n", ["bad.yaml", "particles", "SubmapSlamConfig"]),
        ("rbpf", "particles: three\n", ["bad.yaml", "particles", "integer"]),
        ("rbpf", "config_class: SubmapSlamConfig\n", ["bad.yaml", "RbpfConfig"]),
        ("graph", "a: [\n", ["bad.yaml", "not valid YAML"]),
    ],
)
def test_bad_config_is_one_line_and_writes_nothing(sim_log, tmp_path, method, text, words):
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    res = run("slam", "grid", sim_log, "-o", tmp_path / "out", "--method", method, "--config", bad)
    _one_line_error(res, *words)
    assert not list(tmp_path.glob("out*"))


def test_missing_config_file(sim_log, tmp_path):
    res = run("slam", "grid", sim_log, "-o", tmp_path / "out", "--config", tmp_path / "no.yaml")
    _one_line_error(res, "no.yaml")
    assert not list(tmp_path.glob("out*"))
