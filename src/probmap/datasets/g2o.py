"""Read and write 2-D pose(-landmark) graphs: the g2o and TORO text formats.

Supported records (one per line, whitespace separated; the tag tells the format, so g2o and
TORO files are recognised by their content, not their name)::

    VERTEX_SE2 id x y theta                                   (g2o)
    VERTEX_XY id x y                                          (g2o)
    EDGE_SE2 i j dx dy dtheta I11 I12 I13 I22 I23 I33         (g2o)
    EDGE_SE2_XY i j dx dy I11 I12 I22                         (g2o)
    FIX id                                                    (g2o)
    VERTEX2 id x y theta                                      (TORO)
    EDGE2 i j dx dy dtheta I11 I12 I22 I33 I13 I23            (TORO)
    EQUIV i j                                                 (TORO)

Edge measurements are expressed in the frame of vertex ``i`` (``EDGE_SE2``/``EDGE2``:
``x_i^-1 ⊕ x_j``; ``EDGE_SE2_XY``: the landmark position in the robot frame). Information
matrices are given by their upper triangles, row by row in g2o, in TORO's own order in TORO.
``FIX`` and ``EQUIV`` lines are kept. ``EQUIV`` pairs are not merged: like GTSAM's
``load2D``, the optimizer treats the two ids as distinct nodes (on ``w10000.graph`` that gives
GTSAM's 10 000 nodes and final error). A file without vertex lines takes its initial poses by
chaining its odometry edges (``i -> i+1`` between consecutive ids, from the first id at the
origin). Other tags raise a :class:`~probmap.datasets.protocol.DatasetError` unless
``skip_unknown=True`` (counted and warned).
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._atomic import atomic_write
from probmap._typing import FloatArray, IntArray
from probmap.datasets.validate import PoseLimits, text_lines
from probmap.errors import DatasetError
from probmap.geometry.se2 import pose_batch

__all__ = [
    "LandmarkEdge",
    "PoseEdge",
    "PoseGraph",
    "PoseGraphArrays",
    "pose_graph_arrays",
    "read_g2o",
    "read_pose_graph",
    "with_poses",
    "write_g2o",
    "write_pose_graph_g2o",
]


@dataclass(frozen=True, eq=False)
class PoseEdge:
    """``EDGE_SE2``: relative pose ``measurement (3,)`` of ``j`` in ``i``'s frame, info (3, 3)."""

    i: int
    j: int
    measurement: FloatArray
    information: FloatArray


@dataclass(frozen=True, eq=False)
class LandmarkEdge:
    """``EDGE_SE2_XY``: landmark ``j`` at ``measurement (2,)`` in pose ``i``'s frame, info (2, 2)."""

    i: int
    j: int
    measurement: FloatArray
    information: FloatArray


@dataclass(eq=False)
class PoseGraph:
    """A 2-D pose-landmark graph.

    Attributes
    ----------
    poses : dict[int, ndarray (3,)]
    landmarks : dict[int, ndarray (2,)]
    pose_edges : list of PoseEdge
    landmark_edges : list of LandmarkEdge
    fixed : list of int
        Ids of ``FIX`` vertices.
    equivalences : list of (int, int)
        TORO ``EQUIV`` pairs, as read (not merged).
    format : str
        ``"g2o"`` or ``"toro"``: the format of the file's pose records.
    chained : bool
        True when the file had no vertex lines and ``poses`` were chained from odometry.
    edge2_order : str or None
        The order the information of the file's ``EDGE2`` lines was read in (``"toro"`` or
        ``"g2o"``); None without ``EDGE2`` lines.
    """

    poses: dict[int, FloatArray] = field(default_factory=dict)
    landmarks: dict[int, FloatArray] = field(default_factory=dict)
    pose_edges: list[PoseEdge] = field(default_factory=list)
    landmark_edges: list[LandmarkEdge] = field(default_factory=list)
    fixed: list[int] = field(default_factory=list)
    name: str = "g2o"
    equivalences: list[tuple[int, int]] = field(default_factory=list)
    format: str = "g2o"
    chained: bool = False
    edge2_order: str | None = None


