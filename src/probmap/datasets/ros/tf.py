"""The transform tree of a bag: ``tf`` and ``tf_static`` projected onto the plane.

Frames are projected onto the plane: a transform keeps its ``(x, y)`` translation and its yaw
about +z, which is exact for a robot moving on a level floor with a level laser.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from probmap._typing import FloatArray
from probmap.datasets.ros._reader import _stamp
from probmap.geometry.se2 import compose, inverse, wrap_angle

__all__ = ["TfBuffer", "yaw_from_quaternion"]


TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")


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
        """First and last time (s) at which the chain from ``frame`` to its root is known.

        Raises
        ------
        ValueError
            When the chain runs into a cycle (a bag can link a frame back to itself).
        """
        lo, hi = -math.inf, math.inf
        for f in self._chain(frame.lstrip("/"))[:-1]:
            e = self._edges[f]
            if not e.static:
                t, _ = e.arrays()
                lo, hi = max(lo, float(t[0])), min(hi, float(t[-1]))
        return lo, hi

    def ancestors(self, frame: str) -> list[str]:
        """``frame`` and its parents up to its root (first ``frame``).

        Raises
        ------
        ValueError
            When the chain runs into a cycle.
        """
        return self._chain(frame.lstrip("/"))

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


# ---------------------------------------------------------------------------- tf messages


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
