"""CARMEN log reader: every message type, compressions, beam conventions, errors, real logs."""

from __future__ import annotations

import bz2
import gzip
import math
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest

from probmap.datasets.carmen import (
    DEFAULT_MAX_RANGE,
    BadLinesWarning,
    CarmenLog,
    default_angle_step,
    detect_compression,
    load_scans,
    load_share,
    split_log,
)
from probmap.datasets.protocol import Dataset, DatasetError
from probmap.datasets.records import LaserScan, Odometry

# --------------------------------------------------------------------------- log writers


def flaser(ranges, laser=(0.0, 0.0, 0.0), robot=None, t=100.0, kind="FLASER", logger=None):
    robot = laser if robot is None else robot
    r = " ".join(repr(float(v)) for v in ranges)
    p = " ".join(repr(float(v)) for v in (*laser, *robot))
    lt = t - 50.0 if logger is None else logger
    return f"{kind} {len(ranges)} {r} {p} {t!r} host {lt!r}\n"


def odom(pose, tv=0.5, rv=0.1, t=100.0):
    x, y, th = pose
    return f"ODOM {x!r} {y!r} {th!r} {tv!r} {rv!r} 0.0 {t!r} host {t - 50.0!r}\n"


def robotlaser(ranges, *, start=-1.5664, res=0.0174533, max_range=81.9, rem=(), laser, robot, t):
    r = " ".join(repr(float(v)) for v in ranges)
    e = " ".join(repr(float(v)) for v in rem)
    p = " ".join(repr(float(v)) for v in (*laser, *robot))
    return (
        f"ROBOTLASER1 0 {start!r} 3.141593 {res!r} {max_range!r} 0.01 0 {len(ranges)} {r} "
        f"{len(rem)} {e} {p} 0.3 0.05 0.6 0.3 0.25 {t!r} zoidberg {t - 7.0!r}\n".replace("  ", " ")
    )


OPENERS = {"": open, ".gz": gzip.open, ".bz2": bz2.open}


def write(path: Path, lines, opener=None) -> Path:
    opener = opener or OPENERS[path.suffix if path.suffix in OPENERS else ""]
    with opener(path, "wt") as f:
        f.writelines(lines)
    return path


def basic_lines():
    """A small log with every message type; returns (lines, expected scans, expected odometry)."""
    rng = np.random.default_rng(3)
    lines = [
        "# message_name [message contents] ipc_timestamp ipc_hostname logger_timestamp\n",
        "PARAM robot_frontlaser_offset 0.25 nohost 0\n",
        "PARAM robot_front_laser_max 50.0 1.0 host 1.0\n",
        "PARAM laser_front_laser_resolution 1.0 nohost 0\n",
        "\n",
    ]
    scans, odos = [], []
    for k in range(6):
        pose = (0.5 * k, -0.2 * k, 0.1 * k - 0.3)
        odos.append((len(lines) + 1, pose, 100.0 + k))
        lines.append(odom(pose, t=100.0 + k))
        ranges = rng.uniform(0.5, 30.0, 180)
        laser = (pose[0] + 0.25 * math.cos(pose[2]), pose[1] + 0.25 * math.sin(pose[2]), pose[2])
        scans.append((len(lines) + 1, ranges, laser, pose, 100.5 + k))
        lines.append(flaser(ranges, laser, pose, t=100.5 + k))
        lines.append("NEFF 42\n")
        lines.append("SYNC tag\n")
        lines.append("TRUEPOS 1 2 3 4 5 6 100.0 host 50.0\n")
        lines.append("NMEA-GGA whatever 1 2 3\n")
        lines.append("  # an indented comment\n")
    return lines, scans, odos


# --------------------------------------------------------------------------- parsing


