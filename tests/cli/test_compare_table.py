"""``probmap slam compare``'s table and footnote (issue 21: the footnote named columns that were
not in the table and called an unaligned RMSE "aligned")."""

from __future__ import annotations

import re

import pytest
from typer.testing import CliRunner

import probmap.cli.landmark_slam
from probmap.cli import register
from probmap.cli.app import app

register(app)


@pytest.fixture
def small(monkeypatch):
    from probmap.datasets.simulation import simulate_landmarks

    ds = simulate_landmarks(30, 40, seed=3)
    # every landmark command reads its dataset through slam.open_landmark_dataset
    monkeypatch.setattr(probmap.cli.landmark_slam, "open_landmark_dataset", lambda *args: ds)


def test_footnote_explains_exactly_the_columns_shown(small):
    res = CliRunner().invoke(app, ["slam", "compare", "simulation", "--methods", "ekf,seif"])
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    head = next(ln for ln in lines if "estimator" in ln)
    headers = [h.strip() for h in re.split(r"[┃│]", head) if h.strip()]
    assert headers[:5] == ["estimator", "ms/step", "median", "MiB", "map"]
    errors = headers[5:]
    assert errors == ["robot", "robot al", "lm", "lm al", "ANEES"]  # no GPS in a simulation
    notes = {ln.split(":", 1)[0] for ln in lines if re.match(r"^[\w/ ]+: ", ln)}
    for col in errors[:-1]:
        assert col in notes, (col, notes)
    assert "GPS al" not in notes and "GPS" not in res.output.split("┘")[-1]
    unaligned = next(ln for ln in lines if ln.startswith("robot: "))
    aligned = next(ln for ln in lines if ln.startswith("robot al: "))
    assert "fit" not in unaligned and "SE(2) fit" in aligned
    for row in ("EKF", "SEIF-10"):  # no figure cut short
        cells = next(ln for ln in lines if ln.strip("│ ").startswith(row))
        assert "…" not in cells


def test_config_sections_set_each_methods_configuration(small, tmp_path):
    cfg = tmp_path / "compare.yaml"
    cfg.write_text("fastslam:\n  n_particles: 5\n  version: 1\nseif:\n  max_active: 4\n")
    res = CliRunner().invoke(
        app,
        ["slam", "compare", "simulation", "--methods", "seif,fastslam", "--config", cfg,
         "--max-active", "6"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    # both sections applied, and the option over the seif section's max_active: 4
    assert "SEIF-6 " in res.output and "FastSLAM-1.0" in res.output
    cfg.write_text("fastslam:\n  n_partcles: 5\n")
    res = CliRunner().invoke(
        app, ["slam", "compare", "simulation", "--methods", "fastslam", "--config", cfg]
    )
    assert res.exit_code == 1
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and f"{cfg}: fastslam" in lines[0] and "n_partcles" in lines[0]
