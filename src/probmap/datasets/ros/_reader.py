"""What the parts of :mod:`probmap.datasets.ros` share: the lazy ``rosbags`` import (its error
names the ``ros`` extra), opening a ROS 1 or ROS 2 bag, and reading and decoding its messages with
errors that name the file and topic. ``rosbags`` is imported only when a bag is opened.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from probmap.errors import BagError, MissingExtraError

__all__ = ["require_rosbags"]


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


def _cause(exc: BaseException, limit: int = 160) -> str:
    """What ``rosbags`` (or the decoder) said, on one line: its message with every run of
    whitespace one space (a bad message definition comes back quoted, over many lines), cut
    to ``limit`` characters, or the exception's class name when it said nothing."""
    msg = " ".join(str(exc).split()) or type(exc).__name__
    return msg if len(msg) <= limit else msg[: limit - 3] + "..."


# ---------------------------------------------------------------------------- opening bags


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
        # a MemoryError among them: a corrupt size field asks to read exabytes
        raise BagError(f"corrupt or truncated bag ({_cause(exc)})", path=path) from None
    try:
        _check_index(reader, path)
        yield reader
    finally:
        reader.close()


def _check_index(reader: Any, path: Path) -> None:
    """Refuse an index that ``rosbags`` opened but probmap cannot use: a ROS 2 ``metadata.yaml``
    can give a topic as a list, or a count or start time as text."""
    for c in reader.connections:
        if not (isinstance(c.topic, str) and isinstance(c.msgtype, str)):
            raise BagError(
                f"corrupt bag index: a topic {c.topic!r} of type {c.msgtype!r} (not names)",
                path=path,
            )
        if not isinstance(c.msgcount, int) or isinstance(c.msgcount, bool):
            raise BagError(
                f"corrupt bag index: topic {c.topic!r} has message count {c.msgcount!r}",
                path=path,
            )
    try:
        start = reader.start_time
    except Exception as exc:
        raise BagError(f"corrupt bag index: no start time ({_cause(exc)})", path=path) from None
    if not isinstance(start, int) or isinstance(start, bool):
        raise BagError(f"corrupt bag index: start time {start!r}", path=path)


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
                f"corrupt or truncated bag while reading topic {topic!r} ({_cause(exc)})", path=path
            ) from None
        topic = conn.topic
        yield conn, ts, raw


def _deserialize(reader: Any, path: Path, conn: Any, raw: Any) -> Any:
    try:
        return reader.deserialize(raw, conn.msgtype)
    except Exception as exc:
        raise BagError(
            f"cannot decode a {conn.msgtype} message on topic {conn.topic!r} ({_cause(exc)})",
            path=path,
        ) from None


def _stamp(msg: Any) -> float:
    s = msg.header.stamp
    return float(s.sec) + float(s.nanosec) * _NS
