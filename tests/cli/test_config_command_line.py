"""Every configuration file a command writes records the command line that made it, the probmap
version and the configuration class, and still loads back (issue 21: "outputs record the
resolved configuration, the command line and the package version")."""

from __future__ import annotations

import importlib.metadata
import sys

import pytest
import yaml
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.config import load_config

register(app)


def _run(monkeypatch, *args):
    argv = ["/some/venv/bin/probmap", *(str(a) for a in args)]
    monkeypatch.setattr(sys, "argv", argv)  # what command_line() reads
    res = CliRunner().invoke(app, argv[1:], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    return "probmap " + " ".join(argv[1:])


def _check(path, cls_name, command):
    text = path.read_text()
    first = text.splitlines()[0]
    assert first == f"# command: {command}", first
    doc = yaml.safe_load(text)
    assert doc["probmap_version"] == importlib.metadata.version("probmap")
    assert doc["config_class"] == cls_name
    return doc


def test_map_and_demo_record_their_command_line(monkeypatch, sim_log, tmp_path):
    from probmap.pipelines import MappingConfig

    log = sim_log(tmp_path / "tour.clf")
    command = _run(monkeypatch, "map", log, "-o", tmp_path / "m", "--resolution", "0.1")
    doc = _check(tmp_path / "m.config.yaml", "MappingConfig", command)
    assert doc["resolution"] == 0.1
    assert load_config(MappingConfig, tmp_path / "m.config.yaml").resolution == 0.1
    command = _run(monkeypatch, "demo", "-o", tmp_path / "demo")
    _check(tmp_path / "demo" / "map.config.yaml", "MappingConfig", command)


def test_slam_grid_records_its_command_line(monkeypatch, sim_log, tmp_path):
    from probmap.slam.laser.submap_slam import SubmapSlamConfig

    log = sim_log(tmp_path / "tour.clf")
    command = _run(monkeypatch, "slam", "grid", log, "-o", tmp_path / "s")
    _check(tmp_path / "s.config.yaml", "SubmapSlamConfig", command)
    assert isinstance(load_config(SubmapSlamConfig, tmp_path / "s.config.yaml"), SubmapSlamConfig)


@pytest.mark.parametrize("method", ["ekf", "fastslam"])
def test_landmark_slam_records_its_command_line(monkeypatch, tmp_path, method):
    out = tmp_path / method
    command = _run(monkeypatch, "slam", method, "simulation", "-o", out, "--end-time", "20")
    text = (out / "config.yaml").read_text()
    assert text.splitlines()[0] == f"# command: {command}"
    assert yaml.safe_load(text)["probmap_version"] == importlib.metadata.version("probmap")
