"""Graph SLAM on real laser logs (issues 18, 36): the raw Intel log, the Freiburg hospital log,
the Intel ROS bag, Freiburg 079 (whose look-alike offices fool closures) and the Freiburg campus
(outdoor, a scan every metre, odometry rebuilt from its corrected log: ``_campus.py``), with
default settings, each run in its own process; the RBPF on Intel and raw odometry as peers in
the same run.

Usage::

    python benchmarks/bench_graph_slam.py [--data DIR] [--end-time SECONDS] [--skip-rbpf]
        [--markdown]

Per log: scans, pose-graph nodes, submaps; loop closures searched (node x submap searches),
accepted, kept (robust weight >= 0.5 after the final optimization) and left out by the pairwise
consistency check (not counted as accepted); closure precision;
relation error (Kuemmerle et al. 2009, every relation whose two timestamps the run covers; and
"loop", the relations whose scans lie more than 10 s apart, where only closures hold) of the
robot poses (and, for the hospital, whose laser sits 0.22 m ahead of the robot, of the laser
poses); wall time of SLAM (reading the log is shown apart), real-time factor (log duration over
SLAM wall time) and the process's peak RSS (``getrusage(RUSAGE_SELF)``: the parsed log, numba,
the submaps and the final map; one process per row).

Closure precision. An accepted closure says: node ``k``'s scan lies at pose ``z`` in the frame
of submap anchor ``a``. It is *verified* when the relations file holds a reference relation
``(t1, t2, delta)`` with ``t1`` within 2 s of ``a``'s scan time and ``t2`` within 2 s of ``k``'s
(either order). The reference for ``z`` is then ``x(a)^-1 x(t1) (+) delta (+) x(t2)^-1 x(k)``:
the relation, bridged to the two scans by the run's own trajectory over at most 2 s each (local
odometry-and-matching accuracy, a few cm). The closure *agrees* when ``z`` (in the robot frame)
is within 0.2 m and 2 deg of that reference; precision = agreeing / verified. "consistent" is
the fraction of all accepted closures whose ``z`` agrees within 0.2 m / 2 deg with the final
optimized poses of its two nodes (a closure the optimizer overruled does not).

Run it rarely: the RBPF on the whole Intel log takes minutes (``--skip-rbpf`` skips it).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

LOGS = {
    "intel": (
        "Intel, raw log",
        "intel-research-lab/intel.clf.bz2",
        "intel-research-lab/intel.relations",
    ),
    "clinic": (
        "Freiburg hospital",
        "freiburg-clinic/fr-clinic_robotlaser.clf.bz2",
        "freiburg-clinic/fr-clinic.relations",
    ),
    "bag": (
        "Intel, ROS bag",
        "intel-research-lab/intel.orig.bag",
        "intel-research-lab/intel.relations",
    ),
    # the same bag with its odometry ignored (--no-odometry): lidar-only SLAM
    "bag_lidar": (
        "Intel, ROS bag, lidar only",
        "intel-research-lab/intel.orig.bag",
        "intel-research-lab/intel.relations",
    ),
    "fr079": (
        "Freiburg 079",
        "freiburg-079/fr079.clf.bz2",
        "freiburg-079/fr079.relations",
    ),
    # outdoor, a scan every metre; odometry rebuilt from the corrected log, GMapping's poses as
    # the reference (benchmarks/_campus.py)
    "campus": ("Freiburg campus, rebuilt odometry", "", ""),
}
# the raw logs without their odometry (--no-odometry): run with --worker KEY (not in the table)
LOGS["intel_lidar"] = ("Intel, raw log, lidar only", *LOGS["intel"][1:])
LOGS["fr079_lidar"] = ("Freiburg 079, lidar only", *LOGS["fr079"][1:])
KEYS = ("intel", "bag", "bag_lidar", "clinic", "fr079", "campus")
LOOP_S = 10.0  # a relation between scans further apart than this is a loop relation
BRIDGE_S = 2.0  # longest stretch of the run's own trajectory used to reach a relation
AGREE = (0.2, math.radians(2.0))


# ----------------------------------------------------------------------------- helpers
def _peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux


def _within(rel: Any, times: np.ndarray) -> Any:
    from probmap.metrics.relations import Relations

    lo, hi = float(times.min()) - 1e-3, float(times.max()) + 1e-3
    keep = (rel.t1 >= lo) & (rel.t1 <= hi) & (rel.t2 >= lo) & (rel.t2 <= hi)
    return Relations(rel.t1[keep], rel.t2[keep], rel.delta[keep])


def _loops(rel: Any) -> Any:
    """The relations between scans more than ``LOOP_S`` apart."""
    from probmap.metrics.relations import Relations

    keep = np.abs(rel.t2 - rel.t1) > LOOP_S
    return Relations(rel.t1[keep], rel.t2[keep], rel.delta[keep])


def _errors(times: np.ndarray, poses: np.ndarray, rel: Any) -> dict[str, float]:
    from probmap.metrics.relations import relation_errors

    return relation_errors(np.asarray(times, float), np.asarray(poses, float), rel).summary()


def _head(batch: Any, n: int) -> Any:
    """The first ``n`` scans of a batch (for warming the compiled kernels)."""
    return batch.rows(slice(0, n))


def _bag_without_scans_past_tf(src: Path, dst: Path) -> tuple[Path, int]:
    """Copy a ROS 1 bag without the scans stamped after its last non-scan message (which tf
    cannot place without extrapolating); returns the copy and the number of scans dropped."""
    from rosbags.rosbag1 import Reader, Writer

    with Reader(src) as reader:
        last = max(s for c, s, _ in reader.messages() if not c.msgtype.endswith("LaserScan"))
    dropped = 0
    with Reader(src) as reader, Writer(dst) as writer:
        conns = {
            c.id: writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
            for c in reader.connections
        }
        for conn, stamp, raw in reader.messages():
            if conn.msgtype.endswith("LaserScan") and stamp > last:
                dropped += 1
                continue
            writer.write(conns[conn.id], stamp, raw)
    return dst, dropped


def _lookup(times: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index of the nearest time (times need not be sorted)."""
    order = np.argsort(times, kind="stable")
    st = times[order]
    k = np.clip(np.searchsorted(st, t), 1, len(st) - 1)
    left = k - 1
    k = np.where(np.abs(st[left] - t) <= np.abs(st[k] - t), left, k)
    return order[k]