@pytest.mark.parametrize("suffix", ["", ".gz", ".bz2"])
def test_all_message_types_in_every_compression(tmp_path, suffix):
    lines, scans, odos = basic_lines()
    path = write(tmp_path / f"basic.clf{suffix}", lines)
    log = CarmenLog(path)
    assert isinstance(log, Dataset)
    assert log.name == "basic"
    got = list(log)
    assert len(log) == len(got) == len(scans)
    angles = -np.pi / 2 + np.arange(180) * np.pi / 180
    for scan, (line, ranges, laser, robot, t) in zip(got, scans, strict=True):
        assert isinstance(scan, LaserScan)
        assert scan.line == line and scan.source == "FLASER"
        assert scan.time == t and scan.logger_time == t - 50.0
        np.testing.assert_array_equal(scan.ranges, ranges)  # repr() round-trips exactly
        np.testing.assert_allclose(scan.angles, angles, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(scan.laser_pose, laser)
        np.testing.assert_array_equal(scan.robot_pose, robot)
        assert scan.max_range == 50.0  # from PARAM robot_front_laser_max
    odo = list(log.odometry())
    assert [(o.line, tuple(o.pose), o.time) for o in odo] == [
        (line, pose, t) for line, pose, t in odos
    ]
    assert all(isinstance(o, Odometry) and o.tv == 0.5 and o.rv == 0.1 for o in odo)
    both = list(log.records())
    assert [r.line for r in both] == sorted(r.line for r in both)
    assert len(both) == len(scans) + len(odos)
    assert log.params == {
        "robot_frontlaser_offset": "0.25",
        "robot_front_laser_max": "50.0",
        "laser_front_laser_resolution": "1.0",
    }
    assert log.skipped_lines == 0


def test_compression_is_detected_from_magic_bytes(tmp_path):
    lines, scans, _ = basic_lines()
    gz_named_plain = write(tmp_path / "a.clf", lines, opener=gzip.open)
    bz_named_gz = write(tmp_path / "b.log.gz", lines, opener=bz2.open)
    plain_named_bz2 = write(tmp_path / "c.bz2", lines, opener=open)
    assert detect_compression(gz_named_plain) == "gzip"
    assert detect_compression(bz_named_gz) == "bz2"
    assert detect_compression(plain_named_bz2) == "plain"
    for p in (gz_named_plain, bz_named_gz, plain_named_bz2):
        assert len(CarmenLog(p)) == len(scans)


def test_crlf_line_endings(tmp_path):
    lines, scans, _ = basic_lines()
    path = tmp_path / "crlf.clf"
    path.write_bytes("".join(lines).replace("\n", "\r\n").encode())
    got = list(CarmenLog(path))
    assert [s.line for s in got] == [s[0] for s in scans]
    np.testing.assert_array_equal(got[0].ranges, scans[0][1])


@pytest.mark.parametrize(
    "n,first_deg,last_deg", [(180, -90.0, 89.0), (360, -90.0, 89.5), (361, -90.0, 90.0)]
)
def test_default_beam_angles(tmp_path, n, first_deg, last_deg):
    path = write(tmp_path / "a.clf", [flaser(np.full(n, 2.0))])
    scan = next(iter(CarmenLog(path)))
    assert scan.angles.shape == (n,)
    assert math.degrees(scan.angles[0]) == pytest.approx(first_deg, abs=1e-9)
    assert math.degrees(scan.angles[-1]) == pytest.approx(last_deg, abs=1e-9)
    np.testing.assert_allclose(np.diff(scan.angles), default_angle_step(n), rtol=1e-12)
    assert not scan.angles.flags.writeable  # shared between scans


def test_default_angle_step_rules():
    assert default_angle_step(180) == pytest.approx(math.radians(1.0))
    assert default_angle_step(360) == pytest.approx(math.radians(0.5))
    assert default_angle_step(181) == pytest.approx(math.radians(1.0))
    assert default_angle_step(361) == pytest.approx(math.radians(0.5))
    assert default_angle_step(1) == math.pi


def test_explicit_start_angle_and_step(tmp_path):
    path = write(tmp_path / "a.clf", [flaser(np.full(180, 2.0))])
    step = math.pi / 179  # the linspace(-pi/2, pi/2, 180) convention some tools use
    scan = next(iter(CarmenLog(path, start_angle=-math.pi / 2, angle_step=step)))
    np.testing.assert_allclose(scan.angles, np.linspace(-np.pi / 2, np.pi / 2, 180), atol=1e-14)
    scan = next(iter(CarmenLog(path, start_angle=0.0, angle_step=-0.01)))
    np.testing.assert_allclose(scan.angles, -0.01 * np.arange(180), atol=1e-15)


def test_robotlaser1_explicit_geometry_and_poses(tmp_path):
    ranges = np.linspace(1.0, 5.0, 181)
    ranges[7] = 81.9
    line = robotlaser(
        ranges,
        rem=(0.5, 0.6, 0.7),
        laser=(1.0, 2.0, 0.3),
        robot=(0.9, 1.95, 0.3),
        t=1232658478.161285,
    )
    path = write(tmp_path / "clinic.clf.bz2", ["# x\n", line, line.replace("81.9 0.01", "0 0.01")])
    a, b = list(CarmenLog(path))
    assert a.source == "ROBOTLASER1" and a.line == 2
    np.testing.assert_array_equal(a.ranges, ranges)
    np.testing.assert_allclose(a.angles, -1.5664 + 0.0174533 * np.arange(181), atol=1e-12)
    np.testing.assert_array_equal(a.laser_pose, [1.0, 2.0, 0.3])
    np.testing.assert_array_equal(a.robot_pose, [0.9, 1.95, 0.3])
    assert a.time == 1232658478.161285 and a.logger_time == pytest.approx(1232658471.161285)
    assert a.max_range == 81.9  # the message's own value
    assert b.max_range == DEFAULT_MAX_RANGE  # a zero max range in the message: fall back
    assert next(iter(CarmenLog(path, max_range=30.0))).max_range == 30.0
    batch = load_scans(path)
    assert batch.ranges.shape == (2, 181) and batch.angles.shape == (181,)


def test_rear_laser_uses_rear_parameters(tmp_path):
    lines = [
        "PARAM robot_rear_laser_max 40.0 host 0\n",
        flaser(np.full(180, 1.0), t=1.0),
        flaser(np.full(180, 1.0), t=2.0, kind="RLASER"),
    ]
    path = write(tmp_path / "a.clf", lines)
    front, rear = list(CarmenLog(path))
    assert (front.source, front.max_range) == ("FLASER", DEFAULT_MAX_RANGE)
    assert (rear.source, rear.max_range) == ("RLASER", 40.0)
    assert len(load_scans(path)) == 1  # the mapper takes the front laser only by default
    assert len(load_scans(path, sources=("FLASER", "RLASER"))) == 2


def test_max_range_and_endpoints(tmp_path):
    ranges = np.array([1.0, 79.99, 80.0, 81.9, np.nan, 0.0, -1.0, 2.0])
    path = write(tmp_path / "a.clf", [flaser(ranges, laser=(1.0, -2.0, math.pi / 2))])
    scan = next(iter(CarmenLog(path, start_angle=0.0, angle_step=0.0 + math.pi / 2)))
    assert scan.max_range == DEFAULT_MAX_RANGE
    pts = scan.endpoints()
    # beams 0, 1 and 7 return; beam k points at theta + k * pi/2 = (k + 1) * pi/2
    expected = np.array(
        [
            [1.0 + 1.0 * math.cos(math.pi / 2), -2.0 + 1.0],
            [1.0 + 79.99 * math.cos(math.pi), -2.0 + 79.99 * math.sin(math.pi)],
            [1.0 + 2.0 * math.cos(4 * math.pi), -2.0 + 2.0 * math.sin(4 * math.pi)],
        ]
    )
    np.testing.assert_allclose(pts, expected, atol=1e-9)
    assert len(next(iter(CarmenLog(path, max_range=2.0))).endpoints()) == 1


def test_streaming_memory_stays_small(tmp_path):
    rng = np.random.default_rng(0)
    lines = [flaser(np.round(rng.uniform(0, 20, 180), 2), t=float(k)) for k in range(2500)]
    path = write(tmp_path / "big.clf.gz", lines)
    text_size = sum(len(s) for s in lines)
    log = CarmenLog(path)
    tracemalloc.start()
    try:
        n = sum(1 for _ in log)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert n == 2500
    assert text_size > 2_000_000
    assert peak < 1_000_000, f"peak {peak} bytes while streaming a {text_size} byte log"


# --------------------------------------------------------------------------- bad input

BAD_LINES = [
    ("FLASER 180 1.0 2.0 oops\n", "expected 191 fields, found 5", None),
    ("FLASER many 1.0\n", "expected an integer", "num_readings"),
    ("FLASER -3 1.0\n", "must not be negative", "num_readings"),
    (flaser([1.0, 2.0, 3.0]).replace(" 2.0 ", " two ", 1), "'two'", "range[1]"),
    (flaser([1.0, 2.0], laser=(0.0, 0.0, float("nan"))), "must be finite", "theta"),
    (flaser([1.0, 2.0]).replace("host", "host x"), "expected 13 fields", None),
    ("ODOM 1 2 3 4 5 6 7 host\n", "expected 10 fields", None),
    ("ODOM 1 y 3 4 5 6 7 host 8\n", "'y'", "y"),
    ("ODOM 1 2 3 4 5 6 seven host 8\n", "'seven'", "ipc_timestamp"),
    ("ROBOTLASER1 0 -1.57 3.14 0.0174 81.9 0.01 0 3 1 2\n", "line ends", "num_remissions"),
    ("PARAM robot_front_laser_max lots host 0\n", "'lots'", "robot_front_laser_max"),
    ("PARAM robot_front_laser_max -1 host 0\n", "positive", "robot_front_laser_max"),
    ("PARAM lonely\n", "expected PARAM name value", "value"),
]


@pytest.mark.parametrize("bad,needle,field", BAD_LINES)
def test_malformed_line_names_file_line_and_field(tmp_path, bad, needle, field):
    lines, scans, _ = basic_lines()
    lines.insert(6, bad)
    path = write(tmp_path / "bad.clf", lines)
    with pytest.raises(DatasetError) as info:
        list(CarmenLog(path))
    msg = str(info.value)
    assert str(path) in msg and "line 7" in msg and needle in msg, msg
    assert info.value.line == 7 and info.value.path == path
    if field is not None:
        assert info.value.field == field and repr(field) in msg


def test_skip_bad_lines_counts_and_warns(tmp_path):
    lines, scans, odos = basic_lines()
    for k, (bad, _, _) in enumerate(BAD_LINES):
        lines.insert(6 + 2 * k, bad)
    path = write(tmp_path / "bad.clf.bz2", lines)
    log = CarmenLog(path, skip_bad_lines=True)
    with pytest.warns(
        BadLinesWarning, match=rf"skipped {len(BAD_LINES)} bad \(malformed or implausible\) line"
    ):
        got = list(log)
    assert len(got) == len(scans)
    assert log.skipped_lines == len(BAD_LINES)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BadLinesWarning)
        batch = load_scans(path, skip_bad_lines=True)
        assert len(list(log.odometry())) == len(odos)
    assert batch.skipped_lines == len(BAD_LINES) and len(batch) == len(scans)


