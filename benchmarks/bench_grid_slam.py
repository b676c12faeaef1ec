"""Grid SLAM on the raw Intel log: wall time, scans/s, real-time factor, memory and relation
error of the RBPF beside scan-to-map matching odometry (1 particle) and raw odometry, all in
this run, with GMapping's figures from the issue (measured on the project machine) as anchor.

Usage::

    python benchmarks/bench_grid_slam.py [--particles 30] [--end-time SECONDS] [--data DIR]
        [--skip-peer] [--skip-guard-off]

Rows: the defaults (degeneracy guard on) and the same without the guard, for the RBPF and for
one particle (scan-to-map odometry).

Run it rarely: the full log at 30 particles takes minutes.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

GMAPPING = {"seconds": 68.7, "trans": 0.050, "rot": 1.97, "mib": 132.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=30)
    ap.add_argument("--end-time", type=float, default=None)
    ap.add_argument(
        "--data",
        type=Path,
        default=Path(os.environ.get("PROBMAP_SHARED", "/work/shared")) / "data",
    )
    ap.add_argument("--skip-peer", action="store_true", help="Skip the 1-particle peer runs.")
    ap.add_argument(
        "--skip-guard-off", action="store_true", help="Skip the RBPF run without the guard."
    )
    args = ap.parse_args()

    from rich.console import Console
    from rich.table import Table

    from probmap.datasets.carmen import load_scans
    from probmap.metrics.relations import Relations, read_relations, relation_errors
    from probmap.slam.laser.rbpf import RbpfConfig, run_rbpf

    folder = args.data / "intel-research-lab"
    log, rel_file = folder / "intel.clf.bz2", folder / "intel.relations"
    if not log.exists():
        sys.exit(f"missing {log}")
    batch = load_scans(log, poses="odometry", dtype=np.float32)  # ranges float32: half the memory
    times = np.asarray(batch.times)
    ranges = np.asarray(batch.ranges)
    robot = np.asarray(batch.robot_poses)
    if args.end_time is not None:
        keep = times <= times[0] + args.end_time
        times, ranges, robot = times[keep], ranges[keep], robot[keep]
    angles = np.asarray(batch.angles)
    duration = float(times[-1] - times[0])
    rel = read_relations(rel_file)
    inside = (rel.t1 <= times[-1]) & (rel.t2 <= times[-1])
    rel = Relations(rel.t1[inside], rel.t2[inside], rel.delta[inside])

    def errors(poses: np.ndarray) -> dict[str, float]:
        return relation_errors(times, poses, rel).summary()

    # warm the numba caches outside the timed runs
    warnings.simplefilter("ignore", UserWarning)
    run_rbpf(times[:40], ranges[:40], angles, robot[:40], batch.max_range,
                  RbpfConfig(particles=2))  # fmt: skip
    rows = []
    rbpf = RbpfConfig(particles=args.particles)
    runs = [("RBPF", rbpf, True)]
    if not args.skip_guard_off:
        runs.append(("RBPF, guard off", replace(rbpf, degeneracy_guard=False), True))
    if not args.skip_peer:
        one = RbpfConfig(particles=1)
        runs.append(("scan-to-map odometry", one, False))
        runs.append(("scan-to-map, guard off", replace(one, degeneracy_guard=False), False))
    for name, cfg, sample in runs:
        t0 = time.perf_counter()
        res = run_rbpf(times, ranges, angles, robot, batch.max_range, cfg, sample=sample)
        wall = time.perf_counter() - t0
        e = errors(res.poses)
        rows.append((name, cfg.particles, wall, len(times) / wall, duration / wall,
                     res.map_bytes / 2**20, e))  # fmt: skip
    e_odo = errors(robot)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    table = Table(title=f"grid SLAM on Intel ({len(times)} scans, {duration:.0f} s of log)")
    for col in ("method", "particles", "wall s", "scans/s", "x real time", "tiles MiB",
                "trans m (mean ± std)", "rot deg"):  # fmt: skip
        table.add_column(col, justify="right")
    for name, n, wall, sps, rt, mib, e in rows:
        table.add_row(
            name, str(n), f"{wall:.1f}", f"{sps:.0f}", f"{rt:.1f}", f"{mib:.1f}",
            f"{e['trans_abs_mean_m']:.4f} ± {e['trans_abs_std_m']:.4f}",
            f"{e['rot_abs_mean_deg']:.2f}",
        )  # fmt: skip
    table.add_row("raw odometry", "-", "-", "-", "-", "-",
                  f"{e_odo['trans_abs_mean_m']:.3f} ± {e_odo['trans_abs_std_m']:.3f}",
                  f"{e_odo['rot_abs_mean_deg']:.2f}")  # fmt: skip
    if args.end_time is None:
        g = GMAPPING
        table.add_row("GMapping (issue, 30 p.)", "30", f"{g['seconds']:.1f}", "-",
                      f"{duration / g['seconds']:.1f}", "-", f"{g['trans']:.3f}",
                      f"{g['rot']:.2f}")  # fmt: skip
    Console(width=150).print(table)
    print(f"process peak RSS {peak:.0f} MiB (includes the parsed log and numba/scipy)")
    if args.end_time is None:
        wall = rows[0][2]
        print(f"RBPF / GMapping: wall time x{wall / GMAPPING['seconds']:.2f}, "
              f"translational error x{rows[0][6]['trans_abs_mean_m'] / GMAPPING['trans']:.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