def closure_precision(run: Any, mount: np.ndarray, rel: Any) -> dict[str, float]:
    """Verified, agreeing and consistent closures of a graph-SLAM run (see the module notes)."""
    from probmap.geometry.se2 import between, compose, inverse, wrap_angle

    # closures the pairwise check left out of the graph are rejected, not accepted
    out = run.slam.loops.left_out
    closures = [c for c, o in zip(run.slam.closures, out, strict=True) if not o]
    if not closures:
        return {"verified": 0, "agree": 0, "consistent": 0}
    times, robot = np.asarray(run.times), np.asarray(run.poses)
    scan_of = np.asarray(run.node_scans)
    k = np.asarray([scan_of[c.node] for c in closures])
    a = np.asarray([scan_of[c.anchor] for c in closures])
    z = np.asarray([c.pose for c in closures], dtype=np.float64)  # sensor frame
    m = mount[k]
    z_robot = compose(compose(m, z), inverse(m))
    # consistent with the final optimized poses of the two nodes
    e = between(z_robot, between(robot[a], robot[k]))
    ok = (np.hypot(e[:, 0], e[:, 1]) <= AGREE[0]) & (np.abs(wrap_angle(e[:, 2])) <= AGREE[1])
    consistent = int(ok.sum())
    # verified against a reference relation between the neighbourhoods of the two scans
    t1 = np.concatenate([rel.t1, rel.t2])
    t2 = np.concatenate([rel.t2, rel.t1])
    delta = np.concatenate([rel.delta, inverse(rel.delta)])
    i1, i2 = _lookup(times, t1), _lookup(times, t2)
    verified = agree = 0
    for j in range(len(closures)):
        ta, tk = times[a[j]], times[k[j]]
        gap = np.abs(t1 - ta) + np.abs(t2 - tk)
        cand = np.flatnonzero((np.abs(t1 - ta) <= BRIDGE_S) & (np.abs(t2 - tk) <= BRIDGE_S))
        if cand.size == 0:
            continue
        r = cand[np.argmin(gap[cand])]
        ref = compose(
            compose(between(robot[a[j]], robot[i1[r]]), delta[r]),
            between(robot[i2[r]], robot[k[j]]),
        )
        d = between(ref, z_robot[j])
        verified += 1
        agree += int(math.hypot(d[0], d[1]) <= AGREE[0] and abs(wrap_angle(d[2])) <= AGREE[1])
    return {"verified": verified, "agree": agree, "consistent": consistent}


