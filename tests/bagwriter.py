"""Writing ROS 1 and ROS 2 bags in tests, with rosbags' own writers and typestores (no ROS
install): :class:`BagBuilder` (messages one by one) and :func:`write_batch_bag` (the scans of a
:class:`~probmap.datasets.records.ScanBatch`, e.g. a CARMEN log as probmap reads it, as a bag
that reads back as the same batch).

Import it after ``pytest.importorskip("rosbags")``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

__all__ = ["BagBuilder", "f32", "write_batch_bag", "write_float32_log", "write_log_and_bag"]


class BagBuilder:
    """Writes ROS 1 or ROS 2 bags with rosbags' own writers and typestores."""

    def __init__(self, path: Path, ros: int, storage: str = "sqlite3") -> None:
        self.ros = ros
        if ros == 1:
            self.store = get_typestore(Stores.ROS1_NOETIC)
            self.store.register(
                get_types_from_msg(
                    "geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"
                )
            )
            self.writer = Writer1(path)
        else:
            self.store = get_typestore(Stores.ROS2_HUMBLE)
            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer2(path, version=9, storage_plugin=plugin)
        self.writer.open()
        self.conns: dict[str, object] = {}
        self.t = self.store.types

    def close(self) -> None:
        self.writer.close()

    def write(self, topic: str, msgtype: str, stamp: float, msg: object) -> None:
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)
        data = (
            self.store.serialize_ros1(msg, msgtype)
            if self.ros == 1
            else self.store.serialize_cdr(msg, msgtype)
        )
        self.writer.write(self.conns[topic], int(round(stamp * 1e9)), data)

    def header(self, stamp: float, frame: str) -> object:
        sec = int(math.floor(stamp))
        t = self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((stamp - sec) * 1e9)))
        if self.ros == 1:
            return self.t["std_msgs/msg/Header"](seq=0, stamp=t, frame_id=frame)
        return self.t["std_msgs/msg/Header"](stamp=t, frame_id=frame)

    def pose_msg(self, p: np.ndarray) -> tuple[object, object]:
        q = self.t["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(p[2] / 2), w=math.cos(p[2] / 2)
        )
        return self.t["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=0.0), q

    def scan(
        self,
        topic: str,
        stamp: float,
        frame: str,
        ranges: np.ndarray,
        amin: float,
        ainc: float,
        rmin: float,
        rmax: float,
    ) -> None:
        n = len(ranges)
        msg = self.t["sensor_msgs/msg/LaserScan"](
            header=self.header(stamp, frame),
            angle_min=amin,
            angle_max=amin + ainc * (n - 1),
            angle_increment=ainc,
            time_increment=0.0,
            scan_time=0.0,
            range_min=rmin,
            range_max=rmax,
            ranges=np.asarray(ranges, dtype=np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )
        self.write(topic, "sensor_msgs/msg/LaserScan", stamp, msg)

    def multiecho(
        self, topic: str, stamp: float, frame: str, echoes: list[list[float]], amin: float
    ) -> None:
        e = self.t["sensor_msgs/msg/LaserEcho"]
        msg = self.t["sensor_msgs/msg/MultiEchoLaserScan"](
            header=self.header(stamp, frame),
            angle_min=amin,
            angle_max=amin + 0.01 * (len(echoes) - 1),
            angle_increment=0.01,
            time_increment=0.0,
            scan_time=0.0,
            range_min=0.1,
            range_max=30.0,
            ranges=[e(echoes=np.asarray(x, dtype=np.float32)) for x in echoes],
            intensities=[],
        )
        self.write(topic, "sensor_msgs/msg/MultiEchoLaserScan", stamp, msg)

    def odom(self, topic: str, stamp: float, parent: str, child: str, p: np.ndarray) -> None:
        t = self.t
        pos, q = self.pose_msg(p)
        cov = np.zeros(36)
        v3 = t["geometry_msgs/msg/Vector3"]
        msg = t["nav_msgs/msg/Odometry"](
            header=self.header(stamp, parent),
            child_frame_id=child,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=t["geometry_msgs/msg/Pose"](position=pos, orientation=q), covariance=cov
            ),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](
                    linear=v3(x=0.5, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.1)
                ),
                covariance=cov,
            ),
        )
        self.write(topic, "nav_msgs/msg/Odometry", stamp, msg)

    def tf(self, topic: str, stamp: float, links: list[tuple[str, str, np.ndarray]]) -> None:
        t = self.t
        trs = []
        for parent, child, p in links:
            pos, q = self.pose_msg(p)
            trs.append(
                t["geometry_msgs/msg/TransformStamped"](
                    header=self.header(stamp, parent),
                    child_frame_id=child,
                    transform=t["geometry_msgs/msg/Transform"](
                        translation=t["geometry_msgs/msg/Vector3"](x=pos.x, y=pos.y, z=0.0),
                        rotation=q,
                    ),
                )
            )
        self.write(topic, "tf2_msgs/msg/TFMessage", stamp, t["tf2_msgs/msg/TFMessage"](trs))


