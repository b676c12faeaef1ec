"""``probmap.datasets.open_scans``: one input path for CARMEN logs, ROS 1/2 bags and registry
names; the same scans in a log and in a bag give the same batch."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from probmap.datasets import open_scans
from probmap.datasets.registry import DATASETS, resolve_input
from probmap.errors import DatasetError, MissingExtraError

INTEL_CORRECTED = "intel-research-lab/intel-corrected.log.gz"


def wrapped(p: np.ndarray) -> np.ndarray:
    q = np.array(p, dtype=np.float64)
    q[:, 2] = np.arctan2(np.sin(q[:, 2]), np.cos(q[:, 2]))
    return q


def assert_same_batch(a, b, *, ranges_atol: float = 0.0, angles_atol: float = 0.0) -> None:
    """The same scans: times to the bag's nanoseconds, poses to rounding (a bag's headings
    come through a quaternion and tf, wrapped), ranges and angles as given."""
    assert len(a) == len(b) and a.max_range == b.max_range
    np.testing.assert_array_equal(a.beams, b.beams)
    np.testing.assert_allclose(a.times, b.times, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.ranges, b.ranges, rtol=0, atol=ranges_atol, equal_nan=True)
    np.testing.assert_allclose(a.angles, b.angles, rtol=0, atol=angles_atol)
    for pa, pb in ((a.laser_poses, b.laser_poses), (a.robot_poses, b.robot_poses)):
        np.testing.assert_allclose(wrapped(pa), wrapped(pb), rtol=0, atol=1e-12)
    assert a.readings == b.readings and a.readings is not None
    assert a.skipped_lines == b.skipped_lines == 0


# ------------------------------------------------------------------ the same scans, log or bag


@pytest.mark.parametrize(
    ("ros", "storage"), [(1, "sqlite3"), (2, "sqlite3"), (2, "mcap")], ids=["ros1", "ros2", "mcap"]
)
def test_a_log_and_a_bag_of_the_same_scans_give_the_same_batch(sim_log, tmp_path, ros, storage):
    pytest.importorskip("rosbags")
    from bagwriter import write_log_and_bag

    log, bag = write_log_and_bag(
        sim_log(tmp_path / "sim.log"), tmp_path / "tour.log", ros=ros, storage=storage
    )
    a = open_scans(log)
    b = open_scans(bag)
    assert_same_batch(a, b)  # ranges and angles bit for bit
    assert a.readings.usable > 0 and a.readings.no_return > 0
    # a ROS 2 storage file reads as its folder; "odometry" poses are a bag's only poses
    if ros == 2:
        (storage_file,) = [p for p in bag.iterdir() if p.suffix in (".db3", ".mcap")]
        assert_same_batch(a, open_scans(storage_file))
    assert_same_batch(open_scans(log, poses="odometry"), open_scans(bag, poses="odometry"))
    # and so do their prefixes, maximum ranges and dtypes
    assert_same_batch(open_scans(log, end_time=20.0), open_scans(bag, end_time=20.0))
    assert_same_batch(open_scans(log, max_range=5.0), open_scans(bag, max_range=5.0))
    c, d = open_scans(log, dtype=np.float32), open_scans(bag, dtype=np.float32)
    assert c.ranges.dtype == d.ranges.dtype == np.float32
    assert_same_batch(c, d)


def test_a_sim_log_written_as_a_bag_reads_within_float32(sim_log, tmp_path):
    """The plain ``sim_log`` (ranges with 3 decimals) and the bag of its scans differ only
    by the bag's float32 storage."""
    pytest.importorskip("rosbags")
    from bagwriter import write_batch_bag

    log = sim_log(tmp_path / "sim.log")
    a = open_scans(log)
    b = open_scans(write_batch_bag(a, tmp_path / "sim_ros2", ros=2))
    assert_same_batch(a, b, ranges_atol=1e-6, angles_atol=1e-6)


def test_end_time_keeps_the_first_seconds_and_counts_their_readings(sim_log, tmp_path):
    log = sim_log(tmp_path / "sim.log")
    whole = open_scans(log)
    part = open_scans(log, end_time=10.0)
    keep = whole.times <= whole.times[0] + 10.0
    assert len(part) == keep.sum() < len(whole)
    np.testing.assert_array_equal(part.ranges, whole.ranges[keep])
    assert part.readings.scans == len(part)
    assert part.readings.readings == 181 * len(part)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="end_time"):
            open_scans(log, end_time=bad)


