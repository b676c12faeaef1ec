"""ROS bag reading speed (scans per second): probmap's reader beside rosbags' own decoder and the
CARMEN reader, in one run.

Rows (best of ``--repeat`` runs each):

- synthetic ROS 1 and ROS 2 (sqlite3) bags written here: ``--scans`` LaserScans of ``--beams``
  beams with nav_msgs/Odometry at the same rate and a static base_link -> laser tf.
  ``rosbags deserialize`` is the floor: every scan message decoded, ranges stacked, no pose
  (``+ odometry``: the odometry messages decoded too, as posing needs them);
  ``probmap load_bag_scans`` also decodes the odometry and tf and poses every scan through the
  tf buffer; ``probmap RosBag iteration`` streams LaserScan records. ``CARMEN load_scans`` reads
  the same scans written as a FLASER log (the other format the mapper takes).
- the real Cartographer backpack bag (``MultiEchoLaserScan``, 1,079 beams, bz2 chunks):
  rosbags' decoder (one Python object per beam) against probmap's direct ROS 1 decoder.

Run:  python benchmarks/bench_rosbag.py [--scans 5000] [--beams 360] [--repeat 3]
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from probmap.datasets.carmen import load_scans
from probmap.datasets.ros.scans import RosBag, load_bag_scans

REAL = (
    Path(__file__).resolve().parents[2]
    / "shared"
    / "data"
    / "ros-bags"
    / "b0-2014-07-21-12-42-53-short.bag"
)


def write_bag(path: Path, ros: int, scans: int, beams: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    if ros == 1:
        store = get_typestore(Stores.ROS1_NOETIC)
        store.register(
            get_types_from_msg(
                "geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"
            )
        )
        writer: Writer1 | Writer2 = Writer1(path)
        ser = store.serialize_ros1
    else:
        store = get_typestore(Stores.ROS2_HUMBLE)
        writer = Writer2(path, version=9)
        ser = store.serialize_cdr
    t = store.types

    def header(stamp: float, frame: str) -> object:
        sec = int(stamp)
        tm = t["builtin_interfaces/msg/Time"](sec=sec, nanosec=int((stamp - sec) * 1e9))
        if ros == 1:
            return t["std_msgs/msg/Header"](seq=0, stamp=tm, frame_id=frame)
        return t["std_msgs/msg/Header"](stamp=tm, frame_id=frame)

    def pose(x: float, y: float, th: float) -> tuple[object, object]:
        return (
            t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(th / 2), w=math.cos(th / 2)),
        )

    writer.open()
    c_scan = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=store)
    c_odom = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
    c_tf = writer.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=store)
    t0 = 1.6e9
    p, q = pose(0.2, 0.0, 0.0)
    static = t["geometry_msgs/msg/TransformStamped"](
        header=header(t0, "base_link"),
        child_frame_id="laser",
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=0.2, y=0.0, z=0.0), rotation=q
        ),
    )
    writer.write(c_tf, int(t0 * 1e9), ser(t["tf2_msgs/msg/TFMessage"]([static]), c_tf.msgtype))
    cov = np.zeros(36)
    v3 = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    twist = t["geometry_msgs/msg/TwistWithCovariance"](
        twist=t["geometry_msgs/msg/Twist"](linear=v3, angular=v3), covariance=cov
    )
    for k in range(scans):
        stamp = t0 + 0.1 * k
        ns = int(round(stamp * 1e9))
        p, q = pose(0.05 * k, 0.0, 0.01 * k)
        odom = t["nav_msgs/msg/Odometry"](
            header=header(stamp, "odom"),
            child_frame_id="base_link",
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=t["geometry_msgs/msg/Pose"](position=p, orientation=q), covariance=cov
            ),
            twist=twist,
        )
        writer.write(c_odom, ns, ser(odom, c_odom.msgtype))
        scan = t["sensor_msgs/msg/LaserScan"](
            header=header(stamp, "laser"),
            angle_min=-math.pi / 2,
            angle_max=math.pi / 2,
            angle_increment=math.pi / beams,
            time_increment=0.0,
            scan_time=0.0,
            range_min=0.05,
            range_max=30.0,
            ranges=rng.uniform(0.1, 35.0, beams).astype(np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )
        writer.write(c_scan, ns, ser(scan, c_scan.msgtype))
    writer.close()


def write_carmen(path: Path, bag: Path) -> None:
    batch = load_bag_scans(bag)
    with open(path, "w") as f:
        for k in range(len(batch)):
            r = " ".join(f"{v:.3f}" for v in np.nan_to_num(batch.ranges[k], nan=0.0))
            lp, rp = batch.laser_poses[k], batch.robot_poses[k]
            f.write(
                f"FLASER {batch.ranges.shape[1]} {r} {lp[0]:.6f} {lp[1]:.6f} {lp[2]:.6f} "
                f"{rp[0]:.6f} {rp[1]:.6f} {rp[2]:.6f} {batch.times[k]:.6f} host 0.0\n"
            )


def rosbags_floor(path: Path, topic: str, echo_type: bool = False, odom: bool = False) -> int:
    rows = []
    store = get_typestore(Stores.ROS1_NOETIC if path.suffix == ".bag" else Stores.LATEST)
    topics = (topic, "/odom") if odom else (topic,)
    with AnyReader([path], default_typestore=store) as r:
        conns = [c for c in r.connections if c.topic in topics]
        for c, _, raw in r.messages(connections=conns):
            m = r.deserialize(raw, c.msgtype)
            if c.topic == "/odom":
                continue
            if echo_type:
                rows.append(np.array([e.echoes[0] for e in m.ranges], dtype=np.float64))
            else:
                rows.append(np.asarray(m.ranges, dtype=np.float64))
    return len(np.array(rows))


def best_of(fn: Callable[[], int], repeat: int) -> tuple[float, int]:
    times, n = [], 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        n = fn()
        times.append(time.perf_counter() - t0)
    return min(times), n


def table(title: str, rows: list[tuple[str, Callable[[], int]]], repeat: int) -> None:
    print(f"\n{title}\n")
    print("| reader | scans | seconds | scans/s | ratio to the first row |")
    print("| --- | ---: | ---: | ---: | ---: |")
    base = None
    for name, fn in rows:
        s, n = best_of(fn, repeat)
        base = base or s
        print(f"| {name} | {n:,} | {s:.3f} | {n / s:,.0f} | {s / base:.2f}x |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=5000)
    ap.add_argument("--beams", type=int, default=360)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        b1, b2, log = d / "sim.bag", d / "sim2", d / "sim.clf"
        write_bag(b1, 1, args.scans, args.beams)
        write_bag(b2, 2, args.scans, args.beams)
        write_carmen(log, b1)
        rows: list[tuple[str, Callable[[], int]]] = [
            ("ROS 1: rosbags deserialize (floor, no poses)", lambda: rosbags_floor(b1, "/scan")),
            (
                "ROS 1: rosbags deserialize scans + odometry (floor, no poses)",
                lambda: rosbags_floor(b1, "/scan", odom=True),
            ),
            ("ROS 1: probmap load_bag_scans (odometry + tf)", lambda: len(load_bag_scans(b1))),
            ("ROS 1: probmap RosBag iteration", lambda: sum(1 for _ in RosBag(b1))),
            ("ROS 2 db3: rosbags deserialize (floor)", lambda: rosbags_floor(b2, "/scan")),
            ("ROS 2 db3: probmap load_bag_scans", lambda: len(load_bag_scans(b2))),
            ("same scans as a CARMEN log: load_scans", lambda: len(load_scans(log))),
        ]
        table(
            f"Synthetic bags: {args.scans:,} LaserScans x {args.beams} beams + odometry",
            rows,
            args.repeat,
        )
    if REAL.exists():
        table(
            "Real Cartographer backpack bag, horizontal_laser_2d (MultiEchoLaserScan, 1,079 beams)",
            [
                (
                    "rosbags deserialize (one object per beam)",
                    lambda: rosbags_floor(REAL, "horizontal_laser_2d", echo_type=True),
                ),
                (
                    "probmap load_bag_scans (direct ROS 1 decoder)",
                    lambda: len(
                        load_bag_scans(
                            REAL,
                            scan_topic="horizontal_laser_2d",
                            fixed_frame="horizontal_laser_link",
                        )
                    ),
                ),
            ],
            args.repeat,
        )


if __name__ == "__main__":
    main()
