"""Reader for ROS 1 (``.bag``) and ROS 2 (``.db3``/``.mcap``) bags, without a ROS installation.

Bags are read through the pure-Python ``rosbags`` package (the ``ros`` extra:
``pip install 'probmap[ros]'``), imported only when a bag is opened. The reader yields the same
:class:`~probmap.datasets.records.LaserScan` records as the CARMEN reader and offers the same bulk
:class:`~probmap.datasets.records.ScanBatch` path (:func:`load_bag_scans`), so a bag maps exactly
like a log.

What is read
------------
- ``sensor_msgs/LaserScan`` and ``sensor_msgs/MultiEchoLaserScan`` (one echo, the first by
  default). Beam ``i`` lies at ``angle_min + i * angle_increment`` in the message's frame.
  Readings below ``range_min`` (zero, negative, NaN and -Inf among them) are invalid and become
  NaN, which every command drops; readings at or above ``range_max`` (and +Inf) are "no return"
  and become ``range_max``, as in the CARMEN records. :func:`load_bag_scans` counts them in the
  batch's ``readings`` (:mod:`probmap.datasets.validate`).
- ``nav_msgs/Odometry``: its pose is a transform from ``header.frame_id`` (e.g. ``odom``) to
  ``child_frame_id`` (e.g. ``base_link``).
- ``tf`` and ``tf_static`` (``tf2_msgs/TFMessage``): the transform tree. A scan's pose is the
  chain from the fixed frame (``odom`` or ``map``) to the laser frame, each moving link
  interpolated at the scan's header time (:class:`TfBuffer`).

Frames are projected onto the plane: a transform keeps its ``(x, y)`` translation and its yaw
about +z, which is exact for a robot moving on a level floor with a level laser.
"""

from __future__ import annotations

import math
import os
import struct
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
from numpy.typing import NDArray

from probmap._atomic import atomic_path
from probmap._typing import FloatArray
from probmap.datasets.records import LaserScan, Odometry, ScanBatch, stack_beams
from probmap.datasets.validate import PoseLimits, PoseTracker, ReadingReport, validate_ranges
from probmap.errors import BadLinesWarning, BagError, MissingExtraError
from probmap.geometry.se2 import compose, inverse, wrap_angle

if TYPE_CHECKING:
    from typing_extensions import Unpack

__all__ = [
    "BagMap",
    "BagSummary",
    "RosBag",
    "RosBagOptions",
    "TfBuffer",
    "TopicSummary",
    "is_bag",
    "load_bag_scans",
    "read_map_from_bag",
    "require_rosbags",
    "summarize_bag",
    "write_map_to_bag",
    "yaw_from_quaternion",
]


SCAN_TYPES = ("sensor_msgs/msg/LaserScan", "sensor_msgs/msg/MultiEchoLaserScan")
ODOM_TYPE = "nav_msgs/msg/Odometry"
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
MAP_TYPE = "nav_msgs/msg/OccupancyGrid"
_NS = 1e-9


def require_rosbags() -> Any:
    """Import ``rosbags`` or fail with the extra to install.

    Raises
    ------
    MissingExtraError
        (an ImportError) When ``rosbags`` is not installed; the message names
        ``pip install 'probmap[ros]'``.
    """
    try:
        import rosbags
    except ImportError:
        raise MissingExtraError(
            "reading ROS bags needs the 'rosbags' package: pip install 'probmap[ros]'"
        ) from None
    return rosbags