def test_a_bags_other_max_range_keeps_its_zero_readings_apart(sim_log, tmp_path):
    pytest.importorskip("rosbags")
    from bagwriter import write_batch_bag

    batch = open_scans(sim_log(tmp_path / "sim.log"))
    ranges = np.array(batch.ranges)
    ranges[3, :5] = 0.0  # zero readings: invalid, counted as zero
    bag = write_batch_bag(replace(batch, ranges=ranges), tmp_path / "z_ros2", ros=2)
    own = open_scans(bag)
    assert own.readings.zero == 5
    other = open_scans(bag, max_range=5.0)
    assert other.max_range == 5.0
    assert (other.readings.zero, other.readings.invalid) == (5, own.readings.invalid)
    assert other.readings.no_return > own.readings.no_return
    assert other.readings.readings == own.readings.readings


def test_options_and_refusals(sim_log, tmp_path):
    log = sim_log(tmp_path / "sim.log")
    with pytest.raises(ValueError, match="ROS bags only"):
        open_scans(log, bag_options={"scan_topic": "/scan"})
    assert len(open_scans(log, bag_options={"scan_topic": None})) > 0  # not given
    with pytest.raises(ValueError, match="unknown bag option"):
        open_scans(log, bag_options={"topic": "/scan"})
    with pytest.raises(ValueError, match="poses"):
        open_scans(log, poses="gps")
    zero = tmp_path / "zero.log"
    lines = [
        f"FLASER 3 0 0 0 {0.1 * i} 0 0 {0.1 * i} 0 0 {i}.0 h {i}.0" for i in range(4)
    ]  # fmt: skip
    zero.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=rf"^{zero}: no usable laser reading in 4 scans"):
        open_scans(zero)
    assert open_scans(zero, require_readings=False).readings.zero == 12


def test_a_bag_without_a_usable_reading_is_refused(sim_log, tmp_path):
    pytest.importorskip("rosbags")
    from bagwriter import write_batch_bag

    batch = open_scans(sim_log(tmp_path / "sim.log"))
    bag = write_batch_bag(
        replace(batch, ranges=np.zeros_like(batch.ranges)), tmp_path / "blind.bag", ros=1
    )
    with pytest.raises(DatasetError, match=r"blind\.bag: no usable laser reading"):
        open_scans(bag)


# ------------------------------------------------------------------ registry names


def test_registry_names_resolve_where_paths_do(shared_data, monkeypatch):
    path = shared_data(INTEL_CORRECTED)
    root = path.parents[1]
    by_path = open_scans(path)
    assert_same_batch(open_scans("intel-corrected", data_directory=root), by_path)
    monkeypatch.setenv("PROBMAP_DATA", str(root))
    assert resolve_input("intel-corrected", kind="laser") == root / INTEL_CORRECTED
    assert_same_batch(open_scans("intel-corrected"), by_path)
    # without the variable: ../shared/data relative to the working directory
    monkeypatch.delenv("PROBMAP_DATA")
    monkeypatch.chdir(root.parent)
    if (Path("..") / "shared" / "data" / INTEL_CORRECTED).exists():
        assert len(open_scans("intel-corrected", end_time=5.0)) > 0


def test_every_laser_dataset_of_the_registry_has_a_readable_format():
    laser = {n for n, i in DATASETS.items() if i.kind == "laser"}
    assert {"intel", "intel-corrected", "intel-bag"} <= laser
    for name in laser:
        rel = DATASETS[name].relpath
        assert rel is not None and rel.endswith((".bag", ".clf.bz2", ".log.gz"))
    # the names agree with those of probmap datasets fetch
    from probmap.datasets.fetch import DATASETS as REMOTE

    for name in laser:
        assert DATASETS[name].relpath in REMOTE[name].files


def test_a_name_that_is_neither_file_nor_dataset_lists_the_close_names(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(FileNotFoundError) as info:
        open_scans("intel-corected")
    msg = str(info.value)
    assert (
        msg == "intel-corected: no such file or dataset name (close dataset names: intel-corrected)"
    )
    with pytest.raises(FileNotFoundError, match=r"^inte: no such file or dataset name \(close"):
        open_scans("inte")
    with pytest.raises(FileNotFoundError, match=r"laser datasets: intel, "):
        open_scans("zzz")
    with pytest.raises(FileNotFoundError, match=r"^logs/run\.clf: no such file$"):
        open_scans("logs/run.clf")  # a path: no dataset names
    with pytest.raises(DatasetError, match="holds landmarks, not laser"):
        open_scans("mrclam7")
    with pytest.raises(DatasetError, match="not found under the data directory"):
        open_scans("intel-corrected", data_directory=tmp_path)


# ------------------------------------------------------------------ the ros extra


def test_a_bag_without_the_ros_extra_names_the_extra(tmp_path, monkeypatch):
    bag = tmp_path / "run.bag"
    bag.write_bytes(b"#ROSBAG V2.0\n")
    monkeypatch.setitem(sys.modules, "rosbags", None)  # import rosbags -> ImportError
    with pytest.raises(MissingExtraError, match=r"pip install 'probmap\[ros\]'") as info:
        open_scans(bag)
    assert isinstance(info.value, ImportError) and "\n" not in str(info.value)
