"""Occupancy grids in bags: one ``nav_msgs/OccupancyGrid`` message written into a new ROS 1 or
ROS 2 bag (:func:`write_map_to_bag`) and read back (:func:`read_map_from_bag`)."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from probmap._atomic import atomic_path
from probmap._typing import FloatArray
from probmap.datasets.ros._reader import (
    _deserialize,
    _messages,
    _open_reader,
    _stamp,
    require_rosbags,
)
from probmap.datasets.ros.tf import yaw_from_quaternion
from probmap.errors import BagError

__all__ = ["BagMap", "occupancy_percent", "read_map_from_bag", "write_map_to_bag"]


MAP_TYPE = "nav_msgs/msg/OccupancyGrid"


# ---------------------------------------------------------------------------- writing maps


@dataclass(frozen=True, eq=False)
class BagMap:
    """A ``nav_msgs/OccupancyGrid`` read from a bag.

    Attributes
    ----------
    data : ndarray of int8, shape (H, W)
        Occupancy in percent (0-100), -1 unknown; row 0 at the smallest y (as ``GridSpec``).
    resolution : float
        Metres per cell.
    origin : ndarray, shape (3,)
        ``(x, y, yaw)`` of cell ``[0, 0]``'s lower-left corner in ``frame_id``.
    frame_id : str
    time : float
        Header stamp, seconds.
    """

    data: NDArray[np.int8]
    resolution: float
    origin: FloatArray
    frame_id: str
    time: float


def occupancy_percent(grid: Any) -> NDArray[np.int8]:
    """``nav_msgs/OccupancyGrid`` cell values of a grid: ``round(100 p)``, -1 where unobserved.

    Shape (H, W), row 0 at the smallest y.
    """
    p = np.asarray(grid.probability(), dtype=np.float64)
    v = np.rint(100.0 * p).astype(np.int8)
    v[~np.asarray(grid.observed, dtype=bool)] = -1
    return v


def _map_message(store: Any, grid: Any, frame_id: str, stamp: float, ros1: bool) -> Any:
    types = store.types
    sec = int(math.floor(stamp))
    t = types["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((stamp - sec) * 1e9)))
    header_cls = types["std_msgs/msg/Header"]
    header = (
        header_cls(seq=0, stamp=t, frame_id=frame_id)
        if ros1
        else header_cls(stamp=t, frame_id=frame_id)
    )
    spec = grid.spec
    pose = types["geometry_msgs/msg/Pose"](
        position=types["geometry_msgs/msg/Point"](x=spec.origin[0], y=spec.origin[1], z=0.0),
        orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
    )
    h, w = spec.shape
    info = types["nav_msgs/msg/MapMetaData"](
        map_load_time=t, resolution=spec.resolution, width=w, height=h, origin=pose
    )
    data = np.ascontiguousarray(occupancy_percent(grid).reshape(-1))
    return types[MAP_TYPE](header=header, info=info, data=data)


def write_map_to_bag(
    bag_path: str | os.PathLike[str],
    grid: Any,
    *,
    topic: str = "/map",
    frame_id: str = "map",
    stamp: float = 0.0,
    storage: str = "sqlite3",
) -> Path:
    """Write a grid as one ``nav_msgs/OccupancyGrid`` message into a new bag, atomically.

    Parameters
    ----------
    bag_path : path-like
        ``*.bag`` writes a ROS 1 bag (an existing file is replaced); any other name writes a
        ROS 2 bag folder, which must not exist yet.
    grid : OccupancyGrid
        The map: cells become ``round(100 p)`` percent, -1 where never observed.
    topic, frame_id : str
        Topic name and ``header.frame_id`` (the map's frame).
    stamp : float
        Header time in seconds (also the log time).
    storage : {"sqlite3", "mcap"}
        ROS 2 storage plugin.

    Returns
    -------
    Path
        ``bag_path``.
    """
    require_rosbags()
    from rosbags.typesys import Stores, get_typestore

    out = Path(bag_path)
    if storage not in ("sqlite3", "mcap"):
        raise ValueError(f"storage must be 'sqlite3' or 'mcap', got {storage!r}")
    if not (math.isfinite(stamp) and stamp >= 0):
        raise ValueError(f"stamp must be a non-negative time in seconds, got {stamp}")
    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: output folder does not exist")
    ros1 = out.suffix == ".bag"
    if not ros1 and out.exists():
        raise FileExistsError(f"{out}: a ROS 2 bag folder exists already")
    with atomic_path(out) as tmp:
        ns = int(round(stamp * 1e9))
        if ros1:
            from rosbags.rosbag1 import Writer as Writer1

            store = get_typestore(Stores.ROS1_NOETIC)
            with Writer1(tmp) as w1:
                conn = w1.add_connection(topic, MAP_TYPE, typestore=store, latching=1)
                msg = _map_message(store, grid, frame_id, stamp, True)
                w1.write(conn, ns, store.serialize_ros1(msg, MAP_TYPE))
        else:
            from rosbags.rosbag2 import StoragePlugin
            from rosbags.rosbag2 import Writer as Writer2

            store = get_typestore(Stores.LATEST)
            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            with Writer2(tmp, version=9, storage_plugin=plugin) as w2:
                conn = w2.add_connection(topic, MAP_TYPE, typestore=store)
                msg = _map_message(store, grid, frame_id, stamp, False)
                w2.write(conn, ns, store.serialize_cdr(msg, MAP_TYPE))
    return out


def read_map_from_bag(path: str | os.PathLike[str], *, topic: str | None = None) -> BagMap:
    """The last ``nav_msgs/OccupancyGrid`` on ``topic`` (default: the only map topic).

    Raises
    ------
    BagError
        No map topic, or a message whose data does not fill ``width x height``.
    """
    p = Path(path)
    with _open_reader(p) as reader:
        conns = [
            c
            for c in reader.connections
            if c.msgtype == MAP_TYPE and (topic is None or c.topic in (topic, "/" + topic))
        ]
        if not conns:
            raise BagError(f"no nav_msgs/OccupancyGrid topic {topic or ''}".rstrip(), path=p)
        msg = None
        for conn, _, raw in _messages(reader, p, conns):
            msg = _deserialize(reader, p, conn, raw)
        if msg is None:
            raise BagError(f"topic {conns[0].topic!r} holds no message", path=p)
        w, h = int(msg.info.width), int(msg.info.height)
        data = np.asarray(msg.data, dtype=np.int8)
        if data.size != w * h:
            raise BagError(
                f"map on topic {conns[0].topic!r}: {data.size} cells for {w} x {h}", path=p
            )
        o = msg.info.origin
        q = o.orientation
        return BagMap(
            data.reshape(h, w),
            float(msg.info.resolution),
            np.array((o.position.x, o.position.y, yaw_from_quaternion(q.x, q.y, q.z, q.w))),
            str(msg.header.frame_id),
            _stamp(msg),
        )
