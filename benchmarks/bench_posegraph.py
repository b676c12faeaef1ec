"""Pose-graph optimization: probmap's Levenberg-Marquardt beside GTSAM 4.3's, same run, one core.

For each standard 2-D graph in ``$PROBMAP_DATA/pose-graphs`` (fallback ``../shared/data``
beside the repository; the data README's section 7 lists them), both optimizers start from the
file's poses (vertex-less files chained from odometry) and report GTSAM's error: ``0.5 * sum
e' Omega e`` plus a prior on the first pose (variances 1e-6, 1e-6, 1e-8). GTSAM runs its
default ``LevenbergMarquardtOptimizer`` (``load2D`` with the file's information order, the
prior factor, construction + ``optimize()``); probmap runs ``optimize_pose_graph`` with its
default config, from the file's poses (``given``) and from its LAGO estimate (``lago``), both
timed from arrays to optimized poses (validation, pattern, initialization, LM). Each time is
the median of ``--repeats`` runs after one warm-up, interleaved. The process is pinned to one
CPU and BLAS/OpenMP are limited to one thread, so both libraries run on one core.

Run:  python benchmarks/bench_posegraph.py [--graphs M3500.g2o,intel.g2o] [--repeats 3]
Prints a markdown table: graph, nodes, edges, initial error, then for GTSAM and each probmap
start the final error, iterations and milliseconds, and probmap's time over GTSAM's.

``--incremental`` instead times :class:`PoseGraph2D` the way a SLAM front end uses it: a
simulated 2,000-pose walk through a 4 x 4 block town with noisy odometry and up to 12 loop
closures per pose to earlier poses within 4 m (about 20,000 edges, the closures under DCS),
re-optimized (warm start, at most 10 iterations) every 100 poses.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "TBB_NUM_THREADS"):
    os.environ[_var] = "1"
if hasattr(os, "sched_setaffinity"):  # one core for everything, TBB included (Linux)
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

import time  # noqa: E402

import numpy as np  # noqa: E402

from probmap.datasets.g2o import pose_graph_arrays, read_pose_graph  # noqa: E402
from probmap.slam.posegraph.optimize import optimize_pose_graph  # noqa: E402

GRAPHS = [
    "M3500.g2o",
    "M3500a.g2o",
    "M3500b.g2o",
    "manhattanOlson3500.g2o",
    "intel.g2o",
    "INTEL_P_toro.graph",
    "MITb.g2o",
    "CSAIL_P_toro.graph",
    "FR079_P_toro.graph",
    "FRH_P_toro.graph",
    "city10000.g2o",
    "kitti_00.g2o",
    "ring.g2o",
    "ringCity.g2o",
    "w10000.graph",
    "w100.graph",
    "pose2example.txt",
    "noisyToyGraph.txt",
]


def data_root() -> Path:
    env = os.environ.get("PROBMAP_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "data"


def gtsam_problem(gtsam, path: Path, toro: bool):
    """GTSAM's graph and initial values as its reference harness builds them."""
    fmt = gtsam.NoiseFormat.NoiseFormatTORO if toro else gtsam.NoiseFormat.NoiseFormatG2O
    graph, initial = gtsam.load2D(str(path), None, 0, False, True, fmt)
    first = min(initial.keys())
    prior = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))
    graph.add(gtsam.PriorFactorPose2(first, initial.atPose2(first), prior))
    return graph, initial


def run_gtsam(gtsam, graph, initial):
    t0 = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams())
    result = opt.optimize()
    seconds = time.perf_counter() - t0
    return graph.error(result), opt.iterations(), seconds


def run_probmap(a, init):
    t0 = time.perf_counter()
    r = optimize_pose_graph(a.poses, a.edges, a.measurements, a.information, init=init)
    seconds = time.perf_counter() - t0
    return r.final_error, r.iterations, seconds, r.initial_error


def verdict(ours: float, theirs: float, gtsam_capped: bool) -> str:
    rel = (ours - theirs) / abs(theirs)
    if abs(rel) <= 1e-6:
        return "same"
    if rel < 0:
        return "lower" + ("" if gtsam_capped else f" ({rel:.1e})")
    return f"HIGHER (+{rel:.1e})"


