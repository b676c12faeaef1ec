import numpy as np
import pytest

from probmap.datasets.g2o import LandmarkEdge, PoseEdge, PoseGraph, read_g2o, write_g2o
from probmap.datasets.protocol import DatasetError

SAMPLE = """VERTEX_SE2 0 0 0 0
VERTEX_SE2 1 1.0 0.5 0.1
VERTEX_XY 5 3.0 4.0
FIX 0
EDGE_SE2 0 1 1.0 0.5 0.1 100 1 2 200 3 500
EDGE_SE2_XY 1 5 2.0 3.0 10 0.5 20
"""


def test_parse_sample(tmp_path):
    p = tmp_path / "g.g2o"
    p.write_text(SAMPLE)
    g = read_g2o(p)
    assert set(g.poses) == {0, 1} and set(g.landmarks) == {5} and g.fixed == [0]
    e = g.pose_edges[0]
    assert np.allclose(e.information, [[100, 1, 2], [1, 200, 3], [2, 3, 500]])
    le = g.landmark_edges[0]
    assert np.allclose(le.information, [[10, 0.5], [0.5, 20]]) and np.allclose(
        le.measurement, [2, 3]
    )


def test_round_trip_random_graph(tmp_path):
    rng = np.random.default_rng(0)
    g = PoseGraph()
    for i in range(20):
        g.poses[i] = rng.normal(size=3)
    for j in range(100, 105):
        g.landmarks[j] = rng.normal(size=2)
    for i in range(19):
        A = rng.normal(size=(3, 3))
        g.pose_edges.append(PoseEdge(i, i + 1, rng.normal(size=3), A @ A.T))
        B = rng.normal(size=(2, 2))
        g.landmark_edges.append(LandmarkEdge(i, 100 + i % 5, rng.normal(size=2), B @ B.T))
    p = write_g2o(tmp_path / "out.g2o", g)
    h = read_g2o(p)
    assert all(np.array_equal(g.poses[k], h.poses[k]) for k in g.poses)
    assert all(np.array_equal(g.landmarks[k], h.landmarks[k]) for k in g.landmarks)
    for a, b in zip(g.pose_edges + g.landmark_edges, h.pose_edges + h.landmark_edges, strict=True):
        assert (a.i, a.j) == (b.i, b.j)
        assert np.array_equal(a.measurement, b.measurement)
        assert np.allclose(a.information, b.information, rtol=0, atol=1e-15)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["out.g2o"]


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("VERTEX_SE2 0 0 0\n", "line 1.*needs 4 fields"),
        ("VERTEX_SE2 0 0 0 x\n", "line 1.*bad number"),
        ("VERTEX_SE2 0 0 0 nan\n", "non-finite"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 0 1 1 1\n", "line 2.*duplicate"),
        ("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", "line 2.*missing vertex"),
        ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n", "unknown record"),
    ],
)
def test_bad_input(tmp_path, text, match):
    p = tmp_path / "bad.g2o"
    p.write_text(text)
    with pytest.raises(DatasetError, match=match):
        read_g2o(p)


def test_skip_unknown_warns(tmp_path):
    p = tmp_path / "g.g2o"
    p.write_text("FOO 1 2\n" + SAMPLE)
    with pytest.warns(UserWarning, match="skipped 1"):
        g = read_g2o(p, skip_unknown=True)
    assert len(g.poses) == 2


@pytest.mark.realdata
def test_real_victoria_park_graph(shared_data):
    g = read_g2o(shared_data("victoria-park/victoriaPark-full.g2o"))
    assert (len(g.poses), len(g.landmarks)) == (6969, 151)
    assert (len(g.pose_edges), len(g.landmark_edges)) == (6968, 3640)


def test_write_g2o_is_the_arrays_writer_with_landmarks_and_fix(tmp_path):
    """Oracle: the expected text written out by hand from the records' definitions."""
    from probmap.datasets.g2o import write_pose_graph_g2o

    g = PoseGraph()
    g.poses[5] = np.array([0.1, -0.0, 3.0])
    g.poses[2] = np.array([1.0, 2.0, 0.5])
    g.landmarks[9] = np.array([4.0, 1e-300])
    g.fixed = [5, 9]
    g.pose_edges.append(PoseEdge(5, 2, np.array([1.0, 2.0, 0.25]), np.diag([1.0, 2.0, 3.0])))
    g.pose_edges.append(
        PoseEdge(2, 2, np.zeros(3), np.array([[1.0, 7.0, 0], [0, 1, 0], [0, 0, 1]]))
    )
    g.landmark_edges.append(
        LandmarkEdge(2, 9, np.array([0.5, 0.75]), np.array([[2.0, 0.5], [0.5, 4.0]]))
    )
    expected = (
        "VERTEX_SE2 5 0.1 -0.0 3.0\nVERTEX_SE2 2 1.0 2.0 0.5\nVERTEX_XY 9 4.0 1e-300\n"
        "FIX 5\nFIX 9\n"
        "EDGE_SE2 5 2 1.0 2.0 0.25 1.0 0.0 0.0 2.0 0.0 3.0\n"
        "EDGE_SE2 2 2 0.0 0.0 0.0 1.0 7.0 0.0 1.0 0.0 1.0\n"
        "EDGE_SE2_XY 2 9 0.5 0.75 2.0 0.5 4.0\n"
    )
    assert write_g2o(tmp_path / "a.g2o", g).read_text() == expected
    b = write_pose_graph_g2o(
        tmp_path / "b.g2o",
        [[0.1, -0.0, 3.0], [1.0, 2.0, 0.5]],
        [[0, 1], [1, 1]],
        [e.measurement for e in g.pose_edges],
        [e.information for e in g.pose_edges],
        ids=[5, 2],
        landmarks=[[4.0, 1e-300]],
        landmark_ids=[9],
        landmark_edges=[[1, 0]],
        landmark_measurements=[[0.5, 0.75]],
        landmark_information=[[[2.0, 0.5], [0.5, 4.0]]],
        fixed_ids=[5, 9],
    )
    assert b.read_text() == expected
    g.pose_edges.append(PoseEdge(2, 7, np.zeros(3), np.eye(3)))
    with pytest.raises(ValueError, match="missing vertex 7"):
        write_g2o(tmp_path / "c.g2o", g)
    with pytest.raises(ValueError, match="landmark_edge 0 .* index 1 outside"):
        write_pose_graph_g2o(
            tmp_path / "d.g2o",
            np.zeros((1, 3)),
            np.zeros((0, 2), int),
            np.zeros((0, 3)),
            np.zeros((0, 3, 3)),
            landmarks=np.zeros((1, 2)),
            landmark_edges=[[0, 1]],
            landmark_measurements=np.zeros((1, 2)),
            landmark_information=np.zeros((1, 2, 2)),
        )
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.g2o", "b.g2o"]
