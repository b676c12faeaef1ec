"""``probmap optimize`` never calls a wrong answer converged, and tells what is wrong with a
graph by the file's vertex ids (issue 38): a start far off is "not converged"; implausible
poses and ids beyond int64 are one-line read errors naming the line; zero information,
disconnected parts, missing heading or position information and a direction nothing
constrains are errors naming vertex ids; ``EDGE2`` information in g2o's order is detected as
GTSAM detects it, or taken from ``--edge2-order``."""

from __future__ import annotations

import re

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.datasets.g2o import pose_graph_arrays, read_pose_graph
from probmap.errors import DatasetError
from probmap.geometry.se2 import between, compose
from probmap.pipelines.optimize import PoseGraphConfig, check_determined, optimize_graph

register(app)


def _ring(n: int = 24):
    """Poses on a ring of ``n`` steps, its odometry and one closure, as g2o lines."""
    truth = np.zeros((n, 3))
    for i in range(1, n):
        truth[i] = compose(truth[i - 1], [1.0, 0.0, 2 * np.pi / n])
    edges = [(i, i + 1) for i in range(n - 1)] + [(n - 1, 0), (0, n // 2)]
    return truth, edges, [between(truth[i], truth[j]) for i, j in edges]


def _write(path, poses, edges, z, info=(100.0, 0.0, 0.0, 100.0, 0.0, 400.0), ids=None):
    ids = list(range(len(poses))) if ids is None else ids
    lines = [
        f"VERTEX_SE2 {ids[k]} {p[0]!r} {p[1]!r} {p[2]!r}"
        for k, p in enumerate(np.asarray(poses).tolist())
    ]
    for (i, j), m in zip(edges, z, strict=True):
        vals = " ".join(repr(float(v)) for v in (*m, *info))
        lines.append(f"EDGE_SE2 {ids[i]} {ids[j]} {vals}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_start_far_off_is_not_converged(tmp_path):
    """A vertex started 5e4 m away (inside the plausible extent): LM crawls, the relative
    decrease falls below its tolerance, and before it said "converged"."""
    truth, edges, z = _ring()
    start = truth.copy()
    start[7, 0] += 5.0e4
    g = read_pose_graph(_write(tmp_path / "far.g2o", start, edges, z))
    r = optimize_graph(g, PoseGraphConfig(init="given")).result
    assert not r.converged and "no minimum" in r.message
    assert r.final_error > 1e3
    near = truth.copy()
    near[7, :2] += 0.3  # a fair start: converged, at the truth
    r = optimize_graph(
        read_pose_graph(_write(tmp_path / "near.g2o", near, edges, z)),
        PoseGraphConfig(init="given"),
    ).result
    assert r.converged and r.final_error < 1e-12, r.message
    res = CliRunner().invoke(
        app, ["optimize", str(tmp_path / "far.g2o"), "-o", str(tmp_path / "o.g2o"),
              "--init", "given"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "no:" in res.output and "warning:" in res.output and "not converged" in res.output


def test_a_sane_cost_is_required_to_converge():
    """Edges that contradict each other by 1 km: LM reaches their compromise (a true
    minimum), but a mean chi2 per edge of millions is no converged result."""
    from probmap.slam.posegraph.optimize import MAX_MEAN_CHI2, optimize_pose_graph

    z = np.array([[1.0, 0.0, 0.0], [1000.0, 0.0, 0.0]])
    r = optimize_pose_graph(
        np.zeros((2, 3)), np.array([[0, 1], [0, 1]]), z, np.tile(np.eye(3) * 100, (2, 1, 1))
    )
    assert 2 * r.final_error / 2 > MAX_MEAN_CHI2
    assert not r.converged and "implausible" in r.message


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("VERTEX_SE2 3 100000000.0 0 0", "line 4: VERTEX_SE2 x: 1e+08 m is beyond the plausible"),
        ("VERTEX_SE2 3 0 -2e5 0", "VERTEX_SE2 y: -200000 m is beyond the plausible extent"),
        ("EDGE_SE2 0 1 3e5 0 0 1 0 0 1 0 1", "EDGE_SE2 dx: 300000 m is beyond the plausible"),
        ("VERTEX_SE2 18446744073709551616 0 0 0", "id 18446744073709551616 is beyond the 64-bit"),
        ("EDGE_SE2 0 -9223372036854775809 1 0 0 1 0 0 1 0 1", "is beyond the 64-bit integer"),
    ],
)
def test_implausible_values_and_huge_ids_are_one_line_errors(tmp_path, line, message):
    lines = ["VERTEX_SE2 0 0 0 0", "VERTEX_SE2 1 1 0 0", "VERTEX_SE2 2 2 0 0", line]
    path = tmp_path / "bad.g2o"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=re.escape(message)):
        read_pose_graph(path)
    res = CliRunner().invoke(app, ["optimize", str(path), "-o", str(tmp_path / "o.g2o")])
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert len([x for x in res.output.splitlines() if x.strip()]) == 1
    assert message.split(": ", 1)[-1] in res.output


def test_the_plausible_extent_is_the_laser_logs(tmp_path):
    from probmap.datasets.validate import PoseLimits

    path = tmp_path / "wide.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 5e5 0 0\n")
    with pytest.raises(DatasetError, match=r"\|coordinate\| <= 100000 m"):
        read_pose_graph(path)
    assert read_pose_graph(path, limits=PoseLimits(max_coordinate=1e6)).poses[1][0] == 5e5


# ----------------------------------------------------------------------------- determined
def _arrays(tmp_path, poses, edges, z, info=(100.0, 0.0, 0.0, 100.0, 0.0, 400.0), ids=None):
    g = read_pose_graph(_write(tmp_path / "g.g2o", poses, edges, z, info, ids))
    return g, pose_graph_arrays(g)


def test_under_determined_graphs_name_vertex_ids(tmp_path):
    truth, edges, z = _ring(8)
    ids = [10 * k + 1000 for k in range(8)]
    # two separate parts: 1000..1030 and 1040..1070
    part = [(i, i + 1) for i in range(3)] + [(i, i + 1) for i in range(4, 7)]
    _, a = _arrays(tmp_path, truth, part, [between(truth[i], truth[j]) for i, j in part], ids=ids)
    with pytest.raises(ValueError, match=r"vertices 1040, 1050, 1060 and 1070 are not joined to "
                       r"the fixed vertex \(1000\) by any edge"):  # fmt: skip
        check_determined(a, (0,))
    # zero information everywhere
    _, a = _arrays(tmp_path, truth, edges, z, info=(0.0,) * 6, ids=ids)
    with pytest.raises(ValueError, match="every edge has zero information"):
        check_determined(a, (0,))
    # one vertex tied only by an edge of zero information
    g, a = _arrays(tmp_path, truth, edges[:7], z[:7], ids=ids)
    a.information[6] = 0.0
    with pytest.raises(ValueError, match="vertex 1070 is not joined .* nonzero information"):
        check_determined(a, (0,))
    # no heading information anywhere: every heading is free
    _, a = _arrays(tmp_path, truth, edges, z, info=(100.0, 0.0, 0.0, 100.0, 0.0, 0.0), ids=ids)
    with pytest.raises(ValueError, match="headings are undetermined"):
        check_determined(a, (0,))
    # a straight corridor measured along its axis only: nothing constrains the side direction
    line = np.column_stack([np.arange(6.0), np.zeros(6), np.zeros(6)])
    chain = [(i, i + 1) for i in range(5)]
    _, a = _arrays(tmp_path, line, chain, [between(line[i], line[j]) for i, j in chain],
                   info=(100.0, 0.0, 0.0, 0.0, 0.0, 400.0))  # fmt: skip
    with pytest.raises(ValueError, match=r"direction \(0, 1\) .* vertices 1, 2, 3, 4 and 5"):
        check_determined(a, (0,))
    # the pipeline and the CLI say it with the file's name, in one line
    path = _write(tmp_path / "parts.g2o", truth, part, [between(truth[i], truth[j]) for i, j in part],
                  ids=ids)  # fmt: skip
    res = CliRunner().invoke(app, ["optimize", str(path), "-o", str(tmp_path / "o.g2o")])
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert f"{path}: vertices 1040, 1050, 1060 and 1070 are not joined" in res.output
    assert not (tmp_path / "o.g2o").exists()


# ----------------------------------------------------------------------------- EDGE2 order
def _toro(path, poses, edges, z, info6_toro, info6_g2o, order):
    lines = [
        f"VERTEX2 {k} {p[0]!r} {p[1]!r} {p[2]!r}" for k, p in enumerate(np.asarray(poses).tolist())
    ]
    info = info6_toro if order == "toro" else info6_g2o
    for (i, j), m in zip(edges, z, strict=True):
        lines.append(f"EDGE2 {i} {j} " + " ".join(repr(float(v)) for v in (*m, *info)))
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    ("toro", "g2o"),
    [
        # a diagonal information: GTSAM's own test of the order (which entries are zero)
        ((100.0, 0.0, 100.0, 400.0, 0.0, 0.0), (100.0, 0.0, 0.0, 100.0, 0.0, 400.0)),
        # a full one: I11 I12 I22 I33 I13 I23 = 50 5 40 300 2 3
        ((50.0, 5.0, 40.0, 300.0, 2.0, 3.0), (50.0, 5.0, 2.0, 40.0, 3.0, 300.0)),
    ],
)
def test_edge2_in_g2o_order_is_detected_and_can_be_forced(tmp_path, toro, g2o):
    truth, edges, z = _ring(12)
    start = truth + np.random.default_rng(3).normal(0, 0.05, truth.shape)
    start[0] = truth[0]
    a = read_pose_graph(_toro(tmp_path / "a.graph", start, edges, z, toro, g2o, "toro"))
    b = read_pose_graph(_toro(tmp_path / "b.graph", start, edges, z, toro, g2o, "g2o"))
    assert (a.edge2_order, b.edge2_order) == ("toro", "g2o")
    for ea, eb in zip(a.pose_edges, b.pose_edges, strict=True):
        np.testing.assert_array_equal(ea.information, eb.information)
    ra = optimize_graph(a).result
    rb = optimize_graph(b).result
    np.testing.assert_array_equal(ra.poses, rb.poses)
    # forced: the g2o-ordered file read in TORO's order is refused by the optimizer
    forced = read_pose_graph(tmp_path / "b.graph", edge2_order="g2o")
    assert forced.edge2_order == "g2o"
    wrong = read_pose_graph(tmp_path / "b.graph", edge2_order="toro")
    with pytest.raises(ValueError, match="not positive semi-definite"):
        optimize_graph(wrong)
    runner = CliRunner()
    ok = runner.invoke(app, ["optimize", str(tmp_path / "b.graph"), "-o", str(tmp_path / "o")])
    assert ok.exit_code == 0 and "g2o (detected)" in ok.output, ok.output
    bad = runner.invoke(app, ["optimize", str(tmp_path / "b.graph"), "-o", str(tmp_path / "p"),
                              "--edge2-order", "toro"])  # fmt: skip
    assert bad.exit_code == 1 and "not positive semi-definite" in bad.output


