"""Hypothesis fuzzing of the readers test_fuzz_text_readers.py leaves out (issue 38): ROS 1 bags,
ROS 2 bags (.db3 and .mcap storage), MRCLAM and Victoria Park folders. Each input starts from a
small valid one made here (so the tests run without the shared data) and is broken two ways:
its bytes (flips, truncations, insertions, 32-bit fields overwritten) and its field values (a
bag written with NaN, infinite, empty or huge values; a text table with arbitrary numbers).
Each either reads or raises a ValueError (DatasetError, BagError) whose message is one line
naming the file; nothing else escapes."""

from __future__ import annotations

import os
import shutil
import signal
import struct
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, reject, settings
from hypothesis import strategies as st

FUZZ = settings(  # PROBMAP_FUZZ_EXAMPLES=2000 for a longer search
    max_examples=int(os.environ.get("PROBMAP_FUZZ_EXAMPLES", "40")),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

_NUMBER = st.one_of(
    st.integers(-5, 400).map(str),
    st.integers(-(2**70), 2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["1e400", "nan", "inf", "-0", "x", "0x10", "1_0", "", "3.", ".5"]),
)
_FLOAT = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.sampled_from([0.0, -0.0, 1e-30, 0.01, 1.0, 30.0, 3.4e38]),
)
_U32 = st.sampled_from([0, 1, 4, 8, 255, 4096, 2**31 - 1, 2**31, 2**32 - 1])


def _check(path: Path, read: Callable[[Path], object], *names: str) -> None:
    """``read(path)`` succeeds or raises a ValueError whose message is one line naming the file
    (or one of ``names``: the folder of a multi-file dataset, say), within ``_LIMIT_S``
    seconds (a tf cycle once made a bag read loop for ever)."""
    with _time_limit(_LIMIT_S):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # skipped rows and scans are warned about
                read(path)
        except ValueError as exc:
            _one_line_naming(exc, path, *names)


_LIMIT_S = 10


@contextmanager
def _time_limit(seconds: int) -> Iterator[None]:
    """A TimeoutError after ``seconds`` (where the platform has SIGALRM)."""
    if not hasattr(signal, "SIGALRM"):
        yield
        return

    def stop(signum: int, frame: object) -> None:
        raise TimeoutError(f"the read took more than {seconds} s")

    old = signal.signal(signal.SIGALRM, stop)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def _one_line_naming(exc: BaseException, path: Path, *names: str) -> None:
    msg = str(exc)
    assert len(msg.strip().splitlines()) == 1, msg
    assert any(n in msg for n in (path.name, *names)), msg


class _Valid(dict):
    """The valid inputs of a fixture, shown short in hypothesis' reports."""

    def __repr__(self) -> str:
        return f"<valid {', '.join(self)}>"


def _read_scans(path: Path) -> object:
    from probmap.datasets import open_scans

    return open_scans(path)


# ------------------------------------------------------------------ byte mutations


@st.composite
def _mutations(draw: st.DrawFn, size: int) -> list[tuple[str, int, bytes]]:
    """A few edits of a ``size``-byte file: ``(kind, position, bytes)``."""
    ops = []
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "cut", "insert", "u32"]))
        pos = draw(st.integers(0, max(size - 1, 0)))
        if kind == "flip":
            val = bytes([draw(st.integers(0, 255))])
        elif kind == "insert":
            val = draw(st.binary(min_size=1, max_size=16))
        elif kind == "u32":
            val = struct.pack("<I", draw(_U32))
        else:
            val = b""
        ops.append((kind, pos, val))
    return ops


def _mutate(data: bytes, ops: list[tuple[str, int, bytes]]) -> bytes:
    b = bytearray(data)
    for kind, pos, val in ops:
        pos = min(pos, len(b))
        if kind == "flip" and pos < len(b):
            b[pos] ^= val[0] or 0xFF
        elif kind == "cut":
            del b[pos:]
        elif kind == "insert":
            b[pos:pos] = val
        elif kind == "u32":
            b[pos : pos + 4] = val
    return bytes(b)


# ------------------------------------------------------------------ small valid bags


