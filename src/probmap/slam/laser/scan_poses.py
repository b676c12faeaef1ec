"""Every scan's pose from graph SLAM's optimized nodes: the scans between two nodes share the
correction the optimization made to the second (:func:`spread_between_nodes`, used by
:meth:`probmap.slam.laser.submap_slam.SubmapSlam.trajectory`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap.geometry.se2 import between, compose, wrap_angle

__all__ = ["spread_between_nodes"]


def spread_between_nodes(
    node_poses: ArrayLike,
    node_local: ArrayLike,
    node_scan: ArrayLike,
    scan_node: ArrayLike,
    scan_offset: ArrayLike,
    times: ArrayLike,
) -> NDArray[np.float64]:
    """Pose of every scan from the optimized nodes and each scan's offset from its node.

    Scan ``i`` of node ``k = scan_node[i]`` is first placed at ``P_k (+) o_i`` (``P`` the
    optimized node poses, ``o_i`` its pose relative to node ``k`` in the local-SLAM frame).
    The optimization moved node ``k + 1`` by ``D = P_{k+1} - P_k (+) (L_k^-1 (+) L_{k+1})``
    (map frame, heading wrapped) from where that chain puts it; the scans from node ``k`` to
    node ``k + 1`` receive the fraction of ``D`` that their local-SLAM travel from node ``k``
    is of the whole (translation by path length, heading by the summed turn; by time where
    that part did not move), so the trajectory is continuous at every node. Scans after the
    last node keep ``P_k (+) o_i``.

    Parameters
    ----------
    node_poses : array_like, shape (N, 3)
        Optimized node poses ``P``, map frame (metres, radians).
    node_local : array_like, shape (N, 3)
        The nodes' local-SLAM poses ``L`` (the drifting frame the offsets are in).
    node_scan : array_like, shape (N,)
        Scan index of each node, increasing.
    scan_node : array_like, shape (S,)
        Node of each scan: the last node at or before it.
    scan_offset : array_like, shape (S, 3)
        Each scan's pose relative to its node's local pose (zero for the node itself).
    times : array_like, shape (S,)
        Scan timestamps, seconds.

    Returns
    -------
    ndarray, shape (S, 3)
        Scan poses, map frame; node scans exactly at ``node_poses``.
    """
    P = np.asarray(node_poses, dtype=np.float64).reshape(-1, 3)
    L = np.asarray(node_local, dtype=np.float64).reshape(-1, 3)
    ns = np.asarray(node_scan, dtype=np.int64)
    sn = np.asarray(scan_node, dtype=np.int64)
    off = np.asarray(scan_offset, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(times, dtype=np.float64)
    if sn.size == 0:
        return np.zeros((0, 3))
    out = compose(P[sn], off)
    nxt = np.minimum(sn + 1, P.shape[0] - 1)
    inner = nxt > sn  # scans with a next node
    if not inner.any():
        out[:, 2] = wrap_angle(out[:, 2])
        return out
    predicted = compose(P[sn], between(L[sn], L[nxt]))
    d = P[nxt] - predicted
    d[:, 2] = wrap_angle(d[:, 2])
    a, b = ns[sn], ns[nxt]
    with np.errstate(invalid="ignore", divide="ignore"):
        by_time = np.clip(np.where(t[b] > t[a], (t - t[a]) / (t[b] - t[a]), 0.0), 0.0, 1.0)
    local = compose(L[sn], off)  # every scan's local-SLAM pose
    step = np.diff(local, axis=0)
    cum_xy = np.concatenate([[0.0], np.cumsum(np.hypot(step[:, 0], step[:, 1]))])
    cum_th = np.concatenate([[0.0], np.cumsum(np.abs(wrap_angle(step[:, 2])))])

    def fraction(cum: NDArray[np.float64]) -> NDArray[np.float64]:
        whole = cum[b] - cum[a]
        moved = whole > 1e-9
        with np.errstate(invalid="ignore", divide="ignore"):
            f = np.where(moved, (cum - cum[a]) / np.where(moved, whole, 1.0), by_time)
        return np.clip(f, 0.0, 1.0)

    f_xy = np.where(inner, fraction(cum_xy), 0.0)
    f_th = np.where(inner, fraction(cum_th), 0.0)
    out[:, :2] += f_xy[:, None] * d[:, :2]
    out[:, 2] = wrap_angle(out[:, 2] + f_th * d[:, 2])
    return out