def test_edge2_that_no_order_reads_names_the_line(tmp_path):
    path = tmp_path / "x.graph"
    path.write_text(
        "VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nVERTEX2 2 2 0 0\n"
        "EDGE2 0 1 1 0 0 1 0 1 1 0 0\n"  # TORO diagonal
        "EDGE2 1 2 1 0 0 1 0 0 1 0 1\n"  # g2o diagonal: the two orders mixed
    )
    with pytest.raises(DatasetError, match="line 5: EDGE2 information is not positive"):
        read_pose_graph(path)


def test_every_standard_toro_graph_keeps_its_order():
    """The TORO files of the data set (GTSAM's w100/w10000, the nano-pgo graphs) are read in
    TORO's order, as before."""
    from conftest import _need as need

    for name in ("w100.graph", "INTEL_P_toro.graph", "CSAIL_P_toro.graph"):
        assert read_pose_graph(need(f"pose-graphs/{name}")).edge2_order == "toro"


def test_the_class_tier_verifies_when_asked():
    """PoseGraph2D (the incremental back end) checks only with ``verify=True``; the
    function tier always does. The poses are the same either way."""
    from probmap.slam.posegraph.optimize import PoseGraph2D, optimize_pose_graph

    truth, edges, z = _ring()
    start = truth.copy()
    start[7, 0] += 5.0e4

    def graph():
        g = PoseGraph2D()
        for p in start:
            g.add_node(p)
        for (i, j), m in zip(edges, z, strict=True):
            g.add_edge(i, j, m, np.diag([100.0, 100.0, 400.0]))
        return g

    fast, checked = graph(), graph()
    a = fast.optimize(100)
    b = checked.optimize(100, verify=True)
    np.testing.assert_array_equal(a.poses, b.poses)
    assert a.converged and not b.converged and "no minimum" in b.message
    info = np.tile(np.diag([100.0, 100.0, 400.0]), (len(edges), 1, 1))
    c = optimize_pose_graph(start, np.asarray(edges), np.asarray(z), info)
    assert not c.converged and c.message == b.message