def _gz(data: bytes) -> bytes:
    return gzip.compress(data)


@pytest.mark.parametrize(
    "name,content",
    [
        ("empty.clf", b""),
        ("blank.clf", b"\n  \n\t\n"),
        ("empty.clf.gz", b""),
        ("empty-content.clf.gz", gzip.compress(b"", mtime=0)),
        ("empty-content.clf.bz2", bz2.compress(b"")),
    ],
)
def test_empty_logs(tmp_path, name, content):
    path = tmp_path / name
    path.write_bytes(content)
    log = CarmenLog(path)
    with pytest.raises(DatasetError, match="empty log") as info:
        len(log)
    assert str(path) in str(info.value)
    with pytest.raises(DatasetError, match="empty log"):
        list(log.odometry())


@pytest.mark.parametrize("compress,kind", [(gzip.compress, "gzip"), (bz2.compress, "bz2")])
def test_truncated_compressed_logs(tmp_path, compress, kind):
    lines, _, _ = basic_lines()
    data = compress("".join(lines * 20).encode())
    path = tmp_path / f"trunc.{kind}"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError) as info:
        load_scans(path)
    msg = str(info.value)
    assert str(path) in msg and "truncated or corrupt" in msg and kind in msg, msg


def test_corrupt_gzip_body(tmp_path):
    lines, _, _ = basic_lines()
    data = bytearray(gzip.compress("".join(lines * 20).encode()))
    data[40:60] = b"\x00" * 20
    path = tmp_path / "corrupt.clf.gz"
    path.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match="corrupt"):
        list(CarmenLog(path))


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere.clf"):
        CarmenLog(tmp_path / "nothere.clf")
    with pytest.raises(FileNotFoundError, match="nothere.clf"):
        load_scans(tmp_path / "nothere.clf")
    with pytest.raises(IsADirectoryError, match=str(tmp_path)):
        CarmenLog(tmp_path)


