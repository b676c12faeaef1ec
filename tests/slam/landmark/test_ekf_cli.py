import json

import numpy as np
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app

register(app)
runner = CliRunner()


def test_slam_ekf_on_simulation_writes_outputs(tmp_path):
    out = tmp_path / "out"
    res = runner.invoke(app, ["slam", "ekf", "simulation", "-o", str(out), "--no-plot"])
    assert res.exit_code == 0, res.output
    m = json.loads((out / "metrics.json").read_text())
    assert m["steps"] == 2000 and m["ate"]["translation_m"]["rmse"] < 1.0
    tr = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1)
    assert tr.shape == (2000, 7)
    lm = np.loadtxt(out / "landmarks.csv", delimiter=",", skiprows=1)
    assert lm.shape[1] == 6 and lm.shape[0] == m["landmarks_mapped"]
    assert "ATE RMSE" in res.output


def test_slam_ekf_plot(tmp_path):
    res = runner.invoke(app, ["slam", "ekf", "simulation", "-o", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "slam.png").stat().st_size > 1000


def test_bad_dataset_is_one_line_error(tmp_path):
    res = runner.invoke(app, ["slam", "ekf", str(tmp_path / "nope"), "-o", str(tmp_path)])
    assert res.exit_code == 1
    assert "error:" in res.output and "Traceback" not in res.output
    bad = tmp_path / "vp"
    bad.mkdir()
    (bad / "inputs.dat").write_text("0.0 1.0 0.0\n0.1 x 0.0\n")
    (bad / "measurements.dat").write_text("0.1 5.0 1.0 0.1\n")
    (bad / "gps.dat").write_text("0.0 0.0 0.0\n")
    res = runner.invoke(app, ["slam", "ekf", str(bad), "-o", str(tmp_path / "o")])
    assert res.exit_code == 1 and "inputs.dat, line 2, field 'speed'" in res.output


def test_datasets_list():
    res = runner.invoke(app, ["datasets", "list"])
    assert res.exit_code == 0 and "victoria-park" in res.output and "mrclam7" in res.output


def test_metrics_record_version_command_and_configuration(tmp_path):
    """metrics.json says what ran: the probmap version, the command line and the estimator's
    configuration (the EKF's EKFConfig, field by field, loadable back)."""
    from probmap import __version__
    from probmap.config import load_config
    from probmap.slam.landmark.ekf import EKFConfig

    res = runner.invoke(app, ["slam", "ekf", "simulation", "-o", str(tmp_path), "--no-plot"])
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["probmap_version"] == __version__ and "command" in m
    assert m["configuration"]["config_class"] == "EKFConfig"
    assert load_config(EKFConfig, tmp_path / "config.yaml") == EKFConfig()  # exact copy


def test_config_file_round_trip_for_landmark_commands(tmp_path):
    """--config FILE.yaml replaces the dataset's defaults; OUTPUT/config.yaml of one run fed
    to the next gives the same configuration (ekf, fastslam)."""
    from probmap.config import load_config
    from probmap.slam.landmark.ekf import EKFConfig
    from probmap.slam.landmark.fastslam import FastSLAMConfig

    (tmp_path / "ekf.yaml").write_text("gate_probability: 0.95\n")
    res = runner.invoke(app, ["slam", "ekf", "simulation", "-o", str(tmp_path / "a"), "--no-plot",
                              "--config", str(tmp_path / "ekf.yaml")])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert load_config(EKFConfig, tmp_path / "a" / "config.yaml") == EKFConfig(
        gate_probability=0.95
    )
    (tmp_path / "fs.yaml").write_text("n_particles: 20\nversion: 1\n")
    res = runner.invoke(app, ["slam", "fastslam", "simulation", "-o", str(tmp_path / "b"),
                              "--no-plot", "--config", str(tmp_path / "fs.yaml"), "--seed", "3"])  # fmt: skip
    assert res.exit_code == 0, res.output
    got = load_config(FastSLAMConfig, tmp_path / "b" / "config.yaml")
    assert got == FastSLAMConfig(n_particles=20, version=1, seed=3)
    (tmp_path / "bad.yaml").write_text("n_particles: many\n")
    res = runner.invoke(app, ["slam", "fastslam", "simulation", "-o", str(tmp_path / "c"),
                              "--config", str(tmp_path / "bad.yaml")])  # fmt: skip
    assert res.exit_code == 1 and "bad.yaml" in res.output and "n_particles" in res.output
