"""Where does a graph-SLAM run break? Relation errors binned by the times of their two scans.

Runs graph SLAM with the defaults on one log of ``bench_graph_slam.py`` and prints:

- a matrix of the mean relation error (metres, with the relation count) for every pair of time
  bins: a run that is right is small everywhere; a break at time ``T`` shows as small blocks
  on the diagonal and large errors in every cell that pairs a bin before ``T`` with one after;
- the short relations (scans less than 20 s apart) whose error exceeds 0.2 m: the moment of
  the break, when local SLAM (not a closure) caused it;
- how many accepted closures reach back more than 30 s in each bin, and how many of those a
  reference relation verifies (and of them, how many are more than 0.2 m off).

Usage::

    python benchmarks/graph_slam_breaks.py [--log fr079|intel|bag|clinic] [--bin 100]
        [--no-odometry]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_graph_slam as bench  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", default="fr079", choices=sorted(bench.LOGS))
    ap.add_argument("--bin", type=float, default=100.0, help="Seconds per time bin.")
    ap.add_argument(
        "--no-odometry", action="store_true", help="Ignore the odometry (lidar-only SLAM)."
    )
    default = Path(__file__).resolve().parents[2] / "shared" / "data"
    ap.add_argument("--data", type=Path, default=Path(os.environ.get("PROBMAP_DATA", default)))
    args = ap.parse_args()

    from probmap.geometry.se2 import between, compose, inverse
    from probmap.metrics.relations import read_relations, relation_errors
    from probmap.pipelines.laser_slam import load_laser_log, run_submap_slam

    _, log, rel_file = bench.LOGS[args.log]
    batch = load_laser_log(args.data / log)
    run = run_submap_slam(batch, odometry=False if args.no_odometry else None)
    times, robot = np.asarray(run.times), np.asarray(run.poses)
    t0 = float(times[0])
    rel = bench._within(read_relations(args.data / rel_file), times)
    err = np.asarray(relation_errors(times, robot, rel).translation)
    lo = np.minimum(rel.t1, rel.t2) - t0
    hi = np.maximum(rel.t1, rel.t2) - t0
    edges = np.arange(0.0, float(times[-1] - t0) + args.bin, args.bin)

    print(f"{bench.LOGS[args.log][0]}: mean relation error (count), rows: earlier scan's bin")
    for a in edges[:-1]:
        cells = []
        for b in edges[:-1]:
            s = (lo >= a) & (lo < a + args.bin) & (hi >= b) & (hi < b + args.bin)
            cells.append(f"{err[s].mean():5.2f}({s.sum():3d})" if s.any() else " " * 10)
        print(f"{a:6.0f} s " + " ".join(cells))

    short = np.flatnonzero((hi - lo < 20.0) & (err > 0.2))
    print(f"\nshort relations (< 20 s apart) more than 0.2 m off: {short.size}")
    for j in short[np.argsort(lo[short])][:20]:
        print(f"  {lo[j]:7.1f} -> {hi[j]:7.1f} s: {err[j]:.2f} m")

    # closures reaching back, and those a relation verifies (bench_graph_slam's rule)
    mount = between(np.asarray(batch.robot_poses), np.asarray(batch.laser_poses))
    scan_of = np.asarray(run.node_scans)
    t1 = np.concatenate([rel.t1, rel.t2])
    t2 = np.concatenate([rel.t2, rel.t1])
    delta = np.concatenate([rel.delta, inverse(rel.delta)])
    i1, i2 = bench._lookup(times, t1), bench._lookup(times, t2)
    print("\nclosures reaching back more than 30 s: per bin of the node's time")
    for a in edges[:-1]:
        back = verified = wrong = 0
        for c in run.slam.closures:
            k, anchor = scan_of[c.node], scan_of[c.anchor]
            if not (a <= times[k] - t0 < a + args.bin) or times[k] - times[anchor] <= 30.0:
                continue
            back += 1
            near = np.flatnonzero(
                (np.abs(t1 - times[anchor]) <= bench.BRIDGE_S) & (np.abs(t2 - times[k]) <= 2.0)
            )
            if not near.size:
                continue
            r = near[np.argmin(np.abs(t1[near] - times[anchor]) + np.abs(t2[near] - times[k]))]
            ref = compose(
                compose(between(robot[anchor], robot[i1[r]]), delta[r]),
                between(robot[i2[r]], robot[k]),
            )
            z = compose(compose(mount[k], np.asarray(c.pose)), inverse(mount[k]))
            d = between(ref, z)
            verified += 1
            wrong += math.hypot(d[0], d[1]) > 0.2
        print(f"  {a:6.0f} s: {back:5d} closures, {verified:4d} verified, {wrong:3d} off > 0.2 m")


if __name__ == "__main__":
    main()
