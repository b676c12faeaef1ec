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
    assert written == sorted([src.name, "out.g2o", "out.config.yaml", "out.plot.png"])
    assert "wrote" + str(tmp_path / "out.plot.png") in "".join(res.output.split())
    assert (tmp_path / "out.plot.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (tmp_path / "out.plot.png").unlink()
    res = run("optimize", str(src), "-o", str(out), "--init", "given", "--no-plot")
    assert res.exit_code == 0 and not (tmp_path / "out.plot.png").exists()


def test_the_picture_shows_the_graph_before_and_after(tmp_path, monkeypatch):
    """The two panels draw the file's poses and the optimized ones: the odometry chain (16
    edges) in blue on top, the closure (1 edge) light under it, the false closure red."""
    from matplotlib.figure import Figure

    drawn = []
    real = Figure.savefig
    monkeypatch.setattr(
        Figure, "savefig", lambda self, *a, **k: (drawn.append(self), real(self, *a, **k))[1]
    )
    src = tmp_path / "square.g2o"
    truth = _square_graph(src, false_closure=True)
    start = pose_graph_arrays(read_pose_graph(src)).poses
    res = run("optimize", str(src), "-o", str(tmp_path / "o.g2o"), "--robust", "dcs",
              "--robust-edges", "closures")  # fmt: skip
    assert res.exit_code == 0, res.output
    before, after = drawn[0].axes
    for ax, poses in ((before, start), (after, truth)):
        green, red, blue = ax.collections
        chain = np.stack([poses[:-1, :2], poses[1:, :2]], axis=1)
        np.testing.assert_allclose(np.array(blue.get_segments()), chain, atol=0.05)
        assert blue.get_zorder() > green.get_zorder()
    assert [len(c.get_segments()) for c in before.collections] == [2, 0, 16]
    assert [len(c.get_segments()) for c in after.collections] == [1, 1, 16]  # one down-weighted
    assert "before: the file's poses" in before.get_title(loc="left")
    assert "after: " in after.get_title(loc="left") and "iterations" in after.get_title(loc="left")


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