def _upper_to_full(vals: list[float], n: int) -> FloatArray:
    M = np.zeros((n, n))
    M[np.triu_indices(n)] = vals
    return M + np.triu(M, 1).T


def _toro_to_full(v: list[float]) -> FloatArray:
    """TORO's ``I11 I12 I22 I33 I13 I23`` as a symmetric 3x3 matrix."""
    return np.array([[v[0], v[1], v[4]], [v[1], v[2], v[5]], [v[4], v[5], v[3]]])


# tag -> number of fields including the tag
_COUNTS = {
    "VERTEX_SE2": 5,
    "VERTEX_XY": 4,
    "EDGE_SE2": 12,
    "EDGE_SE2_XY": 8,
    "FIX": 2,
    "VERTEX2": 5,
    "EDGE2": 12,
    "EQUIV": 3,
}
_INT_FIELDS = {"EDGE_SE2": 2, "EDGE_SE2_XY": 2, "EDGE2": 2, "EQUIV": 2}
_INT64 = (-(2**63), 2**63 - 1)
#: Value names of each record after its ids (for the errors that name one).
_FIELDS = {
    "VERTEX_SE2": ("x", "y", "theta"),
    "VERTEX2": ("x", "y", "theta"),
    "VERTEX_XY": ("x", "y"),
    "EDGE_SE2": ("dx", "dy", "dtheta"),
    "EDGE2": ("dx", "dy", "dtheta"),
    "EDGE_SE2_XY": ("dx", "dy"),
}
Edge2Order = Literal["auto", "toro", "g2o"]


def _positive_semidefinite(m: FloatArray) -> NDArray[np.bool_]:
    """Which symmetric 3x3 matrices of ``m (K, 3, 3)`` are positive semi-definite with a
    positive diagonal (the information of a pose edge), to a relative tolerance of 1e-9."""
    diag = np.diagonal(m, axis1=1, axis2=2)
    w = np.linalg.eigvalsh(m)
    return (diag > 0).all(axis=1) & (w[:, 0] >= -1e-9 * np.maximum(np.abs(w[:, -1]), 1e-300))


def _edge2_order(
    lines: list[int], values: list[list[float]], order: Edge2Order, path: Path
) -> Literal["toro", "g2o"]:
    """The information order of a file's ``EDGE2`` lines (their line numbers and six values).

    ``auto`` detects it as GTSAM's ``load2D`` does from the pattern of a diagonal matrix
    (TORO's ``I11 I12 I22 I33 I13 I23`` against g2o's ``I11 I12 I13 I22 I23 I33``), for any
    matrix: TORO's order when it makes every line's information positive semi-definite with a
    positive diagonal, else g2o's when that one does (GTSAM's ``w20000.txt`` writes ``EDGE2``
    in g2o's order); a file that neither order reads is an error naming the first line TORO's
    order fails on."""
    if order != "auto":
        return order
    v = np.asarray(values, dtype=np.float64).reshape(-1, 6)
    toro_ok = _positive_semidefinite(v[:, _TORO_INDEX].reshape(-1, 3, 3))
    if toro_ok.all():
        return "toro"
    if _positive_semidefinite(v[:, _G2O_INDEX].reshape(-1, 3, 3)).all():
        return "g2o"
    raise DatasetError(
        "EDGE2 information is not positive semi-definite in TORO's order "
        "(I11 I12 I22 I33 I13 I23), and g2o's order does not fit every EDGE2 line either",
        path=path,
        line=lines[int(np.flatnonzero(~toro_ok)[0])],
    )


#: Positions of the six values in a row-major 3x3 matrix: TORO's and g2o's orders.
_TORO_INDEX = [0, 1, 4, 1, 2, 5, 4, 5, 3]
_G2O_INDEX = [0, 1, 2, 1, 3, 4, 2, 4, 5]


def _full3(values: list[float], order: list[int]) -> FloatArray:
    """The symmetric 3x3 matrix of six values in the order ``order`` gives."""
    return np.asarray(values, dtype=np.float64)[order].reshape(3, 3)


