"""Read and write 2-D pose-landmark graphs in the g2o text format.

Supported records (one per line, whitespace separated)::

    VERTEX_SE2 id x y theta
    VERTEX_XY id x y
    EDGE_SE2 i j dx dy dtheta I11 I12 I13 I22 I23 I33
    EDGE_SE2_XY i j dx dy I11 I12 I22

Edge measurements are expressed in the frame of vertex ``i`` (``EDGE_SE2``: ``x_i^-1 ⊕ x_j``;
``EDGE_SE2_XY``: the landmark position in the robot frame). Information matrices are given by
their upper triangles, row by row. ``FIX id`` lines are kept; other tags raise a
:class:`~probmap.datasets.protocol.DatasetError` unless ``skip_unknown=True`` (counted and warned).
"""

from __future__ import annotations

import os
import tempfile
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from probmap.datasets.protocol import DatasetError

FloatArray = NDArray[np.float64]

__all__ = ["LandmarkEdge", "PoseEdge", "PoseGraph", "read_g2o", "write_g2o"]


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
    """

    poses: dict[int, FloatArray] = field(default_factory=dict)
    landmarks: dict[int, FloatArray] = field(default_factory=dict)
    pose_edges: list[PoseEdge] = field(default_factory=list)
    landmark_edges: list[LandmarkEdge] = field(default_factory=list)
    fixed: list[int] = field(default_factory=list)
    name: str = "g2o"


def _upper_to_full(vals: list[float], n: int) -> FloatArray:
    M = np.zeros((n, n))
    M[np.triu_indices(n)] = vals
    return M + np.triu(M, 1).T


_COUNTS = {"VERTEX_SE2": 5, "VERTEX_XY": 4, "EDGE_SE2": 12, "EDGE_SE2_XY": 8, "FIX": 2}


def read_g2o(path: str | os.PathLike[str], *, skip_unknown: bool = False) -> PoseGraph:
    """Parse a g2o file into a :class:`PoseGraph`.

    Raises
    ------
    DatasetError
        Short lines, non-numeric fields, non-finite values, duplicate vertex ids, edges that
        reference missing vertices, or (unless ``skip_unknown``) unknown tags; the message names
        the file and line.
    """
    path = Path(path)
    g = PoseGraph(name=path.stem)
    unknown = 0
    edge_lines: list[tuple[int, str, int, int]] = []
    with open(path) as f:
        for lineno, line in enumerate(f, start=1):
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
                ids = [int(p) for p in parts[1 : 3 if tag.startswith("EDGE") else 2]]
                vals = [float(p) for p in parts[len(ids) + 1 : need]]
            except ValueError as exc:
                raise DatasetError(f"bad number in {tag}: {exc}", path=path, line=lineno) from None
            if not np.all(np.isfinite(vals)):
                raise DatasetError(f"non-finite value in {tag}", path=path, line=lineno)
            if tag == "VERTEX_SE2" or tag == "VERTEX_XY":
                vid = ids[0]
                if vid in g.poses or vid in g.landmarks:
                    raise DatasetError(f"duplicate vertex id {vid}", path=path, line=lineno)
                if tag == "VERTEX_SE2":
                    g.poses[vid] = np.array(vals)
                else:
                    g.landmarks[vid] = np.array(vals)
            elif tag == "FIX":
                g.fixed.append(ids[0])
            elif tag == "EDGE_SE2":
                g.pose_edges.append(
                    PoseEdge(ids[0], ids[1], np.array(vals[:3]), _upper_to_full(vals[3:], 3))
                )
                edge_lines.append((lineno, tag, ids[0], ids[1]))
            else:
                g.landmark_edges.append(
                    LandmarkEdge(ids[0], ids[1], np.array(vals[:2]), _upper_to_full(vals[2:], 2))
                )
                edge_lines.append((lineno, tag, ids[0], ids[1]))
    for lineno, tag, i, j in edge_lines:
        j_ok = j in g.poses if tag == "EDGE_SE2" else j in g.landmarks
        if i not in g.poses or not j_ok:
            raise DatasetError(f"{tag} {i} {j} references a missing vertex", path=path, line=lineno)
    if unknown:
        warnings.warn(f"{path}: skipped {unknown} lines of unknown type", UserWarning, stacklevel=2)
    return g


def _fmt(v: float) -> str:
    return repr(float(v))


def write_g2o(path: str | os.PathLike[str], graph: PoseGraph) -> Path:
    """Write ``graph`` to ``path`` atomically (temp file + ``os.replace``), full precision."""
    path = Path(path)
    lines = []
    for vid, p in graph.poses.items():
        lines.append(f"VERTEX_SE2 {vid} " + " ".join(_fmt(v) for v in p))
    for vid, p in graph.landmarks.items():
        lines.append(f"VERTEX_XY {vid} " + " ".join(_fmt(v) for v in p))
    for vid in graph.fixed:
        lines.append(f"FIX {vid}")
    for e in graph.pose_edges:
        info = e.information[np.triu_indices(3)]
        vals = " ".join(_fmt(v) for v in (*e.measurement, *info))
        lines.append(f"EDGE_SE2 {e.i} {e.j} {vals}")
    for le in graph.landmark_edges:
        info = le.information[np.triu_indices(2)]
        vals = " ".join(_fmt(v) for v in (*le.measurement, *info))
        lines.append(f"EDGE_SE2_XY {le.i} {le.j} {vals}")
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write("\n".join(lines) + "\n")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