def write_batch_bag(
    batch, path: Path, *, ros: int, storage: str = "sqlite3", angle_increment: float | None = None
) -> Path:
    """The scans of ``batch`` as a bag that reads back as the same batch: ``/scan`` in frame
    ``laser`` stamped at the scans' times, ``odom -> base_link`` on ``/odom`` (the robot
    poses, at the same stamps) and a static ``base_link -> laser`` on ``/tf_static`` (the
    mounting of the first scan). Scans must share one beam geometry (``angle_increment``,
    default the first two beams' difference); ``range_max`` is the batch's maximum range."""
    from probmap.geometry.se2 import between

    angles = np.asarray(batch.angles, dtype=np.float64)
    assert angles.ndim == 1, "one beam geometry"
    robot = np.asarray(batch.robot_poses, dtype=np.float64)
    mount = between(robot[0], np.asarray(batch.laser_poses[0], dtype=np.float64))
    b = BagBuilder(path, ros, storage)
    t = np.asarray(batch.times, dtype=np.float64)
    b.tf("/tf_static", float(t[0]), [("base_link", "laser", mount)])
    ainc = float(angles[1] - angles[0]) if angle_increment is None else angle_increment
    for k in range(len(t)):
        b.odom("/odom", float(t[k]), "odom", "base_link", robot[k])
        b.scan(
            "/scan", float(t[k]), "laser", np.asarray(batch.ranges[k]), float(angles[0]), ainc,
            0.0, float(batch.max_range),
        )  # fmt: skip
    b.close()
    return path


def f32(v: float) -> str:
    """``v`` rounded to float32 (as a bag stores ranges and angles), written exactly."""
    return repr(float(np.float32(v)))


def write_float32_log(batch, path: Path) -> tuple[Path, float]:
    """``batch`` as a CARMEN log of ``ROBOTLASER1`` lines (which carry the beam geometry) with
    its ranges, first angle, angular step and maximum range rounded to float32, as a bag stores
    them (poses and times exact). Returns the log and its angular step."""
    angles = np.asarray(batch.angles, dtype=np.float64)
    n = len(angles)
    start, step = f32(angles[0]), f32(angles[1] - angles[0])
    head = (
        f"ROBOTLASER1 0 {start} {f32(float(step) * (n - 1))} {step} {f32(batch.max_range)} 0.01 0"
    )
    lines = []
    for t, r, lp, rp in zip(
        batch.times, batch.ranges, batch.laser_poses, batch.robot_poses, strict=True
    ):
        pose = " ".join(repr(float(v)) for v in (*lp, *rp))
        rs = " ".join(f32(v) for v in r)
        lines.append(f"{head} {n} {rs} 0 {pose} 0 0 0 0 0 {float(t)!r} sim {float(t)!r}")
    path.write_text("\n".join(lines) + "\n")
    return path, float(step)


def write_log_and_bag(source: Path, log: Path, *, ros: int, storage: str = "sqlite3"):
    """``(log, bag)``: the scans of the CARMEN log ``source`` written as a float32 CARMEN log
    (:func:`write_float32_log`) and as a bag of the same numbers beside it (``LOG.bag`` for
    ROS 1, else the folder ``LOG_ros2``): the two read as the same scans."""
    from probmap.datasets import open_scans

    log, step = write_float32_log(open_scans(source), log)
    bag = log.with_suffix(".bag") if ros == 1 else log.parent / f"{log.stem}_ros2"
    write_batch_bag(open_scans(log), bag, ros=ros, storage=storage, angle_increment=step)
    return log, bag