def read_pose_graph(
    path: str | os.PathLike[str],
    *,
    skip_unknown: bool = False,
    edge2_order: Edge2Order = "auto",
    limits: PoseLimits | None = None,
) -> PoseGraph:
    """Parse a g2o or TORO file (recognised line by line by its tags) into a :class:`PoseGraph`.

    Parameters
    ----------
    path : path-like
        The graph file.
    skip_unknown : bool
        Skip (and count in a warning) lines with unknown tags instead of raising.
    edge2_order : {"auto", "toro", "g2o"}
        The order of the information values on ``EDGE2`` lines: TORO's own, g2o's (as
        GTSAM's ``w20000.txt`` writes them), or detected per file (``auto``, see
        :func:`_edge2_order`).
    limits : PoseLimits, optional
        Plausibility limits, those of laser logs by default: a vertex coordinate or an edge's
        translation beyond ``limits.max_coordinate`` is an error naming the line and field.

    Returns
    -------
    PoseGraph
        Vertex poses by id (chained from the odometry edges when the file has no vertex
        lines), edges in file order with full 3x3 (2x2) information matrices.

    Raises
    ------
    DatasetError
        Short lines, non-numeric fields, non-finite values, ids beyond int64, implausible
        poses or measurements (``limits``), duplicate vertex ids, edges that reference
        missing vertices, a vertex-less file whose odometry chain has a gap, ``EDGE2``
        information that no order reads, or (unless ``skip_unknown``) unknown tags; the
        message names the file and line.
    """
    if edge2_order not in ("auto", "toro", "g2o"):
        raise ValueError(f"edge2_order must be auto, toro or g2o, got {edge2_order!r}")
    max_coordinate = (limits if limits is not None else PoseLimits()).max_coordinate
    path = Path(path)
    g = PoseGraph(name=path.stem)
    edge2: list[list[float]] = []  # the information values of EDGE2 lines
    edge2_lines: list[int] = []  # their line numbers
    edge2_rows: list[int] = []  # their rows in g.pose_edges
    unknown = 0
    edge_lines: list[tuple[int, str, int, int]] = []
    has_vertices = False
    toro = g2o = False
    for lineno, line in text_lines(path):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        tag = parts[0]
        need = _COUNTS.get(tag)
        if need is None:
            if skip_unknown:
                unknown += 1
                continue
            raise DatasetError(f"unknown record type {tag!r}", path=path, line=lineno)
        if len(parts) < need:
            raise DatasetError(
                f"{tag} needs {need - 1} fields, found {len(parts) - 1}", path=path, line=lineno
            )
        try:
            n_ids = _INT_FIELDS.get(tag, 1)
            ids = [int(p) for p in parts[1 : 1 + n_ids]]
            vals = [float(p) for p in parts[1 + n_ids : need]]
        except ValueError as exc:
            raise DatasetError(f"bad number in {tag}: {exc}", path=path, line=lineno) from None
        if not all(math.isfinite(v) for v in vals):
            raise DatasetError(f"non-finite value in {tag}", path=path, line=lineno)
        if max(ids) > _INT64[1] or min(ids) < _INT64[0]:
            vid = next(v for v in ids if not _INT64[0] <= v <= _INT64[1])
            raise DatasetError(
                f"{tag} id {vid} is beyond the 64-bit integer range", path=path, line=lineno
            )
        if len(vals) >= 2 and max(abs(vals[0]), abs(vals[1])) > max_coordinate:
            k = 0 if abs(vals[0]) > max_coordinate else 1
            raise DatasetError(
                f"{tag} {_FIELDS[tag][k]}: {vals[k]:g} m is beyond the plausible extent "
                f"(|coordinate| <= {max_coordinate:g} m)",
                path=path,
                line=lineno,
            )
        if tag in ("VERTEX_SE2", "VERTEX2", "VERTEX_XY"):
            has_vertices = True
            vid = ids[0]
            if vid in g.poses or vid in g.landmarks:
                raise DatasetError(f"duplicate vertex id {vid}", path=path, line=lineno)
            if tag == "VERTEX_XY":
                g.landmarks[vid] = np.array(vals)
            else:
                g.poses[vid] = np.array(vals)
                toro |= tag == "VERTEX2"
                g2o |= tag == "VERTEX_SE2"
        elif tag == "FIX":
            g.fixed.append(ids[0])
        elif tag == "EQUIV":
            g.equivalences.append((ids[0], ids[1]))
        elif tag in ("EDGE_SE2", "EDGE2"):
            info = _full3(vals[3:], _G2O_INDEX if tag == "EDGE_SE2" else _TORO_INDEX)
            if tag == "EDGE2":  # its order is known once every EDGE2 line is read
                edge2.append(vals[3:])
                edge2_lines.append(lineno)
                edge2_rows.append(len(g.pose_edges))
            g.pose_edges.append(PoseEdge(ids[0], ids[1], np.array(vals[:3]), info))
            edge_lines.append((lineno, tag, ids[0], ids[1]))
            toro |= tag == "EDGE2"
            g2o |= tag == "EDGE_SE2"
        else:
            g.landmark_edges.append(
                LandmarkEdge(ids[0], ids[1], np.array(vals[:2]), _upper_to_full(vals[2:], 2))
            )
            edge_lines.append((lineno, tag, ids[0], ids[1]))
    g.format = "toro" if toro and not g2o else "g2o"
    if edge2:
        g.edge2_order = _edge2_order(edge2_lines, edge2, edge2_order, path)
        if g.edge2_order == "g2o":
            for n, info_values in zip(edge2_rows, edge2, strict=True):
                e = g.pose_edges[n]
                g.pose_edges[n] = PoseEdge(e.i, e.j, e.measurement, _full3(info_values, _G2O_INDEX))
    if not has_vertices and g.pose_edges:
        _chain_odometry(g, edge_lines, path)
    for lineno, tag, i, j in edge_lines:
        j_ok = j in g.landmarks if tag == "EDGE_SE2_XY" else j in g.poses
        if i not in g.poses or not j_ok:
            raise DatasetError(f"{tag} {i} {j} references a missing vertex", path=path, line=lineno)
    if unknown:
        warnings.warn(f"{path}: skipped {unknown} lines of unknown type", UserWarning, stacklevel=2)
    return g


