"""Do a log's reference relations agree with its own laser scans? (issue 18: the hospital goal)

The relation metric (Kuemmerle et al. 2009) scores a trajectory against reference relative
poses. It is only as good as the reference. This script checks each *local* relation
``(t1, t2, delta)`` (the two times less than ``--local-seconds`` apart; the scans overlap) with
the laser data alone: the scan taken at ``t2`` is placed in the frame of the scan taken at
``t1`` by

- the reference relation (robot frame, composed with the laser's mounting pose on each side),
- the estimate (graph SLAM with its default settings, or a trajectory CSV written by
  ``probmap slam grid``),

and the median distance from its endpoints (returns up to ``--max-range`` metres) to the
nearest endpoint of the first scan is taken (a KD-tree; no fitting, no grid). A relative pose
that the scans support gives the smaller distance. Per log the table prints

- the median of those distances for the reference and for the estimate,
- the share of relations where the reference places the scans worse than the estimate by more
  than ``--margin`` metres (on Intel, whose reference comes from manually verified scan
  matching, this is the control: the reference should almost never be worse),
- the same share among the relations on which the estimate's error exceeds 0.15 m,
- the part of the mean relation error (over all relations used, as the metric averages) that
  comes from relations where the reference is the worse of the two: error that an estimate
  could only lower by agreeing less with the laser.

Run: ``PROBMAP_DATA=../shared/data python benchmarks/bench_relations_consistency.py
[--log intel --log clinic] [--trajectory LOG=PREFIX.trajectory.csv]``. Graph SLAM takes about
40 s on Intel and 2 min on the hospital.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

LOGS = {
    "intel": ("intel-research-lab/intel.clf.bz2", "intel-research-lab/intel.relations"),
    "clinic": (
        "freiburg-clinic/fr-clinic_robotlaser.clf.bz2",
        "freiburg-clinic/fr-clinic.relations",
    ),
}


def _endpoints(ranges: np.ndarray, angles: np.ndarray, max_range: float) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(ranges) & (ranges > 0.05) & (ranges < max_range)
    r, a = ranges[ok].astype(np.float64), angles[ok]
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def _median_gap(first: np.ndarray, second: np.ndarray, rel: np.ndarray) -> float:
    """Median distance of ``second``'s points, moved by ``rel`` into ``first``'s frame, to the
    nearest point of ``first``."""
    from scipy.spatial import cKDTree

    c, s = np.cos(rel[2]), np.sin(rel[2])
    moved = np.column_stack(
        [rel[0] + c * second[:, 0] - s * second[:, 1], rel[1] + s * second[:, 0] + c * second[:, 1]]
    )
    d, _ = cKDTree(first).query(moved)
    return float(np.median(d))


def check(
    batch: Any, times: np.ndarray, robot: np.ndarray, rel: Any, args: argparse.Namespace
) -> dict[str, float]:
    """The consistency figures of one log (see the module notes)."""
    from probmap.geometry.se2 import between, compose, inverse
    from probmap.metrics.relations import relation_errors

    mount = between(np.asarray(batch.robot_poses), np.asarray(batch.laser_poses))
    scan_t = np.asarray(batch.times)
    angles = np.asarray(batch.angles)
    errors = relation_errors(times, robot, rel)
    used = np.flatnonzero(errors.used)
    err = errors.translation
    local = np.abs(rel.t2[used] - rel.t1[used]) < args.local_seconds

    order = np.argsort(scan_t, kind="stable")  # logs may hold out-of-order timestamps
    sorted_t = scan_t[order]

    def scan_index(t: float) -> int:
        k = int(np.clip(np.searchsorted(sorted_t, t), 0, len(sorted_t) - 1))
        if k > 0 and abs(sorted_t[k - 1] - t) < abs(sorted_t[k] - t):
            k -= 1
        return int(order[k]) if abs(sorted_t[k] - t) <= 1e-3 else -1

    t_order = np.argsort(times, kind="stable")
    t_sorted = times[t_order]

    def pose_index(t: float) -> int:
        k = int(np.clip(np.searchsorted(t_sorted, t), 0, len(t_sorted) - 1))
        if k > 0 and abs(t_sorted[k - 1] - t) < abs(t_sorted[k] - t):
            k -= 1
        return int(t_order[k])

    rows = []
    for n in np.flatnonzero(local):
        r = used[n]
        i, j = scan_index(rel.t1[r]), scan_index(rel.t2[r])
        if i < 0 or j < 0:
            continue
        a_ang = angles if angles.ndim == 1 else angles[i]
        b_ang = angles if angles.ndim == 1 else angles[j]
        p = _endpoints(np.asarray(batch.ranges[i]), a_ang, args.max_range)
        q = _endpoints(np.asarray(batch.ranges[j]), b_ang, args.max_range)
        if len(p) < 20 or len(q) < 20:
            continue
        ref = compose(compose(inverse(mount[i]), rel.delta[r]), mount[j])
        est_robot = between(robot[pose_index(rel.t1[r])], robot[pose_index(rel.t2[r])])
        est = compose(compose(inverse(mount[i]), est_robot), mount[j])
        rows.append((_median_gap(p, q, ref), _median_gap(p, q, est), err[n]))
    R = np.asarray(rows)
    worse = R[:, 0] > R[:, 1] + args.margin
    big = R[:, 2] > 0.15
    return {
        "relations": float(local.sum()),
        "checked": float(len(R)),
        "gap_ref": float(np.median(R[:, 0])),
        "gap_est": float(np.median(R[:, 1])),
        "worse": float(worse.mean()),
        "big": float(big.sum()),
        "worse_big": float(worse[big].mean()) if big.any() else float("nan"),
        "error_all": float(err.mean()),
        "error_share": float(R[worse, 2].sum() / len(used)),
    }


def _share(value: float, count: float) -> str:
    return "none" if count == 0 else f"{100 * value:.0f} % of {count:.0f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", action="append", choices=sorted(LOGS), default=[])
    ap.add_argument("--trajectory", action="append", default=[], metavar="LOG=CSV")
    ap.add_argument("--local-seconds", type=float, default=60.0)
    ap.add_argument("--max-range", type=float, default=8.0)
    ap.add_argument("--margin", type=float, default=0.01)
    args = ap.parse_args()
    from probmap.metrics.relations import read_relations, read_trajectory
    from probmap.pipelines.laser_slam import load_laser_log, run_submap_slam

    data = Path(os.environ.get("PROBMAP_DATA", "../shared/data"))
    given = dict(t.split("=", 1) for t in args.trajectory)
    results = {}
    for key in args.log or ["intel", "clinic"]:
        log, relf = LOGS[key]
        batch = load_laser_log(data / log)
        rel = read_relations(data / relf)
        if key in given:
            times, robot = read_trajectory(given[key])
            source = given[key]
        else:
            t0 = time.perf_counter()
            run = run_submap_slam(batch)
            times, robot = run.times, run.poses
            source = f"graph SLAM, defaults ({time.perf_counter() - t0:.0f} s)"
        results[key] = (source, check(batch, np.asarray(times), np.asarray(robot), rel, args))
    print(
        "| log | estimate | relations (local, checked) | median gap: reference / estimate m "
        f"| reference worse by > {args.margin:g} m | among estimate errors > 0.15 m "
        "| relation error m | of it where the reference is worse |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for key, (source, r) in results.items():
        print(
            f"| {key} | {source} | {r['relations']:.0f} ({r['checked']:.0f}) | "
            f"{r['gap_ref']:.4f} / {r['gap_est']:.4f} | {100 * r['worse']:.1f} % | "
            f"{_share(r['worse_big'], r['big'])} | {r['error_all']:.4f} | "
            f"{r['error_share']:.4f} |"
        )


if __name__ == "__main__":
    main()