# ---------------------------------------------------------------------------- planar poses


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Rotation about +z (radians) of the unit quaternion ``(x, y, z, w)``.

    >>> round(yaw_from_quaternion(0.0, 0.0, math.sin(0.25), math.cos(0.25)), 12)
    0.5
    """
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


# ---------------------------------------------------------------------------- tf buffer


@dataclass
class _Edge:
    parent: str
    static: bool
    times: list[float]
    poses: list[tuple[float, float, float]]
    source: str
    _arrays: tuple[FloatArray, FloatArray] | None = None

    def arrays(self) -> tuple[FloatArray, FloatArray]:
        if self._arrays is None or len(self._arrays[0]) != len(self.times):
            t = np.asarray(self.times, dtype=np.float64)
            p = np.asarray(self.poses, dtype=np.float64).reshape(-1, 3)
            order = np.argsort(t, kind="stable")
            t, p = t[order], p[order]
            p[:, 2] = np.unwrap(p[:, 2])  # interpolate yaw along the shorter arc
            self._arrays = (t, p)
        return self._arrays


class TfBuffer:
    """A planar transform tree over time (the ``tf`` of ROS, projected onto the plane).

    Every frame has at most one parent. A static link (``tf_static``) holds one transform for
    all time; a moving link holds a time series, linearly interpolated in ``(x, y)`` and along
    the shorter arc in yaw. Looking a time up outside a moving link's series is an error (no
    extrapolation, as tf2).

    Examples
    --------
    >>> tf = TfBuffer()
    >>> tf.add("odom", "base_link", 0.0, (0.0, 0.0, 0.0))
    >>> tf.add("odom", "base_link", 2.0, (2.0, 0.0, 0.0))
    >>> tf.add("base_link", "laser", 0.0, (0.5, 0.0, 0.0), static=True)
    >>> tf.lookup("odom", "laser", [1.0]).round(6).tolist()
    [[1.5, 0.0, 0.0]]
    """

    def __init__(self) -> None:
        self._edges: dict[str, _Edge] = {}

    def add(
        self,
        parent: str,
        child: str,
        time: float,
        pose: Sequence[float] | FloatArray,
        *,
        static: bool = False,
        source: str = "",
    ) -> None:
        """Record the pose ``(x, y, yaw)`` of ``child`` in ``parent`` at ``time`` (seconds).

        Raises
        ------
        ValueError
            When ``child`` already has another parent, or the pose or time is not finite.
        """
        parent, child = parent.lstrip("/"), child.lstrip("/")
        x, y, th = (float(v) for v in pose)
        if not all(math.isfinite(v) for v in (x, y, th, time)):
            raise ValueError(f"transform {parent} -> {child} at t={time} is not finite")
        if parent == child:
            raise ValueError(f"transform from frame {parent!r} to itself")
        e = self._edges.get(child)
        if e is None:
            e = _Edge(parent, static, [], [], source)
            self._edges[child] = e
        elif e.parent != parent:
            raise ValueError(
                f"frame {child!r} has two parents: {e.parent!r} and {parent!r} (tf is a tree)"
            )
        if static:
            e.static, e.times, e.poses = True, [float(time)], [(x, y, th)]
        elif not e.static:
            e.times.append(float(time))
            e.poses.append((x, y, th))

    def replace_parent(self, child: str, edge_source: str) -> None:
        """Forget the links into ``child`` unless they came from ``edge_source``."""
        e = self._edges.get(child.lstrip("/"))
        if e is not None and e.source != edge_source:
            del self._edges[child.lstrip("/")]

    @property
    def frames(self) -> list[str]:
        """Every frame named by a link, sorted."""
        names = set(self._edges) | {e.parent for e in self._edges.values()}
        return sorted(names)

    def links(self) -> list[tuple[str, str, bool, int]]:
        """``(parent, child, static, count)`` of each link."""
        return [(e.parent, c, e.static, len(e.times)) for c, e in sorted(self._edges.items())]

    def parent(self, frame: str) -> str | None:
        """The parent of ``frame``, or None for a root or unknown frame."""
        e = self._edges.get(frame.lstrip("/"))
        return None if e is None else e.parent

    def time_range(self, frame: str) -> tuple[float, float]:
        """First and last time (s) at which the chain from ``frame`` to its root is known."""
        lo, hi = -math.inf, math.inf
        f = frame.lstrip("/")
        while f in self._edges:
            e = self._edges[f]
            if not e.static:
                t, _ = e.arrays()
                lo, hi = max(lo, float(t[0])), min(hi, float(t[-1]))
            f = e.parent
        return lo, hi

    def _chain(self, frame: str) -> list[str]:
        chain = [frame]
        seen = {frame}
        while chain[-1] in self._edges:
            p = self._edges[chain[-1]].parent
            if p in seen:
                raise ValueError(f"tf has a cycle through frame {p!r}")
            chain.append(p)
            seen.add(p)
        return chain

    def _edge_at(self, child: str, times: FloatArray) -> FloatArray:
        e = self._edges[child]
        t, p = e.arrays()
        if e.static:
            return np.broadcast_to(p[0], (len(times), 3)).copy()
        bad = (times < t[0]) | (times > t[-1])
        if bad.any():
            tb = float(times[np.argmax(bad)])
            raise ValueError(
                f"time {tb:.9f} s lies outside the tf buffer of {e.parent} -> {child} "
                f"([{t[0]:.9f}, {t[-1]:.9f}] s; no extrapolation)"
            )
        out = np.empty((len(times), 3))
        for k in range(3):
            out[:, k] = np.interp(times, t, p[:, k])
        out[:, 2] = wrap_angle(out[:, 2])
        return out

    def _to_root(self, chain: list[str], times: FloatArray) -> FloatArray:
        """Pose of ``chain[0]`` in ``chain[-1]`` at each time, shape (N, 3)."""
        pose = np.zeros((len(times), 3))
        for child in chain[:-1]:
            pose = compose(self._edge_at(child, times), pose)
        return pose

    def lookup(self, target: str, source: str, times: Sequence[float] | FloatArray) -> FloatArray:
        """Pose ``(x, y, yaw)`` of frame ``source`` in frame ``target`` at each time.

        Parameters
        ----------
        target : str
            The fixed frame (e.g. ``odom`` or ``map``).
        source : str
            The frame to place (e.g. the laser's).
        times : array_like, shape (N,)
            Seconds.

        Returns
        -------
        ndarray, shape (N, 3)
            Metres, metres, radians in ``(-pi, pi]``.

        Raises
        ------
        ValueError
            When the frames are not connected (naming both and the known frames), or a time
            lies outside a moving link's buffer (naming the link and the time).
        """
        target, source = target.lstrip("/"), source.lstrip("/")
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        if not np.isfinite(t).all():
            raise ValueError("lookup times must be finite")
        up_s, up_t = self._chain(source), self._chain(target)
        common = next((f for f in up_s if f in set(up_t)), None)
        if common is None:
            known = ", ".join(self.frames) or "none"
            raise ValueError(
                f"frame {source!r} cannot be connected to frame {target!r} through tf "
                f"(known frames: {known})"
            )
        a = self._to_root(up_s[: up_s.index(common) + 1], t)
        b = self._to_root(up_t[: up_t.index(common) + 1], t)
        return compose(inverse(b), a)


# ---------------------------------------------------------------------------- opening bags


def is_bag(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` looks like a ROS bag: a ``.bag`` file, a ROS 2 bag folder (with
    ``metadata.yaml``) or a ``.db3``/``.mcap`` storage file. Nothing is opened."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.suffix in (".bag", ".db3", ".mcap")


@contextmanager
def _open_reader(path: Path) -> Iterator[Any]:
    """An open ``rosbags`` AnyReader over a ROS 1 file or a ROS 2 folder/storage file."""
    require_rosbags()
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or directory")
    target = path
    if path.is_file() and path.suffix in (".db3", ".mcap"):
        if not (path.parent / "metadata.yaml").is_file():
            raise BagError(
                "a ROS 2 storage file needs its metadata.yaml beside it (pass the bag folder)",
                path=path,
            )
        target = path.parent
    elif path.is_dir() and not (path / "metadata.yaml").is_file():
        raise BagError("not a ROS 2 bag folder (no metadata.yaml)", path=path)
    elif path.is_file() and path.suffix != ".bag":
        raise BagError("not a ROS bag: expected a .bag file or a ROS 2 bag folder", path=path)
    store = get_typestore(Stores.ROS1_NOETIC if target.suffix == ".bag" else Stores.LATEST)
    reader = AnyReader([target], default_typestore=store)
    try:
        reader.open()
    except Exception as exc:  # rosbags raises many types on a bad file
        if isinstance(exc, (KeyboardInterrupt, MemoryError)):
            raise
        raise BagError(f"corrupt or truncated bag ({exc})", path=path) from None
    try:
        yield reader
    finally:
        reader.close()


def _messages(
    reader: Any, path: Path, connections: Sequence[Any]
) -> Iterator[tuple[Any, int, Any]]:
    """``(connection, log time ns, raw bytes)``, with read errors named by file and topic."""
    if not connections:  # rosbags reads every topic for an empty filter
        return
    it = reader.messages(connections=list(connections))
    topic = "?"
    while True:
        try:
            conn, ts, raw = next(it)
        except StopIteration:
            return
        except Exception as exc:
            raise BagError(
                f"corrupt or truncated bag while reading topic {topic!r} ({exc})", path=path
            ) from None
        topic = conn.topic
        yield conn, ts, raw


def _deserialize(reader: Any, path: Path, conn: Any, raw: Any) -> Any:
    try:
        return reader.deserialize(raw, conn.msgtype)
    except Exception as exc:
        raise BagError(
            f"cannot decode a {conn.msgtype} message on topic {conn.topic!r} ({exc})", path=path
        ) from None


def _stamp(msg: Any) -> float:
    s = msg.header.stamp
    return float(s.sec) + float(s.nanosec) * _NS


# ---------------------------------------------------------------------------- discovery


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag.

    Attributes
    ----------
    topic, msgtype : str
        Name and message type (``pkg/msg/Name``).
    count : int
        Messages on the topic.
    frames : tuple of str
        ``header.frame_id`` of its first message (tf topics: every child frame).
    start, end : float
        Log times in seconds of its first and last message (NaN when empty).
    """

    topic: str
    msgtype: str
    count: int
    frames: tuple[str, ...]
    start: float
    end: float


@dataclass(frozen=True)
class BagSummary:
    """What a bag holds: see :func:`summarize_bag`."""

    path: Path
    ros_version: int
    start: float
    end: float
    messages: int
    topics: tuple[TopicSummary, ...]
    tf_links: tuple[tuple[str, str, bool, int], ...]

    @property
    def duration(self) -> float:
        """Seconds between the first and last message."""
        return self.end - self.start

    @property
    def frames(self) -> tuple[str, ...]:
        """Every frame named by a message header or a tf link, sorted."""
        names = {f for t in self.topics for f in t.frames}
        for p, c, _, _ in self.tf_links:
            names |= {p, c}
        names.discard("")
        return tuple(sorted(names))

    def topics_of(self, msgtypes: Sequence[str]) -> list[TopicSummary]:
        """Topics whose message type is one of ``msgtypes``."""
        return [t for t in self.topics if t.msgtype in msgtypes]


def summarize_bag(path: str | os.PathLike[str]) -> BagSummary:
    """Topics, types, counts, frames and times of a bag (reads one message per topic, and tf).

    Raises
    ------
    FileNotFoundError, BagError, ImportError
        Missing path; corrupt or truncated bag; ``rosbags`` not installed.
    """
    p = Path(path)
    with _open_reader(p) as reader:
        tf = TfBuffer()
        topics = []
        for conn_topic, info in sorted(reader.topics.items()):
            conns = [c for c in reader.connections if c.topic == conn_topic]
            count = sum(int(c.msgcount) for c in conns)
            frames: list[str] = []
            first = last = math.nan
            if info.msgtype in TF_TYPES:
                for c, ts, raw in _messages(reader, p, conns):
                    first = ts * _NS if math.isnan(first) else first
                    last = ts * _NS
                    static = "static" in conn_topic
                    _add_tf(tf, _deserialize(reader, p, c, raw), static, conn_topic)
                frames = sorted({c for _, c, _, _ in tf.links()})
            else:
                for c, ts, raw in _messages(reader, p, conns):
                    first = ts * _NS
                    msg = _deserialize(reader, p, c, raw)
                    header = getattr(msg, "header", None)
                    if header is not None:
                        frames.append(str(header.frame_id).lstrip("/"))
                    break
                last = _last_time(reader, conns, first)
            topics.append(TopicSummary(conn_topic, info.msgtype, count, tuple(frames), first, last))
        return BagSummary(
            p,
            2 if reader.is2 else 1,
            reader.start_time * _NS if reader.message_count else math.nan,
            reader.end_time * _NS if reader.message_count else math.nan,
            int(reader.message_count),
            tuple(topics),
            tuple(tf.links()),
        )


def _last_time(reader: Any, conns: Sequence[Any], first: float) -> float:
    """Log time of the last message of ``conns`` from the index, without decoding."""
    last = first
    for r in reader.readers:
        idx = getattr(r, "indexes", None)
        if isinstance(idx, dict):
            for c in conns:
                entries = idx.get(c.id)
                if entries:
                    last = max(last, entries[-1].time * _NS)
            continue
        # ROS 2: the storage index is cheap to scan without decoding the payloads
        for _, ts, _ in r.messages(connections=[c for c in conns if c.owner is r]):
            last = max(last, ts * _NS)
    return last


def _add_tf(tf: TfBuffer, msg: Any, static: bool, topic: str) -> None:
    for tr in msg.transforms:
        q = tr.transform.rotation
        v = tr.transform.translation
        tf.add(
            str(tr.header.frame_id),
            str(tr.child_frame_id),
            _stamp(tr),
            (v.x, v.y, yaw_from_quaternion(q.x, q.y, q.z, q.w)),
            static=static,
            source=topic,
        )


# ---------------------------------------------------------------------------- scans


def _ros1_multiecho(raw: bytes | memoryview, echo: int) -> tuple[float, str, Any, FloatArray]:
    """Decode a ROS 1 ``MultiEchoLaserScan`` without building a message per beam.

    Returns ``(stamp, frame_id, (angle_min, angle_max, angle_increment, range_min, range_max),
    ranges)``. Beams with fewer echoes than ``echo + 1`` read NaN.
    """
    buf = memoryview(raw)
    _, sec, nsec, n = struct.unpack_from("<IIII", buf, 0)
    frame = bytes(buf[16 : 16 + n]).decode("utf-8", "replace")
    off = 16 + n
    amin, amax, ainc, _, _, rmin, rmax = struct.unpack_from("<7f", buf, off)
    off += 28
    (beams,) = struct.unpack_from("<I", buf, off)
    off += 4
    out = np.full(beams, np.nan)
    if beams:
        (k0,) = struct.unpack_from("<I", buf, off)
        stride = 4 + 4 * k0
        if k0 > 0 and off + beams * stride <= len(buf):
            # every beam the same echo count: one strided view
            block = np.frombuffer(buf, dtype="<u4", count=beams * stride // 4, offset=off)
            block = block.reshape(beams, stride // 4)
            if (block[:, 0] == k0).all():
                if echo < k0:
                    out[:] = block[:, 1 + echo].view("<f4")
                return sec + nsec * _NS, frame, (amin, amax, ainc, rmin, rmax), out
        for i in range(beams):
            (k,) = struct.unpack_from("<I", buf, off)
            if echo < k:
                out[i] = struct.unpack_from("<f", buf, off + 4 + 4 * echo)[0]
            off += 4 + 4 * k
    return sec + nsec * _NS, frame, (amin, amax, ainc, rmin, rmax), out


def _clean_ranges(r: FloatArray, rmin: float, rmax: float) -> FloatArray:
    """NaN below ``range_min`` (and -Inf); ``range_max`` at or above it (and +Inf)."""
    return _validated_ranges(r, rmin, rmax)[0]


def _validated_ranges(r: FloatArray, rmin: float, rmax: float) -> tuple[FloatArray, ReadingReport]:
    """:func:`_clean_ranges` and the classification of the raw readings (positive readings
    below ``range_min`` count as invalid, like NaN)."""
    r = np.asarray(r, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        below = (r > 0) & (r < rmin)
    _, report = validate_ranges(np.where(below, np.nan, r), rmax)
    with np.errstate(invalid="ignore"):
        out = np.where(r >= rmax, rmax, r)
        out[~(r >= rmin) | (r <= 0)] = np.nan  # catches NaN too
    return out, report


@dataclass(frozen=True)
class _RawScan:
    time: float
    log_time: float
    frame: str
    angles: FloatArray
    ranges: FloatArray
    max_range: float
    source: str
    index: int
    report: ReadingReport | None = None


class RosBagOptions(TypedDict, total=False):
    """The keywords of :class:`RosBag` (their defaults and meaning are documented there),
    which :func:`load_bag_scans` hands on to it."""

    scan_topic: str | None
    odom_topic: str | None
    fixed_frame: str | None
    laser_frame: str | None
    echo: int


class RosBag:
    """A ROS 1 or ROS 2 bag as a :class:`~probmap.datasets.protocol.Dataset` of laser scans.

    Parameters
    ----------
    path : path-like
        A ROS 1 ``.bag`` file, or a ROS 2 bag folder (``metadata.yaml`` with ``.db3`` or
        ``.mcap`` storage), or its storage file.
    scan_topic : str, optional
        The ``LaserScan``/``MultiEchoLaserScan`` topic; by default the only one in the bag.
    odom_topic : str, optional
        A ``nav_msgs/Odometry`` topic whose poses become tf links ``frame_id -> child_frame_id``
        (replacing tf's own link into that child). By default the only odometry topic, used
        when tf does not already hold its link.
    fixed_frame : str, optional
        The world frame of the poses. Default: the odometry's ``frame_id``, else ``map`` or
        ``odom`` when tf connects it to the laser, else the root of the laser's tf tree.
    laser_frame : str, optional
        The scans' frame; by default each message's ``header.frame_id``.
    echo : int
        Which echo of a ``MultiEchoLaserScan`` to read (0 = first).

    Notes
    -----
    Iterating yields :class:`~probmap.datasets.records.LaserScan` records in time order with
    ``laser_pose`` the laser frame in the fixed frame at the scan's header time and
    ``robot_pose`` the base frame (the odometry child, else ``base_link``/``base_footprint``,
    else the laser) in the same frame. ``time`` is the header stamp (s), ``logger_time`` the
    bag's log time since its first message (s), ``source`` the message type name and ``line``
    the 1-based index of the message on its topic. A bag without tf or odometry can still be
    read by naming the laser frame as the fixed frame: every pose is then the identity.

    Raises
    ------
    FileNotFoundError, ImportError
        Missing path; ``rosbags`` not installed (names the ``ros`` extra).
    BagError
        (While reading) a corrupt or truncated bag; a missing or ambiguous topic; a scan time
        outside the tf buffer; a laser frame not connected to the fixed frame.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        scan_topic: str | None = None,
        odom_topic: str | None = None,
        fixed_frame: str | None = None,
        laser_frame: str | None = None,
        echo: int = 0,
    ) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: no such file or directory")
        if int(echo) != echo or echo < 0:
            raise ValueError(f"echo must be a non-negative integer, got {echo!r}")
        require_rosbags()
        self.scan_topic = scan_topic
        self.odom_topic = odom_topic
        self.fixed_frame = None if fixed_frame is None else fixed_frame.lstrip("/")
        self.laser_frame = None if laser_frame is None else laser_frame.lstrip("/")
        self.echo = int(echo)
        self.scans_outside_tf = 0  # scans dropped for lying outside the tf buffer (last read)
        self.name = self.path.stem if self.path.suffix == ".bag" else self.path.name
        self._count: int | None = None
        self._base: str | None = None
        #: ``(fixed, base, laser)`` frames the last complete read used (None before one).
        self.resolved_frames: tuple[str, str, str] | None = None

    def __repr__(self) -> str:
        return f"RosBag({str(self.path)!r})"

    # ------------------------------------------------------------------ topics
    def _pick(self, reader: Any, wanted: str | None, types: Sequence[str], what: str) -> Any:
        """Connections of the chosen topic (None when optional and absent)."""
        by_topic: dict[str, list[Any]] = {}
        for c in reader.connections:
            by_topic.setdefault(c.topic, []).append(c)
        if wanted is not None:
            key = wanted if wanted in by_topic else "/" + wanted.lstrip("/")
            if key not in by_topic:
                key = wanted.lstrip("/") if wanted.lstrip("/") in by_topic else key
            if key not in by_topic:
                have = ", ".join(f"{t} ({cs[0].msgtype})" for t, cs in sorted(by_topic.items()))
                raise BagError(f"no topic {wanted!r} in the bag (topics: {have})", path=self.path)
            conns = by_topic[key]
            if conns[0].msgtype not in types:
                raise BagError(
                    f"topic {key!r} holds {conns[0].msgtype}, not {' or '.join(types)}",
                    path=self.path,
                )
            return conns
        cands = sorted(t for t, cs in by_topic.items() if cs[0].msgtype in types)
        if len(cands) == 1:
            return by_topic[cands[0]]
        if not cands:
            return None
        raise BagError(
            f"{len(cands)} {what} topics ({', '.join(cands)}): choose one with "
            f"{what}_topic= (on the command line: --{what}-topic)",
            path=self.path,
        )

    # ------------------------------------------------------------------ reading
    def _read_raw_scans(self, reader: Any, conns: Sequence[Any]) -> Iterator[_RawScan]:
        start = reader.start_time * _NS
        angle_cache: dict[tuple[int, float, float], FloatArray] = {}
        for index, (conn, ts, raw) in enumerate(_messages(reader, self.path, conns), start=1):
            multi = conn.msgtype.endswith("MultiEchoLaserScan")
            try:
                if multi and not reader.is2:
                    stamp, frame, geo, r = _ros1_multiecho(raw, self.echo)
                else:
                    msg = _deserialize(reader, self.path, conn, raw)
                    stamp, frame = _stamp(msg), str(msg.header.frame_id)
                    geo = (
                        msg.angle_min,
                        msg.angle_max,
                        msg.angle_increment,
                        msg.range_min,
                        msg.range_max,
                    )
                    if multi:
                        r = np.array(
                            [
                                e.echoes[self.echo] if len(e.echoes) > self.echo else np.nan
                                for e in msg.ranges
                            ],
                            dtype=np.float64,
                        )
                    else:
                        r = np.asarray(msg.ranges, dtype=np.float64)
            except struct.error as exc:
                raise BagError(
                    f"truncated {conn.msgtype} message {index} on topic {conn.topic!r} ({exc})",
                    path=self.path,
                ) from None
            amin, _, ainc, rmin, rmax = (float(v) for v in geo)
            if not (math.isfinite(amin) and math.isfinite(ainc) and rmax > 0):
                raise BagError(
                    f"scan {index} on topic {conn.topic!r} has a bad geometry "
                    f"(angle_min={amin}, angle_increment={ainc}, range_max={rmax})",
                    path=self.path,
                )
            key = (len(r), amin, ainc)
            a = angle_cache.get(key)
            if a is None:
                a = amin + ainc * np.arange(len(r), dtype=np.float64)
                a.flags.writeable = False
                angle_cache[key] = a
            cleaned, report = _validated_ranges(r, rmin, rmax)
            yield _RawScan(
                stamp,
                ts * _NS - start,
                self.laser_frame or frame.lstrip("/"),
                a,
                cleaned,
                rmax,
                conn.msgtype.rsplit("/", 1)[-1],
                index,
                report,
            )

    def _odometry(self, reader: Any, conns: Sequence[Any]) -> Iterator[tuple[Odometry, str, str]]:
        for index, (conn, _, raw) in enumerate(_messages(reader, self.path, conns), start=1):
            m = _deserialize(reader, self.path, conn, raw)
            p, q = m.pose.pose.position, m.pose.pose.orientation
            pose = np.array((p.x, p.y, yaw_from_quaternion(q.x, q.y, q.z, q.w)))
            tw = m.twist.twist
            t = _stamp(m)
            rec = Odometry(t, pose, float(tw.linear.x), float(tw.angular.z), t, index)
            yield rec, str(m.header.frame_id).lstrip("/"), str(m.child_frame_id).lstrip("/")

    def _tf(self, reader: Any, odom_conns: Sequence[Any] | None) -> tuple[TfBuffer, str | None]:
        """The transform tree of the bag (tf, tf_static and odometry links) and the odometry's
        ``(frame_id)`` if any."""
        tf = TfBuffer()
        tf_conns = [c for c in reader.connections if c.msgtype in TF_TYPES]
        for conn, _, raw in _messages(reader, self.path, tf_conns):
            try:
                _add_tf(
                    tf, _deserialize(reader, self.path, conn, raw), "static" in conn.topic, "tf"
                )
            except ValueError as exc:
                raise BagError(f"topic {conn.topic!r}: {exc}", path=self.path) from None
        odom_frame: str | None = None
        if odom_conns:
            explicit = self.odom_topic is not None
            links: list[tuple[Odometry, str, str]] = list(self._odometry(reader, odom_conns))
            if links:
                odom_frame, child = links[0][1], links[0][2]
                self._base = child
                if explicit:
                    tf.replace_parent(child, "odom")
                if explicit or tf.parent(child) is None:
                    for rec, parent, ch in links:
                        try:
                            tf.add(parent, ch, rec.time, rec.pose, source="odom")
                        except ValueError as exc:
                            raise BagError(
                                f"topic {odom_conns[0].topic!r}: {exc}", path=self.path
                            ) from None
        return tf, odom_frame

    def _scan_connections(self, reader: Any) -> Any:
        """Connections of the scan topic, or :class:`BagError` when the bag has none."""
        conns = self._pick(reader, self.scan_topic, SCAN_TYPES, "scan")
        if conns is None:
            raise BagError(
                "no sensor_msgs/LaserScan or MultiEchoLaserScan topic in the bag", path=self.path
            )
        return conns

    def _sources(self, reader: Any) -> tuple[Any, TfBuffer, str | None]:
        """A fresh read's scan connections, transform tree and odometry frame (resets the
        odometry's base frame and the count of scans outside tf)."""
        self._base = None
        self.scans_outside_tf = 0
        scan_conns = self._scan_connections(reader)
        odom_conns = self._pick(reader, self.odom_topic, (ODOM_TYPE,), "odom")
        tf, odom_frame = self._tf(reader, odom_conns)
        return scan_conns, tf, odom_frame

    def _frames(self, tf: TfBuffer, odom_frame: str | None, laser: str) -> tuple[str, str]:
        """``(fixed, base)`` frames of scans in frame ``laser``: in the laser's own frame the
        robot is the laser."""
        fixed = self._resolve_fixed(tf, odom_frame, laser)
        return fixed, (laser if fixed == laser else self._base_frame(tf, laser))

    def _resolve_fixed(self, tf: TfBuffer, odom_frame: str | None, laser: str) -> str:
        if self.fixed_frame is not None:
            return self.fixed_frame
        if odom_frame is not None:
            return odom_frame
        chain = [laser]
        while (p := tf.parent(chain[-1])) is not None:
            chain.append(p)
        for name in ("map", "odom"):
            if name in chain:
                return name
        if len(chain) == 1:
            raise BagError(
                f"the bag has no tf link and no nav_msgs/Odometry into the laser frame "
                f"{laser!r}: cannot place the scans (fixed_frame={laser!r}, or probmap map "
                f"--fixed-frame {laser}, reads them in the laser's own frame)",
                path=self.path,
            )
        return chain[-1]

    def _base_frame(self, tf: TfBuffer, laser: str) -> str:
        base = getattr(self, "_base", None)
        if base:
            return str(base)
        for name in ("base_link", "base_footprint"):
            if name in tf.frames:
                return name
        return laser

    def _scan_chunks(
        self, chunk: int = 512
    ) -> Iterator[tuple[list[_RawScan], FloatArray, FloatArray]]:
        """Scans with their laser and robot poses, ``chunk`` at a time (one tf lookup each)."""
        with _open_reader(self.path) as reader:
            scan_conns, tf, odom_frame = self._sources(reader)
            topic = scan_conns[0].topic
            buf: list[_RawScan] = []
            fixed = base = laser = ""
            for raw in self._read_raw_scans(reader, scan_conns):
                if not fixed:
                    laser = raw.frame
                    fixed, base = self._frames(tf, odom_frame, laser)
                buf.append(raw)
                if len(buf) >= chunk:
                    yield self._posed(tf, fixed, base, buf, topic)
                    buf = []
            if buf:
                yield self._posed(tf, fixed, base, buf, topic)
            if fixed:
                self.resolved_frames = (fixed, base, laser)
            if self.scans_outside_tf:
                warnings.warn(
                    f"{self.path}: dropped {self.scans_outside_tf} scan(s) stamped before the "
                    "first or after the last transform of their frame (tf is not extrapolated)",
                    UserWarning,
                    stacklevel=3,
                )

    def _posed(
        self, tf: TfBuffer, fixed: str, base: str, scans: list[_RawScan], topic: str
    ) -> tuple[list[_RawScan], FloatArray, FloatArray]:
        """:meth:`_poses` of a chunk; scans stamped outside the tf buffer at either end of the
        bag (a scan after the last odometry message, say) are dropped and counted."""
        try:
            return (scans, *self._poses(tf, fixed, base, scans, topic))
        except BagError:
            kept, laser, robot = [], [], []
            for raw in scans:
                try:
                    lp, rp = self._poses(tf, fixed, base, [raw], topic)
                except BagError:
                    continue
                kept.append(raw)
                laser.append(lp)
                robot.append(rp)
            dropped = len(scans) - len(kept)
            first, last = self._tf_span(tf, fixed, base)
            kept_ids = {id(r) for r in kept}
            inside = [r for r in scans if first <= r.time <= last and id(r) not in kept_ids]
            if not kept or inside:
                raise  # not an edge-of-bag gap: report the first failure as it is
            self.scans_outside_tf += dropped
            return kept, np.concatenate(laser), np.concatenate(robot)

    @staticmethod
    def _tf_span(tf: TfBuffer, fixed: str, base: str) -> tuple[float, float]:
        """Times covered by every moving link between ``fixed`` and ``base``."""
        lo, hi = -math.inf, math.inf
        for frame in (fixed, base):
            try:
                a, b = tf.time_range(frame)
            except (KeyError, ValueError):
                continue
            lo, hi = max(lo, a), min(hi, b)
        return lo, hi

    def _poses(
        self, tf: TfBuffer, fixed: str, base: str, scans: list[_RawScan], topic: str
    ) -> tuple[FloatArray, FloatArray]:
        times = np.array([s.time for s in scans])
        laser = np.empty((len(scans), 3))
        frames = [s.frame for s in scans]
        try:
            for frame in sorted(set(frames)):
                sel = np.array([f == frame for f in frames])
                laser[sel] = tf.lookup(fixed, frame, times[sel])
            robot = tf.lookup(fixed, base, times)
        except ValueError as exc:
            raise BagError(f"scans on topic {topic!r}: {exc}", path=self.path) from None
        return laser, robot

    # ------------------------------------------------------------------ protocol
    def __iter__(self) -> Iterator[LaserScan]:
        for scans, laser, robot in self._scan_chunks():
            for s, lp, rp in zip(scans, laser, robot, strict=True):
                yield LaserScan(
                    time=s.time,
                    ranges=s.ranges,
                    angles=s.angles,
                    laser_pose=lp,
                    robot_pose=rp,
                    max_range=s.max_range,
                    logger_time=s.log_time,
                    source=s.source,
                    line=s.index,
                )

    def __len__(self) -> int:
        """Messages on the scan topic (from the bag's index; nothing is decoded)."""
        if self._count is None:
            with _open_reader(self.path) as reader:
                self._count = sum(int(c.msgcount) for c in self._scan_connections(reader))
        return self._count

    def odometry(self) -> Iterator[Odometry]:
        """The odometry topic's messages as :class:`~probmap.datasets.records.Odometry`.

        ``pose`` is in the message's ``header.frame_id``; ``tv``/``rv`` are the twist's
        ``linear.x`` and ``angular.z``; ``line`` the 1-based message index.
        """
        with _open_reader(self.path) as reader:
            conns = self._pick(reader, self.odom_topic, (ODOM_TYPE,), "odom")
            if conns is None:
                raise BagError("no nav_msgs/Odometry topic in the bag", path=self.path)
            for rec, _, _ in self._odometry(reader, conns):
                yield rec

    def resolve_frames(self) -> tuple[str, str, str]:
        """``(fixed, base, laser)``: the frames a read would use, from tf, the odometry and the
        first scan (no scan is posed). Also stored in :attr:`resolved_frames`.

        Raises
        ------
        BagError
            As iteration: no scan topic, no pose source, an empty scan topic.
        """
        with _open_reader(self.path) as reader:
            scan_conns, tf, odom_frame = self._sources(reader)
            first = next(self._read_raw_scans(reader, scan_conns), None)
            if first is None:
                raise BagError(f"topic {scan_conns[0].topic!r} holds no message", path=self.path)
            fixed, base = self._frames(tf, odom_frame, first.frame)
        self.resolved_frames = (fixed, base, first.frame)
        return self.resolved_frames

    def tf_buffer(self) -> TfBuffer:
        """The bag's transform tree: tf, tf_static and the odometry topic's links."""
        self._base = None
        with _open_reader(self.path) as reader:
            odom_conns = self._pick(reader, self.odom_topic, (ODOM_TYPE,), "odom")
            return self._tf(reader, odom_conns)[0]

    def batch(
        self,
        dtype: type[np.floating] = np.float64,
        *,
        pose_limits: PoseLimits | None = None,
        skip_bad_lines: bool = False,
    ) -> ScanBatch:
        """Every scan stacked into a :class:`~probmap.datasets.records.ScanBatch`.

        A scan whose laser or robot pose is beyond ``pose_limits`` (default
        :class:`~probmap.datasets.validate.PoseLimits`: a coordinate beyond 100 km, a jump of
        more than 10 m + 20 m/s from the previous scan) is a :class:`BagError` naming its
        message, or, with ``skip_bad_lines``, dropped and counted in ``skipped_lines`` (with a
        :class:`~probmap.errors.BadLinesWarning`).
        """
        times: list[FloatArray] = []
        rows: list[FloatArray] = []
        angle_rows: list[FloatArray] = []
        laser: list[FloatArray] = []
        robot: list[FloatArray] = []
        max_ranges: list[float] = []
        report = ReadingReport()
        tracker = PoseTracker(pose_limits)
        skipped = 0
        first_error = ""
        for scans, lp, rp in self._scan_chunks():
            keep = np.ones(len(scans), dtype=bool)
            for k, s in enumerate(scans):
                bad = _implausible(tracker, s, lp[k], rp[k])
                if bad is not None:
                    if not skip_bad_lines:
                        raise BagError(bad, path=self.path)
                    keep[k] = False
                    skipped += 1
                    first_error = first_error or bad
                    continue
                if s.report is not None:
                    report = report + s.report
            if not keep.all():
                scans = [s for s, ok in zip(scans, keep, strict=True) if ok]
                lp, rp = lp[keep], rp[keep]
            times.append(np.array([s.time for s in scans]))
            rows += [s.ranges for s in scans]
            angle_rows += [s.angles for s in scans]
            max_ranges += [s.max_range for s in scans]
            laser.append(lp)
            robot.append(rp)
        if skipped:
            warnings.warn(
                f"{self.path}: skipped {skipped} scan(s) with implausible poses; first: "
                f"{first_error}",
                BadLinesWarning,
                stacklevel=2,
            )
        report = replace(report, skipped_lines=skipped)
        if not rows:
            raise BagError("the scan topic holds no messages", path=self.path)
        ranges, angles, beams = stack_beams(rows, angle_rows, dtype)
        return ScanBatch(
            times=np.concatenate(times),
            ranges=ranges,
            angles=angles,
            laser_poses=np.concatenate(laser),
            robot_poses=np.concatenate(robot),
            max_range=float(min(max_ranges)),
            beams=beams,
            skipped_lines=skipped,
            readings=report,
        )


def _implausible(
    tracker: PoseTracker, scan: _RawScan, laser: FloatArray, robot: FloatArray
) -> str | None:
    """Why a scan's poses are implausible (None when they pass; the tracker then records them)."""
    t = scan.time
    poses = {"laser": tuple(float(v) for v in laser), "robot": tuple(float(v) for v in robot)}
    for name, (x, y, th) in poses.items():
        bad = tracker.check(f"{name} pose", t, x, y, th)
        if bad is not None:
            field = ("x", "y", "theta")[bad[0]]
            return f"scan message {scan.index}: implausible {name} pose {field}: {bad[1]}"
    for name, (x, y, th) in poses.items():
        tracker.accept(f"{name} pose", t, x, y, th)
    return None


def load_bag_scans(
    path: str | os.PathLike[str],
    *,
    dtype: type[np.floating] = np.float64,
    pose_limits: PoseLimits | None = None,
    skip_bad_lines: bool = False,
    **bag_options: Unpack[RosBagOptions],
) -> ScanBatch:
    """Read every scan of a bag into stacked arrays, posed through tf (the bag twin of
    :func:`probmap.datasets.carmen.load_scans`).

    Parameters
    ----------
    path, scan_topic, odom_topic, fixed_frame, laser_frame, echo
        As for :class:`RosBag`.
    dtype : numpy floating type
        dtype of ``ranges``.
    pose_limits, skip_bad_lines
        As for :meth:`RosBag.batch`: a scan with an implausible pose is an error, or dropped
        and counted.

    Returns
    -------
    ScanBatch
        ``laser_poses`` (S, 3): the laser frame in the fixed frame at each scan's time;
        ``ranges`` (S, B) with NaN for readings below ``range_min`` and ``range_max`` for no
        return; ``max_range`` the smallest ``range_max``.

    Raises
    ------
    BagError
        As :class:`RosBag`.
    """
    bag = RosBag(path, **bag_options)
    return bag.batch(dtype, pose_limits=pose_limits, skip_bad_lines=skip_bad_lines)


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
