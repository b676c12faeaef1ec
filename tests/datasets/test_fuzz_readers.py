"""Fuzzing the readers the first fuzz tests (test_input_policy.py) leave out: MRCLAM and
Victoria Park text files, map_server images and ROS bags. Whatever the bytes, a reader raises
DatasetError (or ValueError / FileNotFoundError for a missing file), never another exception."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from probmap.errors import DatasetError

FUZZ = settings(
    max_examples=50,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
NUMBER = st.sampled_from(
    ["0", "1", "-1", "2.5", "63", "5", "nan", "inf", "-inf", "1e308", "1e400", "x", "", "0.1"]
)
ROWS = st.lists(st.lists(NUMBER, max_size=6).map(" ".join), max_size=8).map(
    lambda rows: "\n".join(rows) + "\n"
)
JUNK = st.binary(max_size=40)
EXPECTED = (DatasetError, ValueError, FileNotFoundError)


def _mrclam(d: Path, files: dict[str, str]) -> None:
    base = {
        "Barcodes.dat": "1 5\n6 63\n",
        "Landmark_Groundtruth.dat": "6 1.0 2.0 0.0 0.0\n",
        "Robot1_Odometry.dat": "".join(f"{t:.1f} 0.1 0.0\n" for t in range(10)),
        "Robot1_Groundtruth.dat": "".join(f"{t:.1f} {0.1 * t:.2f} 0.0 0.0\n" for t in range(10)),
        "Robot1_Measurement.dat": "2.0 63 1.5 0.2\n",
    }
    base.update(files)
    for name, text in base.items():
        (d / name).write_text(text, encoding="latin-1", errors="replace")


@FUZZ
@given(
    st.sampled_from(
        ["Barcodes.dat", "Landmark_Groundtruth.dat", "Robot1_Odometry.dat",
         "Robot1_Groundtruth.dat", "Robot1_Measurement.dat"]
    ),
    ROWS,
    JUNK,
)  # fmt: skip
def test_fuzz_mrclam_reader(tmp_path_factory, name, rows, junk):
    from probmap.datasets.utias import MRCLAM

    d = tmp_path_factory.mktemp("mrclam")
    _mrclam(d, {name: rows + junk.decode("latin-1")})
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # skipped rows are reported as warnings: fine here
            ds = MRCLAM(d, 1)
            for _ in ds:
                pass
    except EXPECTED:
        pass


@FUZZ
@given(st.sampled_from(["inputs.dat", "measurements.dat", "gps.dat"]), ROWS, JUNK)
def test_fuzz_victoria_park_reader(tmp_path_factory, name, rows, junk):
    from probmap.datasets.victoria_park import VictoriaPark

    d = tmp_path_factory.mktemp("vp")
    (d / "inputs.dat").write_text("".join(f"{0.025 * k:.3f} 1.0 0.0\n" for k in range(40)))
    (d / "measurements.dat").write_text("0.5 10.0 1.0 0.3\n0.6 12.0 1.2 0.3\n")
    (d / "gps.dat").write_text("0.0 0.0 0.0\n0.5 0.5 0.0\n")
    (d / name).write_bytes(rows.encode() + junk)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ds = VictoriaPark(d)
            for _ in ds:
                pass
    except EXPECTED:
        pass


@FUZZ
@given(
    st.one_of(
        JUNK,
        st.tuples(
            st.sampled_from([b"P5", b"P2", b"P6", b"P5x"]),
            st.lists(
                st.sampled_from([b"2", b"0", b"-1", b"255", b"65536", b"#c", b"a"]), max_size=4
            ),  # fmt: skip
            JUNK,
        ).map(lambda t: t[0] + b"\n" + b" ".join(t[1]) + b"\n" + t[2]),
    )
)
def test_fuzz_map_image_reader(tmp_path_factory, image):
    from probmap.grid.io import read_map_server

    d = tmp_path_factory.mktemp("img")
    (d / "map.pgm").write_bytes(image)
    (d / "map.yaml").write_text(
        "image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    try:
        read_map_server(d / "map.yaml")
    except EXPECTED:
        pass


@FUZZ
@given(st.integers(min_value=0, max_value=4000), JUNK, st.sampled_from([".bag", ".db3"]))
def test_fuzz_bag_reader_on_cut_and_corrupted_bags(shared_data, tmp_path_factory, cut, junk, ext):
    """A real ROS 1 bag cut anywhere in its first 4 kB and followed by junk, or junk alone
    under a bag's name: a BagError/DatasetError naming the file."""
    pytest.importorskip("rosbags")
    from probmap.datasets.ros.scans import load_bag_scans

    src = shared_data("ros-bags/b0-2014-07-21-12-42-53-short.bag")
    d = tmp_path_factory.mktemp("bag")
    path = d / f"cut{ext}"
    if ext == ".bag":
        with open(src, "rb") as f:
            path.write_bytes(f.read(cut) + junk)
    else:
        path.write_bytes(junk)
    try:
        load_bag_scans(path)
    except EXPECTED as exc:
        assert str(path.name) in str(exc) or "bag" in str(exc).lower()


def test_the_fuzzed_readers_accept_their_valid_inputs(tmp_path):
    """The base files above are valid: the fuzz tests start from readable inputs."""
    from probmap.datasets.utias import MRCLAM
    from probmap.datasets.victoria_park import VictoriaPark
    from probmap.grid.io import read_map_server

    _mrclam(tmp_path, {})
    assert len(list(MRCLAM(tmp_path, 1))) > 0
    vp = tmp_path / "vp"
    vp.mkdir()
    (vp / "inputs.dat").write_text("".join(f"{0.025 * k:.3f} 1.0 0.0\n" for k in range(40)))
    (vp / "measurements.dat").write_text("0.5 10.0 1.0 0.3\n0.6 12.0 1.2 0.3\n")
    (vp / "gps.dat").write_text("0.0 0.0 0.0\n0.5 0.5 0.0\n")
    assert len(list(VictoriaPark(vp))) > 0
    (tmp_path / "map.pgm").write_bytes(b"P5\n2 2\n255\n\x00\xff\x80\xcd")
    (tmp_path / "map.yaml").write_text(
        "image: map.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    assert read_map_server(tmp_path / "map.yaml").classify().shape == (2, 2)