def read_g2o(
    path: str | os.PathLike[str], *, skip_unknown: bool = False, edge2_order: Edge2Order = "auto"
) -> PoseGraph:
    """Parse a g2o file into a :class:`PoseGraph` (TORO records are read too: see
    :func:`read_pose_graph`, which this is)."""
    return read_pose_graph(path, skip_unknown=skip_unknown, edge2_order=edge2_order)


def _chain_odometry(g: PoseGraph, edge_lines: list[tuple[int, str, int, int]], path: Path) -> None:
    """Initial poses of a vertex-less file: the first id at the origin, every next id (in
    increasing order) by composing the odometry edge from its predecessor."""
    from probmap.geometry.se2 import compose, inverse

    first_line: dict[int, int] = {}
    odo: dict[tuple[int, int], int] = {}
    for k, (lineno, tag, i, j) in enumerate(edge_lines):
        if tag == "EDGE_SE2_XY":
            continue
        first_line.setdefault(i, lineno)
        first_line.setdefault(j, lineno)
        odo.setdefault((i, j), k)
    ids = sorted(first_line)
    pose = np.zeros(3)
    g.poses[ids[0]] = pose
    for a, b in zip(ids[:-1], ids[1:], strict=True):
        if (a, b) in odo:
            pose = compose(pose, g.pose_edges[odo[a, b]].measurement)
        elif (b, a) in odo:
            pose = compose(pose, inverse(g.pose_edges[odo[b, a]].measurement))
        else:
            raise DatasetError(
                f"no vertex lines, and no odometry edge {a} -> {b} to chain the initial poses",
                path=path,
                line=first_line[b],
            )
        g.poses[b] = pose
    g.chained = True


