"""What a graph-SLAM run reports beside its map (``PREFIX.report.json``): where local SLAM
overrode the odometry or lost track, what the loop-closure search did, how much the visits
contradict each other, which revisits no closure joined, and from those the places and times
where the map may be wrong (the *doubts*), with the one warning line that ``probmap slam grid``
prints. Issue 36, point 2."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from probmap.datasets.records import ScanBatch
    from probmap.slam.laser.submap_slam import SubmapSlam

__all__ = [
    "DOUBT_CELLS",
    "VISIT_LENGTH",
    "closure_report",
    "consistency_report",
    "doubt_line",
    "doubts_of",
    "local_report",
    "revisit_report",
]

#: Travel per visit of the self-consistency figure, metres (:func:`consistency_report`).
VISIT_LENGTH = 10.0


def _quantiles(x: NDArray[np.float64]) -> dict[str, float]:
    if not len(x):
        return {}
    q = np.quantile(x, [0.5, 0.9, 0.99])
    return {"median": float(q[0]), "p90": float(q[1]), "p99": float(q[2]), "max": float(x.max())}


def local_report(slam: SubmapSlam, times: ArrayLike) -> dict[str, Any]:
    """Where local SLAM overrode the odometry: the times (seconds from the first scan of
    ``times``, the run's scan times) of the nodes whose match was kept from the wide search,
    more than the matcher's window away from the odometry, so that their odometry edge was
    left out. Right after an odometry glitch (a late timestamp, wheel slip); also where local
    SLAM broke (Freiburg 079 at 305-309 s: six in 4 s). Intel has none, its bag 3, the
    hospital 4."""
    t = np.asarray(times, dtype=np.float64)
    t0 = float(t[0]) if len(t) else 0.0
    return {
        "lidar_only": slam.lidar_only,
        "odometry_overridden_s": [float(t[k]) - t0 for k in slam.gated_scans if k < len(t)],
        "untracked_s": [float(t[k]) - t0 for k in slam.untracked_scans if k < len(t)],
        "failed_matches": slam.failed_matches,
        "wide_searches": slam.recovered,
    }


def closure_report(slam: SubmapSlam) -> dict[str, Any]:
    """What the loop-closure search did and how the accepted closures sit in the optimized
    graph: counts (searched, accepted near and far, a far closure's confirmations counted as
    far too; rejected and why, the pairwise check's closures left out among them; trusted,
    down-weighted by the robust cost; pairs of closures compared and found inconsistent) and
    the distribution of the accepted closure edges' residuals (metres, radians)."""
    from probmap.slam.posegraph.optimize import edge_residuals

    loops = slam.loops
    kept = ~loops.left_out  # closures the pairwise check left out are rejected
    far = sum(c.far for c, k in zip(loops.closures, kept, strict=True) if k)
    edges = loops.edge_indices()[kept]
    g = slam.graph
    if len(edges):
        res = edge_residuals(g.poses, g.edges[edges], g.measurements[edges])
    else:
        res = np.zeros((0, 3))
    weights = slam.closure_weights()[kept]
    return {
        "searched": loops.searched,
        "accepted": {"near": int(kept.sum()) - far, "far": far},
        "far_searches": loops.far_searched,
        "far_matches": loops.far_found,
        "rejected": {
            "not_confirmed_by_earlier_nodes": loops.rejected,
            "correction_beyond_drift_bound": loops.drift_rejected,
            "ambiguous_place": loops.ambiguous,
            "inconsistent_with_other_closures": int((~kept).sum()),
        },
        "pairs_compared": loops.pairs_checked,
        "pairs_inconsistent": loops.conflicts,
        "trusted": loops.trusted,
        "down_weighted": int((weights < 0.5).sum()),
        "residual_m": _quantiles(np.hypot(res[:, 0], res[:, 1])),
        "residual_rad": _quantiles(np.abs(res[:, 2])),
    }


def consistency_report(
    times: ArrayLike, sensor_poses: ArrayLike, batch: ScanBatch
) -> dict[str, Any]:
    """The self-consistency of a run (:func:`probmap.metrics.consistency.map_consistency`) on
    the batch's scans at ``sensor_poses`` (one per scan of the batch, map frame): the share of
    the walls its visits saw that other visits saw as open space, in all and per visit (times
    in seconds from the first scan). A figure, not yet a verdict: the threshold that tells a
    fold from doors and people is still to be measured on more logs."""
    from probmap.metrics.consistency import map_consistency

    t = np.asarray(times, dtype=np.float64)
    n = len(t)
    c = map_consistency(
        t, sensor_poses, np.asarray(batch.ranges)[:n],
        np.asarray(batch.angles) if np.ndim(batch.angles) == 1 else np.asarray(batch.angles)[:n],
        float(batch.max_range), visit_length=VISIT_LENGTH,
    )  # fmt: skip
    t0 = float(t[0]) if n else 0.0
    return {
        "share": c.share,
        "visit_length_m": VISIT_LENGTH,
        "visits": [
            {
                "start_s": v.start - t0,
                "end_s": v.end - t0,
                "occupied": v.occupied,
                "contradicted": v.contradicted,
            }
            for v in c.visits
        ],
        "pairs": [
            {"wall_visit": q.wall, "open_visit": q.open, "cells": q.cells, "box_m": list(q.box)}
            for q in c.pairs
        ],
    }


def revisit_report(slam: SubmapSlam, times: ArrayLike) -> dict[str, Any]:
    """The revisits of a run that no loop closure joined
    (:func:`probmap.metrics.revisits.unjoined_revisits`, with its defaults) over the pose-graph
    nodes at their optimized poses; a closure joins only while the robust cost trusts it
    (weight at least 0.5) and the pairwise check kept it. Times in seconds from the first scan
    of ``times`` (the run's scan times), boxes in metres in the map frame."""
    from probmap.metrics.revisits import PIECE, unjoined_revisits

    t = np.asarray(times, dtype=np.float64)
    t0 = float(t[0]) if len(t) else 0.0
    nodes = np.asarray(slam.node_scan, dtype=np.int64)
    poses = np.asarray(slam.graph.poses, dtype=np.float64)[: len(nodes)]
    loops = slam.loops
    weights = slam.closure_weights()
    links = [
        (c.node, slam.submaps[c.submap].nodes[-1])
        for c, out, w in zip(loops.closures, loops.left_out, weights, strict=True)
        if not out and w >= 0.5 and slam.submaps[c.submap].nodes
    ]
    r = unjoined_revisits(t[nodes] - t0, poses, np.asarray(links, dtype=np.int64).reshape(-1, 2))
    return {
        "piece_m": PIECE,
        "pieces": r.pieces,
        "unjoined_pieces": r.unjoined,
        "unjoined": [
            {
                "start_s": u.start,
                "end_s": u.end,
                "length_m": u.length,
                "first_passed_s": [u.earlier_start, u.earlier_end],
                "box_m": list(u.box),
            }
            for u in r.spans
        ],
    }


#: Least contradicted cells (0.1 m each: 2 m of wall) of a doubt (:func:`doubts_of`).
DOUBT_CELLS = 20


def doubts_of(report: dict[str, Any]) -> list[dict[str, Any]]:
    """Where and when a graph-SLAM map may be wrong, from its report (``local`` and
    ``consistency`` and ``revisits``, see :func:`probmap.pipelines.laser_slam.slam_grid`);
    empty when nothing is in doubt.

    - ``"walls_in_open_space"``: visit A saw at least :data:`DOUBT_CELLS` cells (2 m) of its
      walls where visit B saw open space, B's own walls are contradicted by at least as many
      cells too, and the two visits are not consecutive. A fold or a wrong loop closure
      misplaces two visits against each other, so both see contradictions. A door or a person
      that moved contradicts one visit only; consecutive visits share their surroundings
      moments apart, so what differs between them is mostly the world changing. Measured:
      Freiburg 079 folded (0.54 m) 2 places; Intel, the Intel bag, Freiburg 079 mapped right
      none (also Intel's first 200 and 400 s); the hospital 9, at 594-653 s and 3450-3830 s,
      where its sparse scans are known to mislead local SLAM.
    - ``"unjoined_revisit"``: at least 10 m of travel that passed a mapped place again with
      no loop closure to it (``revisits``, :func:`revisit_report`): the two passes may be drawn
      apart, a corridor drawn twice. Measured: the hospital at 4,679-4,820 s (its passes of
      0-283 s; 0.66 m apart along the corridor); Intel, the Intel bag and Freiburg 079 none.
    - ``"untracked"``: lidar-only SLAM scans that matched nothing (placed by the
      constant-velocity prediction alone), in spans of scans less than 5 s apart.

    Each entry holds its times in seconds from the first scan; a place also its cells and
    ``box_m = [x_min, y_min, x_max, y_max]``, metres in the map frame, and a revisit its
    length and box.
    """
    out: list[dict[str, Any]] = []
    cons = report.get("consistency") or {}
    visits = cons.get("visits", [])
    for q in cons.get("pairs", []):
        a, b = visits[q["wall_visit"]], visits[q["open_visit"]]
        if (
            q["cells"] >= DOUBT_CELLS
            and b["contradicted"] >= DOUBT_CELLS
            and abs(q["wall_visit"] - q["open_visit"]) > 1
        ):
            out.append({
                "kind": "walls_in_open_space",
                "walls_seen_s": [a["start_s"], a["end_s"]],
                "open_space_seen_s": [b["start_s"], b["end_s"]],
                "cells": q["cells"],
                "box_m": q["box_m"],
            })  # fmt: skip
    for u in (report.get("revisits") or {}).get("unjoined", []):
        out.append({
            "kind": "unjoined_revisit",
            "start_s": u["start_s"],
            "end_s": u["end_s"],
            "length_m": u["length_m"],
            "first_passed_s": u["first_passed_s"],
            "box_m": u["box_m"],
        })  # fmt: skip
    lost = (report.get("local") or {}).get("untracked_s", [])
    spans: list[list[float]] = []
    for t in lost:
        if spans and t - spans[-1][1] < 5.0:
            spans[-1][1] = t
        else:
            spans.append([t, t])
    for lo, hi in spans:
        n = sum(1 for t in lost if lo <= t <= hi)
        out.append({"kind": "untracked", "start_s": lo, "end_s": hi, "scans": n})
    return out


def doubt_line(doubts: list[dict[str, Any]], prefix: str | os.PathLike[str]) -> str | None:
    """One line that says where the map may be wrong (:func:`doubts_of`), or None."""
    if not doubts:
        return None
    places = [d for d in doubts if d["kind"] == "walls_in_open_space"]
    lost = [d for d in doubts if d["kind"] == "untracked"]
    twice = [d for d in doubts if d["kind"] == "unjoined_revisit"]
    parts = []
    if places:
        d = places[0]
        w, o = d["walls_seen_s"], d["open_space_seen_s"]
        more = f" and {len(places) - 1} more place(s)" if len(places) > 1 else ""
        parts.append(
            f"walls seen at t = {w[0]:.0f}-{w[1]:.0f} s lie in open space seen at "
            f"t = {o[0]:.0f}-{o[1]:.0f} s ({d['cells'] / 10:.1f} m of wall{more}: a fold or a "
            f"wrong loop closure; red boxes in {prefix}.plot.png)"
        )
    if twice:
        d = twice[0]
        e = d["first_passed_s"]
        more = f" and {len(twice) - 1} more stretch(es)" if len(twice) > 1 else ""
        parts.append(
            f"t = {d['start_s']:.0f}-{d['end_s']:.0f} s passes the place of t = {e[0]:.0f}-"
            f"{e[1]:.0f} s again ({d['length_m']:.0f} m{more}) and no loop closure joins the "
            f"passes: it may be drawn twice (red boxes in {prefix}.plot.png)"
        )
    if lost:
        n = sum(d["scans"] for d in lost)
        parts.append(
            f"{n} scan(s) without odometry matched nothing (t = {lost[0]['start_s']:.0f}"
            f"-{lost[-1]['end_s']:.0f} s)"
        )
    return "the map may be wrong: " + "; ".join(parts) + f" (see {prefix}.report.json)"