def test_log_without_scans(tmp_path):
    path = write(tmp_path / "odo.clf", [odom((0.0, 0.0, 0.0)), odom((1.0, 0.0, 0.0), t=101.0)])
    log = CarmenLog(path)
    assert len(list(log.odometry())) == 2
    with pytest.raises(DatasetError, match="no laser scans"):
        len(log)
    with pytest.raises(DatasetError, match="no laser scans"):
        list(log)
    with pytest.raises(DatasetError, match=r"odo\.clf.*no laser scans"):
        load_scans(path)
    rear_only = write(tmp_path / "rear.clf", [flaser([1.0], kind="RLASER")])
    with pytest.raises(DatasetError, match="no FLASER/ROBOTLASER1 scans"):
        load_scans(rear_only)


def test_bad_arguments(tmp_path):
    path = write(tmp_path / "a.clf", [flaser([1.0])])
    with pytest.raises(ValueError, match="angle_step"):
        CarmenLog(path, angle_step=0.0)
    with pytest.raises(ValueError, match="max_range"):
        CarmenLog(path, max_range=-1.0)
    with pytest.raises(ValueError, match="start_angle"):
        CarmenLog(path, start_angle=math.inf)
    with pytest.raises(ValueError, match="poses"):
        load_scans(path, poses="gps")
    with pytest.raises(ValueError, match="sources"):
        load_scans(path, sources=("ODOM",))
    with pytest.raises(ValueError, match="front laser only"):
        load_scans(path, poses="odometry", sources=("FLASER", "RLASER"))