def incremental(every: int = 100, n: int = 2000, closures: int = 12) -> None:
    """Time PoseGraph2D re-optimizations on a growing graph (see the module docstring)."""
    from probmap.geometry.se2 import between, compose
    from probmap.slam.posegraph.optimize import OptimizerConfig, PoseGraph2D

    rng = np.random.default_rng(0)
    truth = np.zeros((n, 3))
    for i in range(1, n):  # 1 m steps on the streets of a 4 x 4 block town (10 m blocks)
        turn = 0.0
        if i % 10 == 1 and i > 1:  # at a crossing: any turn that stays in town
            x, y, th = truth[i - 1]
            options = [
                t
                for t in (0.0, np.pi / 2, -np.pi / 2)
                if -0.5 <= x + 10 * np.cos(th + t) <= 40.5
                and -0.5 <= y + 10 * np.sin(th + t) <= 40.5
            ] or [np.pi]
            turn = float(rng.choice(options))
        truth[i - 1, 2] += turn  # turn on the spot at the crossing, then step
        truth[i] = compose(truth[i - 1], [1.0, 0.0, 0.0])
    sigma = np.array([0.02, 0.01, 0.005])
    info_odo = np.diag(sigma**-2.0)
    info_lc = np.diag([100.0, 100.0, 1000.0])
    g = PoseGraph2D(OptimizerConfig(robust="dcs"))  # the loop closures under DCS
    g.add_node(truth[0])
    last = truth[0]
    calls = []
    t_total = time.perf_counter()
    for i in range(1, n):
        z = between(truth[i - 1], truth[i]) + rng.normal(0, sigma)
        last = compose(last, z)  # dead reckoning from the latest estimate
        g.add_node(last)
        g.add_edge(i - 1, i, z, info_odo)
        near = np.flatnonzero(
            np.linalg.norm(truth[: max(i - 20, 0), :2] - truth[i, :2], axis=1) < 3
        )
        for j in rng.permutation(near)[:closures]:
            zc = between(truth[j], truth[i]) + rng.normal(0, [0.05, 0.05, 0.01])
            g.add_edge(int(j), i, zc, info_lc, robust=True)
        if (i + 1) % every == 0:
            r = g.optimize(max_iterations=10)
            last = r.poses[-1]
            calls.append((g.num_nodes, g.num_edges, r.seconds, r.iterations))
    t_total = time.perf_counter() - t_total
    print("| nodes | edges | optimize ms | iterations |")
    print("|---:|---:|---:|---:|")
    for nodes, edges, sec, its in calls[4::5]:
        print(f"| {nodes:,} | {edges:,} | {1e3 * sec:.1f} | {its} |")
    opt = sum(c[2] for c in calls)
    print(f"\n{len(calls)} re-optimizations: {opt:.2f} s of {t_total:.2f} s in all")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graphs", default=",".join(GRAPHS), help="comma-separated file names")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per solver (median)")
    parser.add_argument(
        "--starts", default="given,lago", help="probmap starts to run: given, lago or both"
    )
    parser.add_argument(
        "--incremental", action="store_true", help="time PoseGraph2D re-optimizations instead"
    )
    args = parser.parse_args()
    if args.incremental:
        incremental()
        return 0
    import gtsam

    starts = [s for s in args.starts.split(",") if s]
    root = data_root() / "pose-graphs"
    if not root.is_dir():
        print(f"no pose graphs at {root} (set PROBMAP_DATA)", file=sys.stderr)
        return 1
    head = "| graph | nodes | edges | initial error | GTSAM final | it | ms |"
    rule = "|---|---:|---:|---:|---:|---:|---:|"
    for s in starts:
        head += f" probmap {s} final | vs GTSAM | it | ms | time ratio |"
        rule += "---:|---|---:|---:|---:|"
    from importlib.metadata import version

    print(f"GTSAM {version('gtsam')}, one core; times: median of {args.repeats}\n")
    print(head)
    print(rule)
    for name in args.graphs.split(","):
        path = root / name
        g = read_pose_graph(path)
        a = pose_graph_arrays(g)
        graph, initial = gtsam_problem(gtsam, path, g.format == "toro")
        # warm-up (numba's cache, allocators), then interleaved timed runs
        run_gtsam(gtsam, graph, initial)
        for s in starts:
            run_probmap(a, s)
        runs_g, runs_p = [], {s: [] for s in starts}
        for _ in range(args.repeats):
            runs_g.append(run_gtsam(gtsam, graph, initial))
            for s in starts:
                runs_p[s].append(run_probmap(a, s))
        F_g, it_g, _ = runs_g[-1]
        t_g = float(np.median([r[2] for r in runs_g]))
        F0 = runs_p[starts[0]][-1][3]
        if abs(F0 - graph.error(initial)) > 1e-9 * abs(F0):
            print(f"warning: {name}: initial errors differ", file=sys.stderr)
        capped = it_g >= gtsam.LevenbergMarquardtParams().getMaxIterations()
        row = f"| {name} | {len(a.ids):,} | {len(a.edges):,} | {F0:.6g} | {F_g:.6g}"
        row += f" | {it_g}{' (cap)' if capped else ''} | {1e3 * t_g:.3g} |"
        for s in starts:
            F_p, it_p, _, _ = runs_p[s][-1]
            t_p = float(np.median([r[2] for r in runs_p[s]]))
            row += f" {F_p:.6g} | {verdict(F_p, F_g, capped)} | {it_p} | {1e3 * t_p:.3g} |"
            row += f" {t_p / t_g:.2f} |"
        print(row, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