def write_g2o(path: str | os.PathLike[str], graph: PoseGraph) -> Path:
    """Write ``graph`` to ``path`` in g2o format, atomically, at full precision.

    Vertices in the order of ``graph.poses`` and ``graph.landmarks``, then the ``FIX`` lines,
    then the edges in list order; the lines are written by the package's one g2o writer,
    :func:`write_pose_graph_g2o`. TORO input is written as g2o
    (``VERTEX_SE2``/``EDGE_SE2`` with the information in g2o's order); ``EQUIV`` pairs have no
    g2o record and are not written.

    Raises
    ------
    ValueError
        An edge names a vertex the graph does not have.
    """
    pose_row = {vid: k for k, vid in enumerate(graph.poses)}
    mark_row = {vid: k for k, vid in enumerate(graph.landmarks)}

    def rows(edges: list[PoseEdge] | list[LandmarkEdge], j_rows: dict[int, int]) -> IntArray:
        try:
            ij = [(pose_row[e.i], j_rows[e.j]) for e in edges]
        except KeyError as exc:
            raise ValueError(f"{graph.name}: an edge references a missing vertex {exc}") from None
        return np.array(ij, dtype=np.int64).reshape(len(edges), 2)

    E, L = len(graph.pose_edges), len(graph.landmark_edges)
    return write_pose_graph_g2o(
        path,
        np.array(list(graph.poses.values()), dtype=np.float64).reshape(-1, 3),
        rows(graph.pose_edges, pose_row),
        np.array([e.measurement for e in graph.pose_edges], dtype=np.float64).reshape(E, 3),
        np.array([e.information for e in graph.pose_edges], dtype=np.float64).reshape(E, 3, 3),
        ids=np.array(list(graph.poses), dtype=np.int64),
        landmarks=np.array(list(graph.landmarks.values()), dtype=np.float64).reshape(-1, 2),
        landmark_ids=np.array(list(graph.landmarks), dtype=np.int64),
        landmark_edges=rows(graph.landmark_edges, mark_row),
        landmark_measurements=np.array(
            [e.measurement for e in graph.landmark_edges], dtype=np.float64
        ).reshape(L, 2),
        landmark_information=np.array(
            [e.information for e in graph.landmark_edges], dtype=np.float64
        ).reshape(L, 2, 2),
        fixed_ids=graph.fixed,
    )


@dataclass(frozen=True, eq=False)
class PoseGraphArrays:
    """A graph's poses and pose edges as the arrays :mod:`probmap.slam.posegraph.optimize` takes.

    Attributes
    ----------
    ids : ndarray, shape (N,), int64
        Vertex id of every row of ``poses``, increasing.
    poses : ndarray, shape (N, 3)
        ``(x, y, theta)`` per vertex, metres and radians.
    edges : ndarray, shape (E, 2), int64
        Row indices into ``poses`` of each pose edge (file order).
    measurements : ndarray, shape (E, 3)
    information : ndarray, shape (E, 3, 3)
    fixed : ndarray, shape (F,), int64
        Row indices of the ``FIX`` vertices (empty when the file has none).
    """

    ids: IntArray
    poses: FloatArray
    edges: IntArray
    measurements: FloatArray
    information: FloatArray
    fixed: IntArray


def pose_graph_arrays(graph: PoseGraph) -> PoseGraphArrays:
    """Arrays of ``graph``'s poses and pose edges, with the id -> row mapping.

    Raises
    ------
    ValueError
        The graph has landmark edges (the SE(2) optimizer handles pose edges only), or no
        poses.
    """
    if graph.landmark_edges:
        raise ValueError(
            f"{graph.name}: {len(graph.landmark_edges)} landmark edges; "
            "pose-graph optimization takes pose edges only"
        )
    if not graph.poses:
        raise ValueError(f"{graph.name}: the graph has no poses")
    ids = np.array(sorted(graph.poses), dtype=np.int64)
    poses = np.array([graph.poses[int(i)] for i in ids], dtype=np.float64).reshape(-1, 3)
    E = len(graph.pose_edges)
    ij = np.array([(e.i, e.j) for e in graph.pose_edges], dtype=np.int64).reshape(E, 2)
    edges = np.searchsorted(ids, ij).astype(np.int64)
    z = np.array([e.measurement for e in graph.pose_edges], dtype=np.float64).reshape(E, 3)
    om = np.array([e.information for e in graph.pose_edges], dtype=np.float64).reshape(E, 3, 3)
    fixed_ids = np.array(sorted(set(graph.fixed) & set(graph.poses)), dtype=np.int64)
    fixed = np.searchsorted(ids, fixed_ids).astype(np.int64)
    return PoseGraphArrays(ids, poses, edges, z, om, fixed)