# --------------------------------------------------------------------------- batches


def test_load_scans_corrected_and_odometry_poses(tmp_path):
    lines, scans, _ = basic_lines()
    path = write(tmp_path / "a.clf.gz", lines)
    batch = load_scans(path)
    assert batch.ranges.shape == (6, 180) and batch.ranges.dtype == np.float64
    assert batch.angles.shape == (180,)
    np.testing.assert_array_equal(batch.times, [s[4] for s in scans])
    np.testing.assert_array_equal(batch.ranges, np.stack([s[1] for s in scans]))
    np.testing.assert_array_equal(batch.laser_poses, np.array([s[2] for s in scans]))
    np.testing.assert_array_equal(batch.robot_poses, np.array([s[3] for s in scans]))
    assert batch.max_range == 50.0 and (batch.beams == 180).all()
    odo = load_scans(path, poses="odometry", dtype=np.float32)
    # laser = robot (+) (0.25, 0, 0): the PARAM robot_frontlaser_offset along the robot x axis
    r = odo.robot_poses
    expected = np.column_stack(
        (r[:, 0] + 0.25 * np.cos(r[:, 2]), r[:, 1] + 0.25 * np.sin(r[:, 2]), r[:, 2])
    )
    np.testing.assert_allclose(odo.laser_poses, expected, atol=1e-12)
    # this synthetic log logged the laser pose consistently with the offset
    np.testing.assert_allclose(odo.laser_poses, batch.laser_poses, atol=1e-12)
    assert odo.ranges.dtype == np.float32
    np.testing.assert_allclose(odo.ranges, batch.ranges, rtol=1e-6)


def test_load_scans_mixed_beam_counts_pads_with_nan(tmp_path):
    a = robotlaser(np.full(180, 2.0), start=-1.5708, laser=(0, 0, 0), robot=(0, 0, 0), t=1.0)
    b = robotlaser(np.full(181, 3.0), start=-1.5664, laser=(1, 0, 0), robot=(1, 0, 0), t=2.0)
    path = write(tmp_path / "mixed.clf", [a, b])
    batch = load_scans(path)
    assert batch.ranges.shape == (2, 181) and batch.angles.shape == (2, 181)
    assert batch.beams.tolist() == [180, 181]
    assert np.isnan(batch.ranges[0, 180]) and (batch.ranges[0, :180] == 2.0).all()
    assert batch.angles[0, 0] == -1.5708 and batch.angles[1, 0] == -1.5664


# --------------------------------------------------------------------------- shares of a log


def _concat(parts):
    parts = [b for b in parts if b is not None]
    return {f: np.concatenate([getattr(b, f) for b in parts])
            for f in ("times", "ranges", "laser_poses", "robot_poses")}  # fmt: skip


@pytest.mark.parametrize("suffix", ["", ".gz", ".bz2"])
@pytest.mark.parametrize("n", [1, 2, 4, 9])
def test_shares_parse_like_the_whole_log(tmp_path, suffix, n):
    """Split a log into shares and parse each alone: the whole log's scans, in order, for both
    pose sources (the laser offset PARAM sits in the first share only)."""
    lines, scans, _ = basic_lines()
    path = write(tmp_path / f"a.clf{suffix}", lines)
    shares = split_log(path, n)
    assert len(shares) == min(n, 6) and shares[0].first_line == 1
    for poses in ("corrected", "odometry"):
        whole = load_scans(path, poses=poses)
        parts = [load_share(s, poses=poses) for s in shares]
        assert all(b is not None and len(b.times) >= 1 for b in parts)
        got = _concat(parts)
        for f, v in got.items():
            np.testing.assert_array_equal(v, getattr(whole, f))
        assert {b.max_range for b in parts} == {50.0}  # PARAM context carried into every share


