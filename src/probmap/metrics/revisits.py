"""Revisits that no loop closure joined: where a corridor driven twice may be drawn twice.

When a robot drives through a place it has mapped before, graph SLAM should find loop closures
there that tie the new pass to the old one. Where it finds none, the second pass is placed by
local SLAM alone, and any drift since the first pass stays in the map: the two passes draw the
same walls a little apart, parallel and each straight, which neither looks wrong nor makes the
two passes see each other's walls in open space when the offset runs along the walls (the
Freiburg hospital's last 140 s retrace its corridor of 165-272 s 0.66 m along it, with no
closure between the passes). This test needs no ground truth, only the trajectory of the
pose-graph nodes and the closures that were kept:

1. a node *revisits* when an earlier node, at least ``gap`` metres of travel before it, lies
   within ``radius`` metres of it in the map;
2. the travel is cut into pieces of ``piece`` metres; a piece is a *revisit* when at least
   half its nodes revisit;
3. a revisit piece is *joined* when a closure links a node within ``margin`` metres of travel
   of it to a place at least ``gap`` metres of travel earlier;
4. consecutive revisit pieces that are not joined form a *span*; spans of at least
   ``min_length`` metres are reported.

The defaults were measured on graph SLAM's whole-log results (radius 2 m; pieces of 5 m; spans
of 10 m): Intel 63 revisit pieces, none unjoined; the Intel bag 70, none; Freiburg 079 35,
one unjoined piece of 4.7 m (not reported); the hospital 15, ten unjoined, one span of 41 m at
4,679-4,820 s over its passes of 0-273 s. A pass drawn more than ``radius`` from the first is
not seen as a revisit at all; a fold is the consistency check's part
(:mod:`probmap.metrics.consistency`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["PIECE", "Revisits", "UnjoinedSpan", "unjoined_revisits"]

#: Travel per piece of :func:`unjoined_revisits`, metres.
PIECE = 5.0


@dataclass(frozen=True)
class UnjoinedSpan:
    """Nodes ``first .. last`` (inclusive), times ``start .. end`` (seconds), ``length`` metres
    of travel, revisit places first passed at ``earlier_start .. earlier_end`` (seconds), and
    no closure joins them; ``box`` bounds the span's nodes, ``(x_min, y_min, x_max, y_max)``
    in metres, map frame."""

    first: int
    last: int
    start: float
    end: float
    length: float
    earlier_start: float
    earlier_end: float
    box: tuple[float, float, float, float]


@dataclass(frozen=True)
class Revisits:
    """``pieces`` of travel that revisit a place, ``unjoined`` of them with no closure, and the
    ``spans`` of at least the least length among those (longest first)."""

    pieces: int
    unjoined: int
    spans: tuple[UnjoinedSpan, ...]


def unjoined_revisits(
    times: ArrayLike,
    poses: ArrayLike,
    links: ArrayLike,
    *,
    radius: float = 2.0,
    gap: float = 30.0,
    piece: float = PIECE,
    margin: float = 5.0,
    min_length: float = 10.0,
) -> Revisits:
    """Stretches of a trajectory that pass a mapped place again with no loop closure to it
    (module docstring).

    Parameters
    ----------
    times : array_like, shape (N,)
        Times of the pose-graph nodes, seconds (in node order).
    poses : array_like, shape (N, 3)
        Optimized poses of the nodes, map frame (metres, radians).
    links : array_like, shape (C, 2), int
        The kept loop closures as node pairs ``(node, earlier node)``: the node whose scan
        was matched and a node of the place it was matched to (for a submap closure, the
        submap's last node).
    radius : float
        Distance in the map within which an earlier node makes a revisit, metres.
    gap : float
        Least travel between a node and an earlier node for a revisit or a closure to count,
        metres (less is the same pass, which local SLAM holds together).
    piece : float
        Travel per piece, metres.
    margin : float
        Travel within which a closure's node joins a piece, metres.
    min_length : float
        Least travel of a reported span, metres.

    Returns
    -------
    Revisits
    """
    t = np.asarray(times, dtype=np.float64)
    p = np.asarray(poses, dtype=np.float64)
    ln = np.asarray(links, dtype=np.int64).reshape(-1, 2)
    n = len(t)
    if p.shape != (n, 3):
        raise ValueError(f"times (N,) and poses (N, 3) must agree, got {t.shape} and {p.shape}")
    if len(ln) and (ln.min() < 0 or ln.max() >= n):
        raise ValueError(f"links must hold node indices in [0, {n}), got {ln.min()}..{ln.max()}")
    for name, v in (("radius", radius), ("piece", piece), ("gap", gap)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be > 0 m, got {v}")
    if n == 0:
        return Revisits(0, 0, ())
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p[:, :2], axis=0).T))])
    # each node's earliest and latest node within the radius and at least the gap behind (the
    # travel grows with the index, so those are the nodes up to one index): blocks of rows of
    # the distance matrix, small enough for any log
    earliest = np.full(n, -1, dtype=np.int64)
    latest = np.full(n, -1, dtype=np.int64)
    upto = np.searchsorted(travel, travel - gap, side="right")  # nodes [0, upto) are behind
    xy = p[:, :2]
    rows = max(1, 250_000 // n)
    for b0 in range(0, n, rows):
        b1 = min(b0 + rows, n)
        m = int(upto[b1 - 1])
        if m == 0:
            continue
        d2 = (xy[b0:b1, None, 0] - xy[None, :m, 0]) ** 2 + (
            xy[b0:b1, None, 1] - xy[None, :m, 1]
        ) ** 2
        near = (d2 <= radius * radius) & (np.arange(m)[None, :] < upto[b0:b1, None])
        has = near.any(axis=1)
        earliest[b0:b1][has] = near[has].argmax(axis=1)
        latest[b0:b1][has] = m - 1 - near[has, ::-1].argmax(axis=1)
    revisit = earliest >= 0
    far = travel[ln[:, 0]] - travel[ln[:, 1]] >= gap if len(ln) else np.zeros(0, bool)
    joins = np.sort(travel[ln[far, 0]])  # travel at the nodes of the closures that count
    which = np.floor(travel / piece).astype(np.int64)
    starts = np.flatnonzero(np.r_[True, which[1:] != which[:-1]])
    ends = np.r_[starts[1:], n]
    pieces = 0
    loose: list[tuple[int, int]] = []  # node ranges [a, b) of unjoined revisit pieces
    for a, b in zip(starts.tolist(), ends.tolist(), strict=True):
        if revisit[a:b].mean() < 0.5:
            continue
        pieces += 1
        lo, hi = travel[a] - margin, travel[b - 1] + margin
        if np.searchsorted(joins, hi, side="right") - np.searchsorted(joins, lo) == 0:
            loose.append((a, b))
    merged: list[list[int]] = []
    for a, b in loose:
        if merged and a == merged[-1][1]:
            merged[-1][1] = b
        else:
            merged.append([a, b])
    spans = []
    for a, b in merged:
        length = float(travel[b - 1] - travel[a])
        if length < min_length:
            continue
        had = revisit[a:b]
        e0 = int(earliest[a:b][had].min())
        e1 = int(latest[a:b][had].max())
        xy = p[a:b, :2]
        box = (float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()),
               float(xy[:, 1].max()))  # fmt: skip
        spans.append(
            UnjoinedSpan(
                a, b - 1, float(t[a]), float(t[b - 1]), length, float(t[e0]), float(t[e1]), box
            )  # fmt: skip
        )
    spans.sort(key=lambda s: -s.length)
    return Revisits(pieces, len(loose), tuple(spans))
