"""CLI: probmap optimize writes the optimized graph and a summary; bad input is one line, exit 1."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.datasets.g2o import pose_graph_arrays, read_pose_graph
from probmap.geometry.se2 import between, compose

register(app)
runner = CliRunner()


def run(*args: str):
    return runner.invoke(app, list(args))


def _square_graph(path, *, toro=False, false_closure=False):
    """A 4 m square of 16 poses, odometry with a distorted start, one true loop closure (and
    optionally a false one)."""
    truth = np.zeros((17, 3))
    for i in range(16):
        step = [1.0, 0.0, np.pi / 2 if i % 4 == 3 else 0.0]
        truth[i + 1] = compose(truth[i], step)
    edges = [(i, i + 1) for i in range(16)] + [(0, 16)]
    z = [between(truth[i], truth[j]) for i, j in edges]
    if false_closure:
        edges.append((2, 10))
        z.append(np.array([1.0, 0.0, 0.0]))
    rng = np.random.default_rng(0)
    start = truth + rng.normal(0, 0.1, truth.shape)
    start[0] = truth[0]
    start, z = start.tolist(), [list(map(float, zz)) for zz in z]
    lines = []
    for n, p in enumerate(start):
        lines.append(f"{'VERTEX2' if toro else 'VERTEX_SE2'} {n} {p[0]!r} {p[1]!r} {p[2]!r}")
    for (i, j), zz in zip(edges, z, strict=True):
        info = "100 0 100 400 0 0" if toro else "100 0 0 100 0 400"
        tag = "EDGE2" if toro else "EDGE_SE2"
        lines.append(f"{tag} {i} {j} {zz[0]!r} {zz[1]!r} {zz[2]!r} {info}")
    path.write_text("\n".join(lines) + "\n")
    return truth


@pytest.mark.parametrize("toro", [False, True])
def test_optimize_writes_graph_and_summary(tmp_path, toro):
    src = tmp_path / ("square.graph" if toro else "square.g2o")
    truth = _square_graph(src, toro=toro)
    out = tmp_path / "out.g2o"
    res = run("optimize", str(src), "-o", str(out), "--init", "given")
    assert res.exit_code == 0, res.output
    for word in ("nodes", "17", "edges", "initial error", "final error", "iterations", "time"):
        assert word in res.output
    a = pose_graph_arrays(read_pose_graph(out))
    assert np.allclose(a.poses[:, :2], truth[:, :2], atol=1e-6)
    written = sorted(x.name for x in tmp_path.iterdir())
    assert written == sorted([src.name, "out.g2o", "out.config.yaml"])


def test_robust_closures_only(tmp_path):
    src = tmp_path / "square.g2o"
    truth = _square_graph(src, false_closure=True)
    out = tmp_path / "out.g2o"
    res = run("optimize", str(src), "-o", str(out), "--robust", "dcs", "--robust-edges", "closures")
    assert res.exit_code == 0, res.output
    assert "dcs" in res.output and "weight < 0.5" in res.output
    a = pose_graph_arrays(read_pose_graph(out))
    assert np.abs(a.poses[:, :2] - truth[:, :2]).max() < 0.05


def test_lago_start(tmp_path):
    src = tmp_path / "square.g2o"
    truth = _square_graph(src)
    res = run("optimize", str(src), "-o", str(tmp_path / "o.g2o"), "--init", "lago")
    assert res.exit_code == 0 and "LAGO" in res.output
    a = pose_graph_arrays(read_pose_graph(tmp_path / "o.g2o"))
    assert np.allclose(a.poses[:, :2], truth[:, :2], atol=1e-6)


@pytest.mark.parametrize(
    ("content", "args", "match"),
    [
        ("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", [], "line 2"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 0 0 0 x\n", [], "line 2: bad number"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n", [], "vertex 1 is not joined"),
        (None, ["--robust", "tukey"], "--robust must be"),
        (None, ["--init", "chordal"], "--init must be"),
        (None, ["--max-iterations", "-3"], "max_iterations"),
    ],
)
def test_errors_are_one_line_and_exit_1(tmp_path, content, args, match):
    src = tmp_path / "g.g2o"
    if content is None:
        _square_graph(src)
    else:
        src.write_text(content)
    out = tmp_path / "out.g2o"
    res = run("optimize", str(src), "-o", str(out), *args)
    assert res.exit_code == 1
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and match in lines[0], res.output
    assert not out.exists()


def test_missing_file(tmp_path):
    res = run("optimize", str(tmp_path / "nope.g2o"), "-o", str(tmp_path / "o.g2o"))
    assert res.exit_code == 1 and res.output.startswith("error: ") and "nope.g2o" in res.output