def test_share_errors_name_the_log_line(tmp_path):
    lines, scans, _ = basic_lines()
    bad_line = scans[4][0]  # 1-based line number of the fifth FLASER
    lines[bad_line - 1] = lines[bad_line - 1].replace("FLASER 180", "FLASER 179")
    path = write(tmp_path / "bad.clf.gz", lines)
    shares = split_log(path, 3)
    with pytest.raises(DatasetError, match=f"bad.clf.gz.*line {bad_line}"):
        for s in shares:
            load_share(s)
    with pytest.raises(DatasetError, match=f"line {bad_line}"):
        load_scans(path)  # the same line in a whole-log read
    # skipping: the share holding it counts it
    with pytest.warns(UserWarning, match=f"line {bad_line}"):
        counts = [load_share(s, skip_bad_lines=True) for s in shares]
    assert sum(b.skipped_lines for b in counts if b is not None) == 1


def test_split_log_without_scans_and_empty(tmp_path):
    only_odom = write(tmp_path / "odo.clf", [odom((0.0, 0.0, 0.0)), odom((1.0, 0.0, 0.0))])
    shares = split_log(only_odom, 4)
    assert len(shares) == 1 and load_share(shares[0]) is None
    empty = write(tmp_path / "empty.clf", ["\n"])
    with pytest.raises(DatasetError, match="empty"):
        split_log(empty, 2)
    with pytest.raises(ValueError, match="n_shares"):
        split_log(only_odom, 0)
    with pytest.raises(FileNotFoundError):
        split_log(tmp_path / "missing.clf", 2)


@pytest.mark.realdata
def test_intel_shares_equal_whole_log(shared_data):
    path = shared_data("intel-research-lab/intel.clf.bz2")
    whole = load_scans(path)
    got = _concat([load_share(s) for s in split_log(path, 8)])
    for f, v in got.items():
        np.testing.assert_array_equal(v, getattr(whole, f))


# --------------------------------------------------------------------------- real data


@pytest.mark.realdata
def test_intel_raw_log_counts(shared_data):
    log = CarmenLog(shared_data("intel-research-lab/intel.clf.bz2"))
    n_scan = n_odom = 0
    first = last = None
    for rec in log.records():
        if isinstance(rec, LaserScan):
            n_scan += 1
            first = first or rec
            last = rec
            assert rec.ranges.shape == (180,)
        else:
            n_odom += 1
    assert (n_scan, n_odom) == (13631, 26915)
    assert first is not None and last is not None
    assert first.time == pytest.approx(976052857.34, abs=0.01)
    assert last.time == pytest.approx(976055548.62, abs=0.01)
    assert log.params["robot_frontlaser_offset"] == "0.0"
    assert log.skipped_lines == 0 and len(log) == 13631


@pytest.mark.realdata
def test_intel_corrected_log(shared_data):
    path = shared_data("intel-research-lab/intel-corrected.log.gz")
    batch = load_scans(path)
    assert batch.ranges.shape == (910, 180)
    assert batch.max_range == DEFAULT_MAX_RANGE
    assert np.nanmax(batch.ranges[batch.ranges < 80.0]) < 30.0  # second-largest reading 26.37
    assert sum(1 for _ in CarmenLog(path).odometry()) == 14541


@pytest.mark.realdata
def test_freiburg_campus_corrected_log(shared_data):
    path = shared_data("freiburg-campus/freiburg-campus-corrected.log.gz")
    batch = load_scans(path)
    assert batch.ranges.shape == (2008, 360)
    assert batch.max_range == 80.99  # PARAM robot_front_laser_max
    np.testing.assert_allclose(np.diff(batch.angles), math.pi / 360)
    odo = load_scans(path, poses="odometry")
    d = np.hypot(*(odo.laser_poses[:, :2] - odo.robot_poses[:, :2]).T)
    np.testing.assert_allclose(d, 0.04, atol=1e-9)  # PARAM robot_frontlaser_offset -0.04