def _write_bag(path: Path, ros: int, storage: str = "sqlite3", **v: object) -> Path:
    """A small bag: a static ``base_link -> laser``, odometry ``odom -> base_link`` and a few
    scans (``multiecho``: MultiEchoLaserScan), every value overridable through ``v``."""
    from bagwriter import BagBuilder

    quat = v.get("quat")

    class Builder(BagBuilder):
        def pose_msg(self, p: np.ndarray) -> tuple[object, object]:
            pos, q = super().pose_msg(p)
            if quat is None:
                return pos, q
            x, y, z, w = quat  # type: ignore[misc]
            return pos, self.t["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)

    b = Builder(path, ros, storage)
    n = int(v.get("scans", 4))  # type: ignore[call-overload]
    t0 = float(v.get("t0", 10.0))  # type: ignore[arg-type]
    odom, base = str(v.get("odom_frame", "odom")), str(v.get("base_frame", "base_link"))
    b.tf("/tf_static", t0, [(v.get("parent", base), "laser", np.array([0.1, 0.0, 0.0]))])
    pose = np.array(v.get("pose", (0.0, 0.0, 0.0)), dtype=np.float64)
    for k in range(n + 1):
        b.odom("/odom", t0 + 0.1 * k, odom, base, pose + [0.05 * k, 0.0, 0.01 * k])
    beams = int(v.get("beams", 8))  # type: ignore[call-overload]
    ranges = np.asarray(v.get("ranges", np.linspace(1.0, 5.0, beams)), dtype=np.float32)
    topics = [str(v.get("topic", "/scan"))] + (["/scan2"] if v.get("second_topic") else [])
    for k, topic in ((k, t) for k in range(n) for t in topics):
        stamp = float(v.get("stamp", t0 + 0.1 * k + 0.05))  # type: ignore[arg-type]
        frame = str(v.get("frame", "laser"))
        if v.get("multiecho"):
            echoes = [[float(r)] * int(v.get("echoes", 1)) for r in ranges]  # type: ignore[call-overload]
            b.multiecho(topic, stamp, frame, echoes, float(v.get("amin", -1.0)))  # type: ignore[arg-type]
        else:
            amin, ainc = float(v.get("amin", -1.0)), float(v.get("ainc", 0.25))  # type: ignore[arg-type]
            if abs(amin + ainc * (len(ranges) - 1)) > 3.4e38:
                b.close()  # angle_max beyond float32: no bag can hold it
                reject()
            b.scan(
                topic, stamp, frame, ranges, amin, ainc,
                float(v.get("rmin", 0.1)), float(v.get("rmax", 30.0)),  # type: ignore[arg-type]
            )  # fmt: skip
    b.close()
    return path


@pytest.fixture(scope="module")
def ros1_bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    pytest.importorskip("rosbags")
    d = tmp_path_factory.mktemp("valid1")
    out = _Valid()
    for name, multi in (("scan", False), ("multiecho", True)):
        p = _write_bag(d / f"{name}.bag", 1, multiecho=multi)
        _read_scans(p)  # the fuzzing starts from a readable bag
        out[name] = p.read_bytes()
    return out


@pytest.fixture(scope="module")
def ros2_bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[bytes, str, str]]:
    """``storage -> (storage file bytes, its name, metadata.yaml text)``."""
    pytest.importorskip("rosbags")
    d = tmp_path_factory.mktemp("valid2")
    out = _Valid()
    for storage in ("sqlite3", "mcap"):
        p = _write_bag(d / storage, 2, storage)
        _read_scans(p)
        (f,) = [q for q in p.iterdir() if q.suffix in (".db3", ".mcap")]
        out[storage] = (f.read_bytes(), f.name, (p / "metadata.yaml").read_text())
    return out


# ------------------------------------------------------------------ ROS 1


@FUZZ
@given(kind=st.sampled_from(["scan", "multiecho"]), data=st.data())
def test_ros1_bags_with_broken_bytes(tmp_path, ros1_bags, kind, data):
    valid = ros1_bags[kind]
    path = tmp_path / "fuzz.bag"
    path.write_bytes(_mutate(valid, data.draw(_mutations(len(valid)))))
    _check(path, _read_scans)


_BAG_FIELDS = st.fixed_dictionaries(
    {},
    optional={
        "scans": st.integers(0, 3),
        "t0": st.sampled_from([0.0, 1e-9, 1.0, 2.1e9]),
        "stamp": st.sampled_from([0.0, 5.0, 10.15, 2.1e9]),
        "parent": st.sampled_from(["base_link", "laser", "", "/", "odom", "map", "p\nq"]),
        "frame": st.sampled_from(["laser", "", "/", "/laser", "odom", "base_link", "x y", "a\nb"]),
        "odom_frame": st.sampled_from(["odom", "", "/", "map", "laser", "o\nm"]),
        "base_frame": st.sampled_from(["base_link", "", "odom", "laser", "b\nl"]),
        "topic": st.sampled_from(["/scan", "scan", "/odom", "/tf", "/s\nt", "/s can"]),
        "second_topic": st.booleans(),
        "pose": st.tuples(_FLOAT, _FLOAT, st.floats(-1e6, 1e6)),
        "quat": st.tuples(_FLOAT, _FLOAT, _FLOAT, _FLOAT),
        "beams": st.integers(0, 3),
        "ranges": st.lists(_FLOAT, max_size=6),
        "amin": _FLOAT,
        "ainc": _FLOAT,
        "rmin": _FLOAT,
        "rmax": _FLOAT,
        "multiecho": st.booleans(),
        "echoes": st.integers(0, 2),
    },
)


