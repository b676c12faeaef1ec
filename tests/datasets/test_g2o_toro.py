"""TORO records, format detection, vertex-less odometry chaining, the optimizer's arrays, and the
g2o round trip of an optimized graph."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.datasets.g2o import (
    pose_graph_arrays,
    read_g2o,
    read_pose_graph,
    with_poses,
    write_g2o,
)
from probmap.datasets.protocol import DatasetError
from probmap.geometry.se2 import compose, inverse

TORO = """VERTEX2 0 0 0 0
VERTEX2 1 1.0 0.1 0.2
VERTEX2 2 2.0 0.3 0.1
EDGE2 0 1 1.0 0.0 0.1 11 12 22 33 13 23
EDGE2 1 2 1.0 0.1 0.0 100 0 100 1000 0 0
EQUIV 2 0
"""


def test_toro_information_order(tmp_path):
    p = tmp_path / "g.graph"
    p.write_text(TORO)
    g = read_pose_graph(p)
    assert g.format == "toro" and not g.chained
    assert g.equivalences == [(2, 0)]
    assert np.array_equal(g.pose_edges[0].information, [[11, 12, 13], [12, 22, 23], [13, 23, 33]])
    assert np.array_equal(g.pose_edges[0].measurement, [1.0, 0.0, 0.1])


def test_format_is_recognised_by_content_not_name(tmp_path):
    p = tmp_path / "looks_like.g2o"
    p.write_text(TORO)
    assert read_g2o(p).format == "toro"
    q = tmp_path / "looks_like.graph"
    q.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    assert read_pose_graph(q).format == "g2o"


def test_toro_to_g2o_round_trip(tmp_path):
    p = tmp_path / "g.graph"
    p.write_text(TORO)
    g = read_pose_graph(p)
    out = write_g2o(tmp_path / "out.g2o", g)
    h = read_pose_graph(out)
    assert h.format == "g2o"
    assert all(np.array_equal(g.poses[k], h.poses[k]) for k in g.poses)
    for a, b in zip(g.pose_edges, h.pose_edges, strict=True):
        assert (a.i, a.j) == (b.i, b.j)
        assert np.array_equal(a.measurement, b.measurement)
        assert np.array_equal(a.information, b.information)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["g.graph", "out.g2o"]


def test_vertexless_file_chains_odometry(tmp_path):
    rng = np.random.default_rng(0)
    z = rng.normal(0, 1, (6, 3))
    lines = [
        f"EDGE_SE2 {i} {i + 1} {float(z[i, 0])!r} {float(z[i, 1])!r} {float(z[i, 2])!r} 1 0 0 1 0 1"
        for i in range(4)
    ]
    # a loop closure before the last odometry edge, and the last one written backwards
    lines.append(
        f"EDGE_SE2 0 3 {float(z[4, 0])!r} {float(z[4, 1])!r} {float(z[4, 2])!r} 1 0 0 1 0 1"
    )
    lines.append(
        f"EDGE_SE2 5 4 {float(z[5, 0])!r} {float(z[5, 1])!r} {float(z[5, 2])!r} 1 0 0 1 0 1"
    )
    p = tmp_path / "odo.g2o"
    p.write_text("\n".join(lines) + "\n")
    g = read_pose_graph(p)
    assert g.chained and sorted(g.poses) == [0, 1, 2, 3, 4, 5]
    want = np.zeros(3)
    for i in range(4):
        assert np.allclose(g.poses[i], want)
        want = compose(want, z[i])
    assert np.allclose(g.poses[4], want)
    assert np.allclose(g.poses[5], compose(want, inverse(z[5])))


def test_vertexless_gap_names_the_line(tmp_path):
    p = tmp_path / "gap.g2o"
    p.write_text("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 2 3 1 0 0 1 0 0 1 0 1\n")
    with pytest.raises(DatasetError, match=r"gap.g2o, line 2: .*no odometry edge 1 -> 2"):
        read_pose_graph(p)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("VERTEX2 0 0 0\n", "line 1: VERTEX2 needs 4 fields"),
        ("VERTEX2 0 0 0 0\nVERTEX2 1 0 0 0\nEDGE2 0 1 1 0 0 1 0 1 1 0 x\n", "line 3: bad number"),
        (
            "VERTEX2 0 0 0 0\nEDGE2 0 7 1 0 0 1 0 1 1 0 0\n",
            "line 2: EDGE2 0 7 references a missing",
        ),
        ("VERTEX2 0 0 0 0\nEQUIV 0\n", "line 2: EQUIV needs 2 fields"),
        ("VERTEX2 0 0 0 0\nEQUIV a 0\n", "line 2: bad number"),
        ("VERTEX2 0 0 0 inf\n", "line 1: non-finite"),
    ],
)
def test_bad_toro_input_names_file_and_line(tmp_path, text, match):
    p = tmp_path / "bad.graph"
    p.write_text(text)
    with pytest.raises(DatasetError, match=match) as info:
        read_pose_graph(p)
    assert str(p) in str(info.value) and "\n" not in str(info.value)


def test_arrays_map_ids_to_rows_and_back(tmp_path):
    p = tmp_path / "g.g2o"
    p.write_text(
        "VERTEX_SE2 10 0 0 0\nVERTEX_SE2 30 2 0 0\nVERTEX_SE2 20 1 0 0\nFIX 20\n"
        "EDGE_SE2 10 20 1 0 0 1 0 0 1 0 1\nEDGE_SE2 20 30 1 0 0 1 0 0 1 0 1\n"
    )
    g = read_pose_graph(p)
    a = pose_graph_arrays(g)
    assert a.ids.tolist() == [10, 20, 30]
    assert a.edges.tolist() == [[0, 1], [1, 2]] and a.fixed.tolist() == [1]
    assert np.array_equal(a.poses[:, 0], [0, 1, 2])
    h = with_poses(g, a.ids, a.poses + 1.0)
    assert np.array_equal(h.poses[30], [3.0, 1.0, 1.0]) and np.array_equal(g.poses[30], [2, 0, 0])
    with pytest.raises(ValueError, match="no vertex 99"):
        with_poses(g, [99], np.zeros((1, 3)))


def test_arrays_refuse_landmark_edges(tmp_path):
    p = tmp_path / "lm.g2o"
    p.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_XY 1 1 1\nEDGE_SE2_XY 0 1 1 1 1 0 1\n")
    with pytest.raises(ValueError, match="landmark edges"):
        pose_graph_arrays(read_pose_graph(p))


@pytest.mark.realdata
def test_w10000_equiv_lines_are_kept_not_merged(shared_data):
    """GTSAM's load2D ignores EQUIV: 10 000 poses, 64 311 edges, initial error 2.76031e7."""
    from probmap.slam.posegraph.optimize import graph_error

    g = read_pose_graph(shared_data("pose-graphs/w10000.graph"))
    a = pose_graph_arrays(g)
    assert (len(a.ids), len(a.edges), len(g.equivalences)) == (10000, 64311, 5875)
    assert graph_error(a.poses, a.edges, a.measurements, a.information) == pytest.approx(
        2.76031e7, rel=1e-5
    )


@pytest.mark.realdata
def test_kitti_without_vertices_matches_gtsam_initial_error(shared_data):
    from probmap.slam.posegraph.optimize import graph_error

    g = read_pose_graph(shared_data("pose-graphs/kitti_00.g2o"))
    a = pose_graph_arrays(g)
    assert g.chained and (len(a.ids), len(a.edges)) == (4541, 4677)
    # GTSAM's load2D chains the same way: 37308573.875 (measured with gtsam 4.3)
    assert graph_error(a.poses, a.edges, a.measurements, a.information) == pytest.approx(
        37308573.875, rel=1e-9
    )
