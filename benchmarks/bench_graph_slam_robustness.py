"""How graph SLAM's one default configuration holds up when the data is not what it was built on
(issue 18: "build for data you have not seen").

Each row runs ``run_submap_slam`` with the default ``SubmapSlamConfig`` on a perturbed copy of a
real log and scores it with the log's relations (Kuemmerle et al. 2009), the same metric as
``bench_graph_slam.py``. The perturbations stand for the ways another robot's log differs:

- ``odometry x S``: every odometry increment's translation scaled by ``S`` (uncalibrated wheel
  radius; the odometry poses are re-integrated from the scaled increments),
- ``rotation x S``: every increment's rotation scaled by ``S`` (wrong wheel base),
- ``drift D rad/m``: a heading drift of ``D`` radians per metre travelled (unequal wheels),
- ``range noise S m``: Gaussian noise of ``S`` metres added to every return (a noisier laser;
  a SICK LMS is about 0.01 m),
- ``every Nth scan``: only every ``N``-th scan kept (a slower laser or a dropped topic),
- ``max range R m``: returns beyond ``R`` metres turned into no-returns (a shorter-range laser).

The noise is seeded, graph SLAM is deterministic, so the errors are reproducible; the time is
the wall time of one core (shown for scale only). "doubts" counts the places and spans that
``probmap slam grid`` would warn about on the same run (``slam_report.doubts_of``): a copy that
breaks with no doubt is a silently wrong map. One process per row, so one row's memory and
compiled kernels do not leak into the next.

Run: ``PROBMAP_DATA=../shared/data python benchmarks/bench_graph_slam_robustness.py
[--log intel|clinic] [--cases base,odometry:1.05,...] [--set FIELD=VALUE ...] [--jobs N]
[--markdown]``. ``--set`` changes a ``SubmapSlamConfig`` field for every row (as in
``graph_slam_diagnose.py``: ``max_window=40,0.5``, ``matcher.sigma=0.035``), to judge a
candidate default on all the rows at once; ``--jobs`` runs that many rows side by side (their
times are then for scale only). The last line is the sum of the rows' mean errors.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import replace
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
CASES = (
    "base",
    "odometry:1.05",
    "odometry:0.95",
    "rotation:1.03",
    "drift:0.01",
    "noise:0.015",
    "noise:0.03",
    "every:2",
    "maxrange:15",
)


def describe(case: str) -> str:
    kind, _, value = case.partition(":")
    return {
        "base": "as logged",
        "odometry": f"odometry x {value}",
        "rotation": f"rotation x {value}",
        "drift": f"drift {value} rad/m",
        "noise": f"range noise {value} m",
        "every": f"every {value}nd scan" if value == "2" else f"every {value}th scan",
        "maxrange": f"max range {value} m",
    }[kind]


def _reintegrate(robot: np.ndarray, trans: float, rot: float, drift: float) -> np.ndarray:
    """Odometry poses re-integrated from increments with scaled translation and rotation and
    a heading drift per metre."""
    from probmap.geometry.se2 import between, compose

    inc = np.array(between(robot[:-1], robot[1:]), dtype=float)
    dist = np.hypot(inc[:, 0], inc[:, 1])
    inc[:, :2] *= trans
    inc[:, 2] = inc[:, 2] * rot + drift * dist
    out = np.empty_like(robot)
    out[0] = robot[0]
    for i in range(len(inc)):
        out[i + 1] = compose(out[i], inc[i])
    return out


def perturb(batch: Any, case: str, seed: int = 0) -> Any:
    """A copy of ``batch`` (``load_laser_log``) perturbed as ``case`` says."""
    from probmap.geometry.se2 import between, compose

    kind, _, value = case.partition(":")
    if kind == "base":
        return batch
    v = float(value)
    robot = np.asarray(batch.robot_poses, float)
    laser = np.asarray(batch.laser_poses, float)
    if kind in ("odometry", "rotation", "drift"):
        args = {"odometry": (v, 1.0, 0.0), "rotation": (1.0, v, 0.0), "drift": (1.0, 1.0, v)}
        new = _reintegrate(robot, *args[kind])
        return replace(batch, robot_poses=new, laser_poses=compose(new, between(robot, laser)))
    if kind == "noise":
        rng = np.random.default_rng(seed)
        r = np.asarray(batch.ranges, float)
        hit = r < batch.max_range
        noisy = np.where(hit, np.maximum(r + rng.normal(0.0, v, r.shape), 0.01), r)
        return replace(batch, ranges=noisy.astype(np.asarray(batch.ranges).dtype))
    if kind == "every":
        return batch.rows(slice(None, None, int(v)))
    if kind == "maxrange":
        r = np.asarray(batch.ranges).copy()
        r[r > v] = batch.max_range
        return replace(batch, ranges=r)
    raise ValueError(f"unknown case {case!r}")


def worker(data: Path, log: str, case: str, settings: list[str]) -> dict[str, Any]:
    from graph_slam_diagnose import configure
    from probmap.metrics.relations import read_relations, relation_errors
    from probmap.pipelines.laser_slam import load_laser_log, run_submap_slam

    log_rel, rel_rel = LOGS[log]
    batch = perturb(load_laser_log(data / log_rel), case)
    config = configure(settings)
    t0 = time.perf_counter()
    run = run_submap_slam(batch, config)
    wall = time.perf_counter() - t0
    rel = read_relations(data / rel_rel)
    e = relation_errors(np.asarray(run.times), np.asarray(run.poses), rel)
    odo = relation_errors(np.asarray(batch.times), np.asarray(batch.robot_poses, float), rel)
    w = np.asarray(run.closure_weights)
    # what `slam grid` would warn about (after the timing: the check is not SLAM's cost)
    from bench_graph_slam import doubts_of_run

    doubts = doubts_of_run(run, batch)
    return {
        "case": case,
        "mean": float(e.translation.mean()),
        "std": float(e.translation.std()),
        "p95": float(np.percentile(e.translation, 95)),
        "odometry": float(odo.translation.mean()),
        "accepted": len(w),
        "kept": int((w >= 0.5).sum()),
        "doubts": len(doubts),
        "seconds": wall,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[2] / "shared" / "data"
    ap.add_argument("--data", type=Path, default=Path(os.environ.get("PROBMAP_DATA", default)))
    ap.add_argument("--log", choices=sorted(LOGS), default="intel")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--markdown", action="store_true")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker is not None:
        print(json.dumps(worker(args.data, args.log, args.worker, args.set)))
        return
    if args.jobs < 1:
        ap.error(f"--jobs must be at least 1, got {args.jobs}")
    from graph_slam_diagnose import configure

    try:  # a misspelt field fails here, once, not in every worker
        configure(args.set)
    except (TypeError, ValueError) as exc:
        ap.error(f"--set: {exc}")
    cmd = [sys.executable, __file__, "--data", str(args.data), "--log", args.log]
    for s in args.set:
        cmd += ["--set", s]
    cases = args.cases.split(",")
    procs: dict[str, subprocess.Popen[str]] = {}
    results: dict[str, dict[str, Any]] = {}
    pending = list(cases)
    while pending or procs:
        while pending and len(procs) < args.jobs:
            case = pending.pop(0)
            print(f"running {case} ...", file=sys.stderr, flush=True)
            procs[case] = subprocess.Popen(
                [*cmd, "--worker", case], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
            )
        case = next(iter(procs))
        proc = procs.pop(case)
        out, err = proc.communicate()
        if proc.returncode != 0:
            sys.exit(f"{case} failed:\n{err[-2000:]}")
        results[case] = json.loads(out.strip().splitlines()[-1])
    rows = [results[c] for c in cases]
    base = next((r["mean"] for r in rows if r["case"] == "base"), None)
    head = ("perturbation", "relation error m (mean ± std)", "p95 m", "vs as logged",
            "odometry alone m", "closures accepted / kept", "doubts", "SLAM s")  # fmt: skip
    lines = []
    for r in rows:
        ratio = f"{r['mean'] / base:.2f}x" if base else "-"
        lines.append((describe(r["case"]), f"{r['mean']:.4f} ± {r['std']:.4f}", f"{r['p95']:.3f}",
                      ratio, f"{r['odometry']:.3f}", f"{r['accepted']:,} / {r['kept']:,}",
                      str(r["doubts"]), f"{r['seconds']:.0f}"))  # fmt: skip
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"graph SLAM defaults on perturbed copies of {args.log}")
    for h in head:
        table.add_column(h, justify="left" if h == "perturbation" else "right")
    for line in lines:
        table.add_row(*line)
    Console(width=200).print(table)
    if args.markdown:
        print("| " + " | ".join(head) + " |")
        print("|---" + "|---:" * (len(head) - 1) + "|")
        for line in lines:
            print("| " + " | ".join(line) + " |")
    settings = " ".join(args.set) or "defaults"
    print(f"sum of the rows' mean errors ({settings}): {sum(r['mean'] for r in rows):.4f} m")


if __name__ == "__main__":
    main()
