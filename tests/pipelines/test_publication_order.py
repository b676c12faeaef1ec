"""Scans in the order their driver published them (ROS 1 header sequence numbers): the keys,
the batch's rows, and lidar-only SLAM from a bag written in stamp order whose stamps jitter."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from probmap.datasets.records import ScanBatch
from probmap.datasets.ros.scans import publication_keys
from probmap.datasets.scans import in_publication_order
from probmap.geometry.se2 import between

sys.path.insert(0, str(Path(__file__).parents[1] / "slam" / "laser"))


def test_publication_keys():
    assert publication_keys([0, 1, 3, 2, 4]).tolist() == [0, 1, 3, 2, 4]
    # a driver that starts again counts on after the last run's largest number
    assert publication_keys([500, 501, 503, 502, 3, 5, 4]).tolist() == [
        500, 501, 503, 502, 507, 509, 508,
    ]  # fmt: skip
    # a scan more than 100 places late stays where the file has it
    keys = publication_keys([*range(1000, 1201), 1050, 1201])
    assert (np.diff(keys) > 0).all()
    assert publication_keys([0, 0, 0]) is None  # a converter that wrote zeros
    assert publication_keys([1, None, 2]) is None
    assert publication_keys([]) is None


def _batch(published, n=3):
    n = n if published is None else len(published)
    return ScanBatch(
        times=np.arange(n, dtype=float),
        ranges=np.arange(n * 3, dtype=float).reshape(n, 3),
        angles=np.zeros((n, 3)),
        laser_poses=np.column_stack([np.arange(n), np.zeros(n), np.zeros(n)]).astype(float),
        robot_poses=np.zeros((n, 3)),
        max_range=10.0,
        beams=np.full(n, 3),
        published=None if published is None else np.asarray(published, dtype=np.int64),
    )


def test_in_publication_order_takes_every_per_scan_array_alike():
    b = _batch([0, 2, 3, 1, 4, 6, 5])
    c, late = in_publication_order(b)
    assert late == 2  # 1 after 3, 5 after 6
    order = [0, 3, 1, 2, 4, 6, 5]
    assert c.times.tolist() == order
    assert c.published.tolist() == sorted(b.published.tolist())
    assert np.array_equal(c.ranges, b.ranges[order])
    assert np.array_equal(c.angles, b.angles[order])
    assert np.array_equal(c.laser_poses, b.laser_poses[order])
    assert len(c.rows(slice(2, None))) == 5 and c.rows(slice(2, None)).published.tolist() == [
        2, 3, 4, 5, 6,
    ]  # fmt: skip
    for same in ([0, 1, 2], None):
        b = _batch(same)
        assert in_publication_order(b) == (b, 0)


def _ring_bag(path: Path) -> tuple[np.ndarray, np.ndarray, int]:
    """The ring corridor of the graph-SLAM tests driven at 1 m/s, 10 scans a second, written
    as a ROS 1 bag in stamp order with every 4th scan stamped 0.5 s late (its sequence
    number says when it was published); no odometry, no tf. Returns the true laser poses,
    the stamps (publication order) and the number of scans the bag holds late."""
    import test_submap_slam as T
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    world = T.loop_world()
    _, _, _, _, _, angles, max_range, _ = world
    truth = T._unicycle_loop(0.1, 0.1, 0.6)
    ranges = T._scans_at(world, truth)
    n = len(truth)
    stamps = 100.0 + 0.1 * np.arange(n) + 0.5 * (np.arange(n) % 4 == 3)
    store = get_typestore(Stores.ROS1_NOETIC)
    M = store.types
    inc = float(angles[1] - angles[0])
    with Writer(path) as writer:
        conn = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=store)
        for i in np.argsort(stamps, kind="stable"):
            sec = int(stamps[i])
            t = M["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((stamps[i] - sec) * 1e9))
            msg = M["sensor_msgs/msg/LaserScan"](
                header=M["std_msgs/msg/Header"](seq=int(i), stamp=t, frame_id="laser"),
                angle_min=float(angles[0]), angle_max=float(angles[-1]), angle_increment=inc,
                time_increment=0.0, scan_time=0.1, range_min=0.05, range_max=float(max_range),
                ranges=ranges[i].astype(np.float32), intensities=np.zeros(0, np.float32),
            )  # fmt: skip
            writer.write(
                conn,
                round(stamps[i] * 1e9),
                store.serialize_ros1(msg, "sensor_msgs/msg/LaserScan"),
            )
    held = np.argsort(stamps, kind="stable")
    late = int(np.count_nonzero(held[1:] < np.maximum.accumulate(held)[:-1]))
    return truth, stamps, late


def test_lidar_only_slam_from_a_bag_in_stamp_order_takes_the_published_order(tmp_path):
    pytest.importorskip("rosbags")
    from probmap.pipelines.laser_slam import load_laser_log, slam_grid

    bag = tmp_path / "ring.bag"
    truth, stamps, late = _ring_bag(bag)
    batch = load_laser_log(bag)
    assert np.array_equal(np.sort(batch.published), np.arange(len(truth)))
    assert batch.published.tolist() != sorted(batch.published.tolist())
    out = slam_grid(bag, tmp_path / "out")
    report = json.loads((tmp_path / "out.report.json").read_text())
    assert report["local"]["lidar_only"] and report["local"]["scans_reordered"] == late > 0
    # the trajectory follows the truth scan by scan (rows in publication order)
    run = out.run
    assert np.array_equal(run.times, stamps)
    est = run.sensor_poses
    errs = [
        math.hypot(*between(between(est[i], est[i + 10]), between(truth[i], truth[i + 10]))[:2])
        for i in range(0, len(truth) - 10, 5)
    ]
    assert np.mean(errs) < 0.03 and max(errs) < 0.1