# ----------------------------------------------------------------------------- workers
def worker_graph(key: str, data: Path, end_time: float | None) -> dict[str, Any]:
    from probmap.geometry.se2 import between
    from probmap.metrics.relations import read_relations
    from probmap.pipelines.laser_slam import load_laser_log, run_submap_slam

    _, log_rel, rel_rel = LOGS[key]
    path = data / log_rel
    note = ""
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if key == "campus":
            import _campus

            path = Path(tmp) / "campus.clf"
            ref_times, ref_poses = _campus.rebuild(data / _campus.CORRECTED, path)
            note = "reference: GMapping's poses"
        try:
            batch = load_laser_log(path, end_time=end_time)
        except ValueError as exc:  # a reader that refuses a scan past the tf buffer
            if not key.startswith("bag") or "tf buffer" not in str(exc):
                raise
            copy, dropped = _bag_without_scans_past_tf(path, Path(tmp) / "intel.bag")
            batch = load_laser_log(copy, end_time=end_time)
            note = f"{dropped} scan past the tf buffer dropped"
    for w in caught:
        m = re.search(r"dropped (\d+) scan", str(w.message))
        if m:
            note = f"{m.group(1)} scan(s) past the tf buffer dropped"
    read_s = time.perf_counter() - t0
    odometry = not key.endswith("_lidar")
    if not odometry:  # as slam grid runs lidar-only SLAM: the scans in publication order
        from probmap.datasets.scans import in_publication_order

        batch, _ = in_publication_order(batch)
    # warm the compiled kernels outside the timed run
    run_submap_slam(_head(batch, 150), odometry=odometry)
    run = run_submap_slam(batch, odometry=odometry)
    if key == "campus":
        from probmap.metrics.relations import Relations

        local, loop = _campus.relations(ref_times, ref_poses)
        rel = Relations(
            np.concatenate([local.t1, loop.t1]),
            np.concatenate([local.t2, loop.t2]),
            np.concatenate([local.delta, loop.delta]),
        )
    else:
        rel = _within(read_relations(data / rel_rel), np.asarray(run.times))
    laser = np.asarray(batch.laser_poses, float)
    robot = np.asarray(batch.robot_poses, float)
    mount = between(robot, laser)
    w = np.asarray(run.closure_weights)
    out: dict[str, Any] = {
        "scans": len(run.times),
        "nodes": run.nodes,
        "submaps": run.submaps,
        "searched": run.searched,
        "accepted": len(w) - int(run.slam.loops.left_out.sum()),
        "left_out": int(run.slam.loops.left_out.sum()),
        "kept": int((w >= 0.5).sum()),
        "read_s": read_s,
        "slam_s": run.seconds,
        "optimize_s": run.optimize_seconds,
        "search_s": run.search_seconds,
        "duration": run.duration,
        "relations": len(rel),
        "robot": _errors(run.times, run.poses, rel),
        "loop": _errors(run.times, run.poses, _loops(rel)),
        "laser": _errors(run.times, run.sensor_poses, rel),
        "odo_robot": _errors(batch.times, robot, rel),
        "odo_laser": _errors(batch.times, laser, rel),
        "mount": float(np.abs(mount[:, :2]).max()),
        "note": note,
    }
    out.update(closure_precision(run, mount, rel))
    out["peak_mib"] = _peak_mib()
    # the doubt check of `slam grid` (after the peak: the SLAM's memory is what is measured)
    out["doubts"] = len(doubts_of_run(run, batch))
    return out