_FOUND = [  # what the fuzzing found: a tf cycle (a read looped for ever), a line break in a name
    {"odom_frame": "laser"},
    {"base_frame": "b\nl"},
    {"topic": "/s\nt", "second_topic": True},
]


@FUZZ
@given(fields=_BAG_FIELDS)
@example(fields=_FOUND[0])
@example(fields=_FOUND[1])
@example(fields=_FOUND[2])
def test_ros1_bags_with_arbitrary_field_values(tmp_path, ros1_bags, fields):
    path = tmp_path / "fuzz.bag"
    path.unlink(missing_ok=True)
    _check(_write_bag(path, 1, **fields), _read_scans)


# ------------------------------------------------------------------ ROS 2


def _ros2_folder(tmp_path: Path, storage_file: str, data: bytes, metadata: str) -> Path:
    d = tmp_path / "bag"
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir()
    (d / storage_file).write_bytes(data)
    (d / "metadata.yaml").write_text(metadata)
    return d


@FUZZ
@given(storage=st.sampled_from(["sqlite3", "mcap"]), by_file=st.booleans(), data=st.data())
def test_ros2_bags_with_broken_bytes(tmp_path, ros2_bags, storage, by_file, data):
    valid, name, metadata = ros2_bags[storage]
    d = _ros2_folder(tmp_path, name, _mutate(valid, data.draw(_mutations(len(valid)))), metadata)
    _check(d / name if by_file else d, _read_scans, d.name, name)


@FUZZ
@given(storage=st.sampled_from(["sqlite3", "mcap"]), data=st.data())
def test_ros2_bags_with_a_broken_metadata_yaml(tmp_path, ros2_bags, storage, data):
    valid, name, metadata = ros2_bags[storage]
    lines = metadata.splitlines()
    k = data.draw(st.integers(0, len(lines) - 1))
    key, sep, _ = lines[k].partition(":")
    new = data.draw(st.one_of(_NUMBER, st.sampled_from(["[]", "{}", "~", "'x'", "- 1", "!!x"])))
    lines[k] = f"{key}{sep} {new}" if sep else new
    if data.draw(st.booleans()):
        lines = lines[: data.draw(st.integers(0, len(lines)))]
    d = _ros2_folder(tmp_path, name, valid, "\n".join(lines) + "\n")
    _check(d, _read_scans, d.name, "metadata.yaml")


@pytest.mark.parametrize(
    ("old", "new"),
    [("name: /tf_static", "name: []"), ("message_count: 1\n", "message_count: x\n")],
)
def test_ros2_metadata_the_fuzzing_found(tmp_path, ros2_bags, old, new):
    """A topic named by a list once escaped as a TypeError from deep in the reader."""
    from probmap.errors import BagError

    valid, name, metadata = ros2_bags["sqlite3"]
    assert old in metadata
    d = _ros2_folder(tmp_path, name, valid, metadata.replace(old, new, 1))
    with pytest.raises(BagError) as err:
        _read_scans(d)
    _one_line_naming(err.value, d)


@FUZZ
@given(storage=st.sampled_from(["sqlite3", "mcap"]), fields=_BAG_FIELDS)
@example(storage="sqlite3", fields=_FOUND[0])
@example(storage="mcap", fields=_FOUND[1])
def test_ros2_bags_with_arbitrary_field_values(tmp_path, ros2_bags, storage, fields):
    d = tmp_path / "bag"
    shutil.rmtree(d, ignore_errors=True)
    _check(_write_bag(d, 2, storage, **fields), _read_scans, d.name)


# ------------------------------------------------------------------ MRCLAM and Victoria Park

_MRCLAM = {
    "Barcodes.dat": [["1", "5"], ["6", "63"]],
    "Landmark_Groundtruth.dat": [["6", "1.0", "2.0", "0.0", "0.0"]],
    "Robot1_Odometry.dat": [[f"{t:.1f}", "0.1", "0.0"] for t in range(10)],
    "Robot1_Groundtruth.dat": [[f"{t:.1f}", f"{0.1 * t:.2f}", "0.0", "0.0"] for t in range(10)],
    "Robot1_Measurement.dat": [["2.0", "63", "1.5", "0.2"], ["3.0", "5", "1.0", "0.1"]],
}
_VICTORIA = {
    "inputs.dat": [[f"{0.025 * k:.3f}", "1.0", "0.0"] for k in range(40)],
    "measurements.dat": [["0.5", "10.0", "1.0", "0.3"], ["0.6", "12.0", "1.2", "0.3"]],
    "gps.dat": [["0.0", "0.0", "0.0"], ["0.5", "0.5", "0.0"]],
}


