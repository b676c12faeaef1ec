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
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
from numpy.typing import NDArray

from probmap._typing import FloatArray
from probmap.datasets.records import LaserScan, Odometry, ScanBatch, stack_beams
from probmap.datasets.ros._reader import (
    _NS,
    _deserialize,
    _messages,
    _open_reader,
    _stamp,
    require_rosbags,
)
from probmap.datasets.ros.tf import TF_TYPES, TfBuffer, _add_tf, yaw_from_quaternion
from probmap.datasets.validate import PoseLimits, PoseTracker, ReadingReport, validate_ranges
from probmap.errors import BadLinesWarning, BagError, NoPoseSourceError

if TYPE_CHECKING:
    from typing_extensions import Unpack

__all__ = [
    "RosBag",
    "RosBagOptions",
    "is_bag",
    "load_bag_scans",
]


SCAN_TYPES = ("sensor_msgs/msg/LaserScan", "sensor_msgs/msg/MultiEchoLaserScan")
ODOM_TYPE = "nav_msgs/msg/Odometry"


def is_bag(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` looks like a ROS bag: a ``.bag`` file, a ROS 2 bag folder (with
    ``metadata.yaml``) or a ``.db3``/``.mcap`` storage file. Nothing is opened."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.suffix in (".bag", ".db3", ".mcap")


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
    seq: int | None = None  # the ROS 1 header's sequence number (ROS 2 has none)


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
            seq: int | None = None
            try:
                if multi and not reader.is2:
                    stamp, frame, geo, r = _ros1_multiecho(raw, self.echo)
                    seq = struct.unpack_from("<I", raw, 0)[0]
                else:
                    msg = _deserialize(reader, self.path, conn, raw)
                    stamp, frame = _stamp(msg), str(msg.header.frame_id)
                    if not reader.is2:
                        seq = int(msg.header.seq)
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
                seq,
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
        try:
            chain = tf.ancestors(laser)
        except ValueError as exc:  # a cycle
            raise BagError(str(exc), path=self.path) from None
        for name in ("map", "odom"):
            if name in chain:
                return name
        if len(chain) == 1:
            raise NoPoseSourceError(
                f"the bag has no tf link and no nav_msgs/Odometry into the laser frame "
                f"{laser!r}: cannot place the scans (fixed_frame={laser!r}, or probmap map "
                f"--fixed-frame {laser}, reads them in the laser's own frame)",
                path=self.path,
                laser_frame=laser,
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
        seqs: list[int | None] = []
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
            seqs += [s.seq for s in scans]
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
            pose_source=self._pose_source(),
            published=publication_keys(seqs),
        )

    def _pose_source(self) -> str:
        """What placed the scans of the last read (:attr:`ScanBatch.pose_source`): ``"laser"``
        in the laser's own frame, ``"corrected"`` in a ``map`` frame (a SLAM system's), else
        ``"odometry"`` (odom, or the odometry topic's frame)."""
        frames = getattr(self, "resolved_frames", None)
        if not frames:
            return ""
        fixed, _, laser = frames
        if fixed == laser:
            return "laser"
        return "corrected" if fixed == "map" else "odometry"


def publication_keys(seqs: Sequence[int | None]) -> NDArray[np.int64] | None:
    """Keys that sort scans into the order their driver published them
    (:attr:`~probmap.datasets.records.ScanBatch.published`), from the ROS 1 header sequence
    numbers in the bag's order; None when a scan has none or all are equal (a converter that
    wrote zeros).

    A number more than 100 below the largest so far is taken for a driver that started
    again: it and those after it count on from that largest number, so that the scans of one
    run of the driver stay before those of the next, as the bag holds them. (A scan stamped
    so late that more than 100 later ones precede it stays where the bag has it.)
    """
    if not seqs or any(q is None for q in seqs):
        return None
    raw = np.asarray(seqs, dtype=np.int64)
    if (raw == raw[0]).all():
        return None
    keys = np.empty_like(raw)
    offset = 0
    top = -1
    for i, q in enumerate(raw):
        if top >= 0 and q < top - offset - 100:
            offset = top + 1  # a restart: count on
        keys[i] = q + offset
        top = max(top, int(keys[i]))
    return keys


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
    path
        As for :class:`RosBag`.
    **bag_options
        ``scan_topic``, ``odom_topic``, ``fixed_frame``, ``laser_frame``, ``echo``: as for
        :class:`RosBag`.
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