def doubts_of_run(run: Any, batch: Any) -> list[dict[str, Any]]:
    """What ``slam grid`` would warn about for ``run`` (``run_submap_slam`` on ``batch``):
    the doubts of its local, consistency and revisit reports (``slam_report.doubts_of``)."""
    from probmap.pipelines.slam_report import (
        consistency_report,
        doubts_of,
        local_report,
        revisit_report,
    )

    check = {
        "local": local_report(run.slam, run.times),
        "consistency": consistency_report(run.times, run.sensor_poses, batch),
        "revisits": revisit_report(run.slam, run.times),
    }
    return doubts_of(check)


def worker_warm(data: Path, end_time: float | None) -> dict[str, Any]:
    """Compile (or load) every kernel graph SLAM and the RBPF use, on the first ``end_time``
    seconds of the hospital log (the 180/181-beam log exercises both scan widths)."""
    from probmap.pipelines.laser_slam import load_laser_log, run_submap_slam

    batch = load_laser_log(data / LOGS["clinic"][1], end_time=end_time)
    run_submap_slam(batch)
    return {"peak_mib": _peak_mib()}


def worker_rbpf(data: Path, end_time: float | None) -> dict[str, Any]:
    from probmap.datasets.carmen import load_scans
    from probmap.metrics.relations import read_relations
    from probmap.pipelines.laser_slam import slam_log
    from probmap.slam.laser.rbpf import RbpfConfig, run_rbpf

    _, log_rel, rel_rel = LOGS["intel"]
    warnings.simplefilter("ignore", UserWarning)
    b = load_scans(data / log_rel, poses="odometry", dtype=np.float32)
    n = 40  # warm the compiled kernels outside the timed run
    run_rbpf(np.asarray(b.times)[:n], np.asarray(b.ranges)[:n], np.asarray(b.angles),
                  np.asarray(b.robot_poses)[:n], b.max_range, RbpfConfig(particles=2))  # fmt: skip
    del b
    t0 = time.perf_counter()
    res = slam_log(data / log_rel, RbpfConfig(), end_time=end_time)
    wall = time.perf_counter() - t0
    rel = _within(read_relations(data / rel_rel), np.asarray(res.times))
    return {
        "scans": len(res.times),
        "slam_s": res.seconds,
        "wall_s": wall,
        "duration": float(res.times[-1] - res.times[0]),
        "relations": len(rel),
        "robot": _errors(res.times, res.poses, rel),
        "peak_mib": _peak_mib(),
    }