@st.composite
def _tables(draw: st.DrawFn, base: dict[str, list[list[str]]]) -> dict[str, list[list[str]]]:
    """``base`` with one file's fields replaced, rows dropped or added, in its own format."""
    name = draw(st.sampled_from(sorted(base)))
    rows = [list(r) for r in base[name]]
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["field", "field", "drop", "add", "cut"]))
        if op == "field" and rows:
            r = rows[draw(st.integers(0, len(rows) - 1))]
            r[draw(st.integers(0, max(len(r) - 1, 0))) :][:1] = [draw(_NUMBER)]
        elif op == "drop" and rows:
            del rows[draw(st.integers(0, len(rows) - 1))]
        elif op == "add":
            rows.insert(draw(st.integers(0, len(rows))), draw(st.lists(_NUMBER, max_size=6)))
        elif op == "cut" and rows:
            r = rows[draw(st.integers(0, len(rows) - 1))]
            del r[draw(st.integers(0, len(r))) :]
    return {**base, name: rows}


def _write_tables(
    d: Path, tables: dict[str, list[list[str]]], damage: tuple[str, str, bytes] | None = None
) -> None:
    """The tables as text files; ``damage`` = ``("junk", name, bytes)`` appends bytes (not
    UTF-8, say) to a file, ``("missing", name, b"")`` leaves it out."""
    d.mkdir(exist_ok=True)
    for name, rows in tables.items():
        (d / name).write_text("\n".join(" ".join(r) for r in rows) + "\n")
    if damage is not None:
        kind, name, junk = damage
        if kind == "missing":
            (d / name).unlink()
        else:
            with open(d / name, "ab") as f:
                f.write(junk)


def _damage(names: dict[str, list[list[str]]]) -> st.SearchStrategy[tuple[str, str, bytes] | None]:
    return st.one_of(
        st.none(),
        st.tuples(
            st.sampled_from(["junk", "missing"]), st.sampled_from(sorted(names)), st.binary()
        ),
    )


def _check_folder(d: Path, read: Callable[[Path], object], names: list[str]) -> None:
    """:func:`_check`, and a missing file is a FileNotFoundError naming it (as every reader's)."""
    try:
        _check(d, read, *names)
    except FileNotFoundError as exc:
        _one_line_naming(exc, d, *names)


def _read_landmarks(ds: object) -> None:
    for _ in ds:  # type: ignore[attr-defined]
        pass


@FUZZ
@given(tables=_tables(_MRCLAM), damage=_damage(_MRCLAM))
def test_mrclam_folders(tmp_path, tables, damage):
    from probmap.datasets.utias import MRCLAM

    d = tmp_path / "mrclam"
    shutil.rmtree(d, ignore_errors=True)
    _write_tables(d, tables, damage)
    _check_folder(d, lambda p: _read_landmarks(MRCLAM(p, 1)), list(tables))


@FUZZ
@given(tables=_tables(_VICTORIA), damage=_damage(_VICTORIA))
def test_victoria_park_folders(tmp_path, tables, damage):
    from probmap.datasets.victoria_park import VictoriaPark

    d = tmp_path / "vp"
    shutil.rmtree(d, ignore_errors=True)
    _write_tables(d, tables, damage)
    _check_folder(d, lambda p: _read_landmarks(VictoriaPark(p)), list(tables))


def test_the_unfuzzed_inputs_read(tmp_path, ros1_bags, ros2_bags):
    """The fuzzing starts from readable inputs, and the checks can fail."""
    from probmap.datasets.utias import MRCLAM
    from probmap.datasets.victoria_park import VictoriaPark

    _write_tables(tmp_path / "m", _MRCLAM)
    assert len(list(MRCLAM(tmp_path / "m", 1))) > 0
    _write_tables(tmp_path / "v", _VICTORIA)
    assert len(list(VictoriaPark(tmp_path / "v"))) > 0
    assert ros1_bags and ros2_bags  # their fixtures read each bag
    with pytest.raises(AssertionError):
        _check(tmp_path / "x.bag", lambda p: (_ for _ in ()).throw(ValueError("a\nb x.bag")))
    with pytest.raises(AssertionError):
        _check(tmp_path / "x.bag", lambda p: (_ for _ in ()).throw(ValueError("no name")))
    with pytest.raises(KeyError):
        _check(tmp_path / "x.bag", lambda p: {}["k"])
    if hasattr(signal, "SIGALRM"):
        with pytest.raises(TimeoutError), _time_limit(1):
            while True:
                pass