def with_poses(graph: PoseGraph, ids: ArrayLike, poses: ArrayLike) -> PoseGraph:
    """A copy of ``graph`` whose vertices ``ids (N,)`` take ``poses (N, 3)`` (edges shared)."""
    ids_a = np.asarray(ids, dtype=np.int64)
    p = np.asarray(poses, dtype=np.float64)
    if p.shape != (ids_a.size, 3):
        raise ValueError(f"poses must have shape ({ids_a.size}, 3), got {p.shape}")
    new = dict(graph.poses)
    for vid, row in zip(ids_a.tolist(), p, strict=True):
        if vid not in new:
            raise ValueError(f"{graph.name}: no vertex {vid}")
        new[vid] = row.copy()
    return PoseGraph(
        poses=new,
        landmarks=dict(graph.landmarks),
        pose_edges=graph.pose_edges,
        landmark_edges=graph.landmark_edges,
        fixed=list(graph.fixed),
        name=graph.name,
        equivalences=list(graph.equivalences),
        format=graph.format,
        chained=graph.chained,
        edge2_order=graph.edge2_order,
    )


def write_pose_graph_g2o(
    path: str | os.PathLike[str],
    poses: ArrayLike,
    edges: ArrayLike,
    measurements: ArrayLike,
    information: ArrayLike,
    *,
    ids: ArrayLike | None = None,
    landmarks: ArrayLike | None = None,
    landmark_ids: ArrayLike | None = None,
    landmark_edges: ArrayLike | None = None,
    landmark_measurements: ArrayLike | None = None,
    landmark_information: ArrayLike | None = None,
    fixed_ids: Sequence[int] = (),
) -> Path:
    """Write a pose(-landmark) graph given as arrays to ``path`` in g2o format, atomically.

    The one g2o writer of the package (:func:`write_g2o` writes a :class:`PoseGraph` through it). Records, in this order, at full
    precision (``repr`` of every float): ``VERTEX_SE2 id x y theta`` per pose,
    ``VERTEX_XY id x y`` per landmark, ``FIX id`` per fixed id, ``EDGE_SE2 i j dx dy dtheta``
    plus the upper triangle of the information matrix (row by row) per pose edge, and
    ``EDGE_SE2_XY i j dx dy`` plus the upper triangle of the 2x2 information per landmark
    edge.

    Parameters
    ----------
    path : path-like
    poses : array_like, shape (N, 3)
    edges : array_like, shape (E, 2), int
        Row indices into ``poses``.
    measurements : array_like, shape (E, 3)
    information : array_like, shape (E, 3, 3)
    ids : array_like of int, shape (N,), optional
        Vertex ids to write (default ``0 .. N-1``).
    landmarks : array_like, shape (M, 2), optional
        Landmark positions, metres (default none).
    landmark_ids : array_like of int, shape (M,), optional
        Their vertex ids (default ``N .. N+M-1``).
    landmark_edges : array_like, shape (L, 2), int, optional
        Per landmark edge, the row of its pose in ``poses`` and of its landmark in
        ``landmarks``.
    landmark_measurements : array_like, shape (L, 2), optional
        The landmark's position in the pose's frame, metres.
    landmark_information : array_like, shape (L, 2, 2), optional
    fixed_ids : sequence of int
        Vertex ids written as ``FIX`` lines.

    Returns
    -------
    Path
    """
    x = pose_batch(poses)
    vid = _as_ids(ids, len(x), 0, "ids")
    lm = np.zeros((0, 2)) if landmarks is None else np.asarray(landmarks, dtype=np.float64)
    if lm.ndim != 2 or lm.shape[1] != 2:
        raise ValueError(f"landmarks must have shape (M, 2), got {lm.shape}")
    lid = _as_ids(landmark_ids, len(lm), len(x), "landmark_ids")
    pe = _edge_arrays("", edges, measurements, information, 3, len(x), len(x))
    if landmark_edges is None:
        landmark_edges, landmark_measurements = np.zeros((0, 2), np.int64), np.zeros((0, 2))
        landmark_information = np.zeros((0, 2, 2))
    le = _edge_arrays(
        "landmark_", landmark_edges, landmark_measurements, landmark_information, 2, len(x), len(lm)
    )
    lines = [
        f"VERTEX_SE2 {n} {p[0]!r} {p[1]!r} {p[2]!r}"
        for n, p in zip(vid.tolist(), x.tolist(), strict=True)
    ]
    lines += [
        f"VERTEX_XY {n} {p[0]!r} {p[1]!r}" for n, p in zip(lid.tolist(), lm.tolist(), strict=True)
    ]
    lines += [f"FIX {int(n)}" for n in fixed_ids]
    _edge_lines(lines, "EDGE_SE2", vid[pe[0][:, 0]], vid[pe[0][:, 1]], pe[1], pe[2])
    _edge_lines(lines, "EDGE_SE2_XY", vid[le[0][:, 0]], lid[le[0][:, 1]], le[1], le[2])
    with atomic_write(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return Path(path)


def _as_ids(ids: ArrayLike | None, n: int, first: int, name: str) -> IntArray:
    """Vertex ids ``(n,)`` as int64, by default ``first .. first+n-1``."""
    vid = np.arange(first, first + n) if ids is None else np.asarray(ids, dtype=np.int64)
    if vid.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {vid.shape}")
    return vid


def _edge_arrays(
    name: str,
    edges: ArrayLike,
    measurements: ArrayLike | None,
    information: ArrayLike | None,
    dim: int,
    n_i: int,
    n_j: int,
) -> tuple[IntArray, FloatArray, FloatArray]:
    """Edges ``(E, 2)`` with rows ``< (n_i, n_j)``, measurements ``(E, dim)`` and information
    ``(E, dim, dim)`` checked for their shapes and bounds only (a file may hold any values)."""
    e = np.asarray(edges)
    if e.size and not np.issubdtype(e.dtype, np.integer):
        raise ValueError(f"{name}edges must hold integer row indices, got dtype {e.dtype}")
    e = e.astype(np.int64).reshape(-1, 2) if e.size == 0 else e.astype(np.int64)
    E = len(e)
    z = np.asarray(measurements, dtype=np.float64)
    om = np.asarray(information, dtype=np.float64)
    if e.shape != (E, 2) or z.shape != (E, dim) or om.shape != (E, dim, dim):
        raise ValueError(
            f"{name}edges, {name}measurements and {name}information must have shapes "
            f"(E, 2), (E, {dim}) and (E, {dim}, {dim}), got {e.shape}, {z.shape} and {om.shape}"
        )
    for col, n in ((0, n_i), (1, n_j)):
        bad = np.flatnonzero((e[:, col] < 0) | (e[:, col] >= n))
        if bad.size:
            k = int(bad[0])
            raise ValueError(f"{name}edge {k} {tuple(e[k].tolist())}: index {col} outside [0, {n})")
    return e, z, om


def _edge_lines(
    lines: list[str], tag: str, i: IntArray, j: IntArray, z: FloatArray, info: FloatArray
) -> None:
    """Append one g2o edge line per row: ``tag i j z...`` and the upper triangle of ``info``."""
    iu = np.triu_indices(info.shape[1])
    upper = info[:, iu[0], iu[1]].tolist()
    for a, b, zz, u in zip(i.tolist(), j.tolist(), z.tolist(), upper, strict=True):
        lines.append(f"{tag} {a} {b} " + " ".join(repr(v) for v in (*zz, *u)))
