"""CLI: probmap semantic (labelled scans to maps), its errors as one line, the demo printer."""

from __future__ import annotations

import numpy as np
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.grid.semantic_io import LabelledScans, load_semantic, write_labelled_scans
from probmap.sim.semantic import simulate_labelled_world

register(app)
runner = CliRunner()


def _scans_file(path, **changes):
    w = simulate_labelled_world(seed=2, size=(8.0, 12.0), step=0.3)
    sc = LabelledScans(w.poses, w.ranges, w.angles, w.max_range, w.classes, labels=w.labels)
    for k, v in changes.items():
        object.__setattr__(sc, k, v)
    return write_labelled_scans(path, sc), w


def test_semantic_command_writes_maps(tmp_path):
    path, w = _scans_file(tmp_path / "scans.npz")
    res = runner.invoke(app, ["semantic", str(path), "-o", str(tmp_path / "out"), "--chunk", "50"])
    assert res.exit_code == 0, res.output
    for name in ("out.npz", "out.png", "out.occupancy.yaml", "out.occupancy.pgm"):
        assert (tmp_path / name).exists()
    assert "wall" in res.output and "cells updated" in res.output
    grid = load_semantic(tmp_path / "out.npz")
    assert grid.classes == w.classes and grid.scans_integrated == len(w.poses)
    # chunked integration through the CLI equals one batch in the library
    ref = LabelledScans(w.poses, w.ranges, w.angles, w.max_range, w.classes, labels=w.labels)
    g = ref.make_grid()
    ref.integrate_into(g)
    np.testing.assert_array_equal(g.log_odds, grid.log_odds)


def test_semantic_command_bad_input(tmp_path):
    labels = simulate_labelled_world(seed=2, size=(8.0, 12.0), step=0.3).labels.copy()
    labels[5, labels[5].argmax()] = 9
    path, _ = _scans_file(tmp_path / "bad.npz", labels=labels)
    res = runner.invoke(app, ["semantic", str(path), "-o", str(tmp_path / "out")])
    assert res.exit_code == 1
    assert "error:" in res.output and "scan 5" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "out.npz").exists()
    res = runner.invoke(app, ["semantic", str(tmp_path / "none.npz"), "-o", str(tmp_path / "o")])
    assert res.exit_code == 1 and "no such file" in res.output
    good, _ = _scans_file(tmp_path / "good.npz")
    (tmp_path / "afile").write_text("")
    res = runner.invoke(app, ["semantic", str(good), "-o", str(tmp_path / "afile" / "o")])
    assert res.exit_code == 1 and "not a folder" in res.output
    res = runner.invoke(app, ["semantic", str(good), "-o", str(tmp_path / "o"), "--p-hit", "2"])
    assert res.exit_code == 1 and "p_hit" in res.output


def test_demo_printer(tmp_path, capsys):
    from probmap.cli.semantic import print_semantic_demo
    from probmap.pipelines.semantic import run_semantic_demo

    print_semantic_demo(run_semantic_demo(tmp_path))
    out = capsys.readouterr().out
    assert "per-class IoU" in out and "pillar" in out and "wrote" in out