# ----------------------------------------------------------------------------- parent
def _spawn(job: str, data: Path, end_time: float | None) -> dict[str, Any]:
    cmd = [sys.executable, __file__, "--worker", job, "--data", str(data)]
    if end_time is not None:
        cmd += ["--end-time", str(end_time)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"worker {job} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _err(e: dict[str, float]) -> tuple[str, str]:
    return (
        f"{e['trans_abs_mean_m']:.4f} ± {e['trans_abs_std_m']:.4f}",
        f"{e['rot_abs_mean_deg']:.2f} ± {e['rot_abs_std_deg']:.2f}",
    )


COLUMNS = (
    "log", "method", "scans", "nodes", "submaps",
    "closures searched / accepted / kept (left out as inconsistent)",
    "precision (agree / verified)", "consistent", "relations", "trans. error m (mean ± std)",
    "rot. error deg (mean ± std)", "loop error m", "doubts", "read s", "SLAM s", "x real time",
    "peak MiB",
)  # fmt: skip


def rows_of(results: dict[str, dict[str, Any]]) -> list[tuple[str, ...]]:
    rows: list[tuple[str, ...]] = []
    for key in KEYS:
        if key not in results:
            continue
        r = results[key]
        name = LOGS[key][0] + (f" ({r['note']})" if r["note"] else "")
        prec = (
            f"{r['agree'] / r['verified']:.3f} ({r['agree']} / {r['verified']})"
            if r["verified"]
            else "-"
        )
        cons = f"{r['consistent'] / max(r['accepted'], 1):.3f}"
        closures = (
            f"{r['searched']:,} / {r['accepted']:,} / {r['kept']:,} ({r.get('left_out', 0):,})"
        )
        timing = (f"{r['read_s']:.1f}", f"{r['slam_s']:.1f}", f"{r['duration'] / r['slam_s']:.1f}",
                  f"{r['peak_mib']:.0f}")  # fmt: skip
        frames = [("robot", "odo_robot", "")]
        if r["mount"] > 1e-6:
            frames.append(("laser", "odo_laser", ", laser poses"))
        for mine, _, suffix in frames:
            loop = (
                f"{r['loop']['trans_abs_mean_m']:.4f}" if mine == "robot" and "loop" in r else "-"
            )
            rows.append((name, f"graph SLAM{suffix}", f"{r['scans']:,}", f"{r['nodes']:,}",
                         f"{r['submaps']:,}", closures, prec, cons, f"{r['relations']:,}",
                         *_err(r[mine]), loop, str(r.get("doubts", "-")), *timing))  # fmt: skip
        for _, odo, suffix in frames:
            odometry = "raw odometry" + (" (/odom)" if key == "bag" else "") + suffix
            rows.append((name, odometry, f"{r['scans']:,}", "-", "-", "-", "-", "-",
                         f"{r['relations']:,}", *_err(r[odo]), "-", "-", "-", "-", "-", "-"))  # fmt: skip
        if key == "intel" and "rbpf" in results:
            b = results["rbpf"]
            rows.append((name, "RBPF, 30 particles", f"{b['scans']:,}", "-", "-", "-", "-", "-",
                         f"{b['relations']:,}", *_err(b["robot"]), "-", "-", "-", f"{b['slam_s']:.1f}",
                         f"{b['duration'] / b['slam_s']:.1f}", f"{b['peak_mib']:.0f}"))  # fmt: skip
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--data",
        type=Path,
        default=Path(
            os.environ.get("PROBMAP_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")
        ),
    )
    ap.add_argument(
        "--end-time", type=float, default=None, help="Use the first SECONDS of each log."
    )
    ap.add_argument("--skip-rbpf", action="store_true", help="Skip the RBPF peer (minutes).")
    ap.add_argument("--markdown", action="store_true", help="Also print the table as Markdown.")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()

    if args.worker is not None:
        if args.worker == "warm":
            out = worker_warm(args.data, args.end_time)
        elif args.worker == "rbpf":
            out = worker_rbpf(args.data, args.end_time)
        else:
            out = worker_graph(args.worker, args.data, args.end_time)
        print(json.dumps(out))
        return

    from rich.console import Console
    from rich.table import Table

    for _, log, rel in LOGS.values():
        for p in (args.data / log, args.data / rel):
            if not p.exists():
                sys.exit(f"missing {p} (set PROBMAP_DATA or --data)")
    results: dict[str, dict[str, Any]] = {}
    # fill numba's on-disk cache in a process of its own first: a kernel compiled inside a
    # measured process leaves LLVM's working memory in its peak RSS (about +30 MiB after a
    # change of the kernels) and its compile time in nothing timed, so peaks would depend on
    # whether the cache happened to be warm
    print("warming the kernel cache ...", file=sys.stderr, flush=True)
    _spawn("warm", args.data, 300.0)
    jobs = [*KEYS] + ([] if args.skip_rbpf else ["rbpf"])
    for job in jobs:
        print(f"running {job} ...", file=sys.stderr, flush=True)
        results[job] = _spawn(job, args.data, args.end_time)
    rows = rows_of(results)
    span = "whole logs" if args.end_time is None else f"first {args.end_time:g} s"
    table = Table(title=f"graph SLAM, default settings, {span}; one process per run")
    for col in COLUMNS:
        table.add_column(col, justify="left" if col in ("log", "method") else "right")
    for row in rows:
        table.add_row(*row)
    Console(width=260).print(table)
    for key in KEYS:
        r = results[key]
        print(f"{LOGS[key][0]}: optimization {r['optimize_s']:.1f} s, closure search "
              f"{r['search_s']:.1f} s of {r['slam_s']:.1f} s")  # fmt: skip
    if args.markdown:
        print()
        print("| " + " | ".join(COLUMNS) + " |")
        print(
            "| " + " | ".join("---" if c in ("log", "method") else "---:" for c in COLUMNS) + " |"
        )
        for row in rows:
            print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
