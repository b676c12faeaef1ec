"""Hypothesis fuzzing of the readers issue 38 changed: a session file damaged anywhere (bytes
flipped, cut short, JSON values replaced) and g2o/TORO text made of the formats' own tags with
arbitrary fields. Each either reads or fails with the reader's one-line error naming the file;
nothing else escapes (no TypeError, IndexError, KeyError, AttributeError, RecursionError ...)."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from probmap.datasets.g2o import read_pose_graph
from probmap.errors import DatasetError
from probmap.pipelines.sessions import load_session, save_session
from probmap.slam.laser.submap_slam import SubmapSlam

FUZZ = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@pytest.fixture(scope="module")
def session_file(tmp_path_factory) -> Path:
    """A small real session: 40 scans of a floor plan, two submaps (a path, so that a failing
    example does not print megabytes)."""
    from probmap.sim.floorplan import simulate_laser_world

    w = simulate_laser_world(seed=2, size=(8.0, 6.0), step=0.2, range_noise=0.01)
    slam = SubmapSlam(max_range=float(w.max_range))
    for i in range(40):
        slam.add_scan(0.2 * i, w.ranges[i], w.angles, w.poses[i])
    path = tmp_path_factory.mktemp("fuzz") / "s.session"
    save_session(slam, path)
    return path


def _loads_or_one_line(path: Path) -> None:
    try:
        load_session(path)
    except ValueError as exc:  # NotASessionError is one
        msg = str(exc)
        assert "\n" not in msg and str(path) in msg, msg


@FUZZ
@given(data=st.data())
def test_a_damaged_session_reads_or_is_one_line(session_file, tmp_path, data):
    raw = bytearray(session_file.read_bytes())
    kind = data.draw(st.sampled_from(["flip", "cut", "splice"]))
    if kind == "flip":
        for _ in range(data.draw(st.integers(1, 8))):
            i = data.draw(st.integers(0, len(raw) - 1))
            raw[i] ^= data.draw(st.integers(1, 255))
    elif kind == "cut":
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    else:
        i = data.draw(st.integers(0, len(raw)))
        raw[i:i] = data.draw(st.binary(min_size=1, max_size=64))
    path = tmp_path / "damaged.session"
    path.write_bytes(bytes(raw))
    _loads_or_one_line(path)


_JSON = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats() | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4)
    ),
    max_leaves=12,
)


def _paths(node, prefix=()):
    """Every path into a JSON tree (keys and list indices)."""
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, (*prefix, i))


@FUZZ
@given(data=st.data())
def test_a_session_with_a_json_value_replaced_reads_or_is_one_line(session_file, tmp_path, data):
    member = data.draw(st.sampled_from(["header.json", "state.json"]))
    with zipfile.ZipFile(session_file) as z:
        members = {n: z.read(n) for n in z.namelist()}
    tree = json.loads(members[member])
    paths = [p for p in _paths(tree) if p]
    path_in = data.draw(st.sampled_from(paths))
    value = data.draw(_JSON)
    node = tree
    for key in path_in[:-1]:
        node = node[key]
    node[path_in[-1]] = value
    members[member] = json.dumps(tree, allow_nan=True).encode()
    path = tmp_path / "edited.session"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as out:
        for name, content in members.items():
            out.writestr(name, content)
    _loads_or_one_line(path)


_TAGS = ["VERTEX_SE2", "VERTEX2", "VERTEX_XY", "EDGE_SE2", "EDGE2", "EDGE_SE2_XY", "FIX", "EQUIV"]
_FIELD = st.one_of(
    st.integers(-3, 6).map(str),
    st.integers(-(2**70), 2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["1e400", "nan", "-0", "x", "", "0x10", "1_0"]),
)


@FUZZ
@given(
    lines=st.lists(
        st.tuples(st.sampled_from(_TAGS), st.lists(_FIELD, min_size=0, max_size=13)),
        min_size=1,
        max_size=12,
    ),
    order=st.sampled_from(["auto", "toro", "g2o"]),
)
def test_g2o_and_toro_text_reads_or_is_one_line(tmp_path, lines, order):
    path = tmp_path / "fuzz.g2o"
    path.write_text("\n".join(" ".join([tag, *fields]) for tag, fields in lines) + "\n")
    try:
        g = read_pose_graph(path, edge2_order=order)
    except DatasetError as exc:
        msg = str(exc)
        assert "\n" not in msg and str(path) in msg, msg
        return
    if g.landmark_edges or not g.poses:
        return
    from probmap.pipelines.optimize import PoseGraphConfig, optimize_graph

    try:
        r = optimize_graph(g, PoseGraphConfig(max_iterations=5)).result
    except ValueError as exc:
        assert "\n" not in str(exc)
        return
    assert np.isfinite(r.poses).all() or not r.converged
