"""What a bag holds (what ``probmap info BAG`` prints): topics, message types and counts, frames,
times and the tf links (:func:`summarize_bag`)."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from probmap.datasets.ros._reader import _NS, _deserialize, _messages, _open_reader
from probmap.datasets.ros.tf import TF_TYPES, TfBuffer, _add_tf

__all__ = ["BagSummary", "TopicSummary", "summarize_bag"]


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
