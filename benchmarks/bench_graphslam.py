"""GraphSLAM against the EKF on real logs and on simulation (issue 22).

Runs EKF SLAM and GraphSLAM (each with its dataset defaults: ``default_ekf_config`` and
``default_graphslam_config``) on MRCLAM Dataset 7 robots 1-3 (known ids, whole logs, against
Vicon) and on seeded simulations (25 landmarks, 150 steps), in one process, single-threaded
BLAS. Prints one markdown table: robot position RMSE raw (map frame) and SE(2)-aligned, landmark
RMSE raw and aligned, pose ANEES, wall time of the whole run (GraphSLAM: recording the log plus
the batch solve), and the GraphSLAM solve's iterations. On simulation it also counts the seeds
where GraphSLAM's robot RMSE (map frame, then aligned) is at or below the EKF's, and the mean
cross term of ``|e_f|^2 = |e_s|^2 + |d|^2 + 2 e_s.d`` (EKF error ``e_f``, GraphSLAM error
``e_s``, ``d = e_f - e_s``), zero when GraphSLAM is the optimal smoother: then the EKF can come
out ahead in a run only through that zero-mean term.

Victoria Park (unknown correspondences: GraphSLAM's front end, batch solve and Table 11.8
merges) is in ``benchmarks/bench_landmark_family.py`` with the other estimators and GTSAM.

Run: ``PROBMAP_DATA=../shared/data python benchmarks/bench_graphslam.py [--robots 1,2,3]
[--seeds 20] [--end-time S]``.
"""

from __future__ import annotations

import argparse
import os
import time

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from probmap.datasets import registry  # noqa: E402
from probmap.datasets.simulation import simulate_landmarks  # noqa: E402
from probmap.pipelines.landmark_slam import (  # noqa: E402
    default_ekf_config,
    default_graphslam_config,
    evaluate,
    run_landmark_slam,
)
from probmap.slam.landmark.ekf import EKFSLAM  # noqa: E402
from probmap.slam.landmark.graphslam import build_graphslam  # noqa: E402


def _get(m: dict[str, Any], *keys: str) -> float:
    v: Any = m
    for k in keys:
        if not isinstance(v, dict) or k not in v:
            return float("nan")
        v = v[k]
    return float(v)


def _run(ds: Any, method: str, trajectories: list[Any] | None = None) -> dict[str, float]:
    if method == "EKF":
        est: Any = EKFSLAM(
            ds.motion_model,
            ds.measurement_model,
            ds.initial_pose,
            ds.initial_covariance,
            default_ekf_config(ds),
        )
    else:
        est = build_graphslam(ds, default_graphslam_config(ds))
    t0 = time.perf_counter()
    res = run_landmark_slam(est, ds)
    seconds = time.perf_counter() - t0
    if trajectories is not None:
        trajectories.append(res.trajectory)
    m = evaluate(res, ds, with_dead_reckoning=False)
    out = {
        "robot": _get(m, "ate", "translation_m", "rmse"),
        "robot_aligned": _get(m, "ate_aligned", "translation_m", "rmse"),
        "landmark": _get(m, "landmarks", "error_m", "rmse"),
        "landmark_aligned": _get(m, "landmarks_aligned", "error_m", "rmse"),
        "anees": _get(m, "pose_nees", "mean"),
        "seconds": seconds,
        "iterations": float("nan"),
    }
    if method == "GraphSLAM":
        out["iterations"] = float(est.result.iterations)
        out["solve_seconds"] = float(est.result.seconds)
    return out


def _row(name: str, method: str, r: dict[str, float]) -> str:
    its = "-" if np.isnan(r["iterations"]) else f"{int(r['iterations'])}"
    return (
        f"| {name} | {method} | {r['robot']:.3f} | {r['robot_aligned']:.3f} | "
        f"{r['landmark']:.3f} | {r['landmark_aligned']:.3f} | {r['anees']:.1f} | "
        f"{r['seconds']:.1f} | {its} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--robots", default="1,2,3")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--end-time", type=float, default=None)
    args = ap.parse_args()
    print(
        "| data | method | robot RMSE m | aligned | landmark RMSE m | aligned | pose ANEES | "
        "time s | GN iterations |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for robot in [int(r) for r in args.robots.split(",") if r]:
        ds = registry.load("mrclam7", robot=robot, end_time=args.end_time)
        for method in ("EKF", "GraphSLAM"):
            print(_row(f"MRCLAM 7 robot {robot}", method, _run(ds, method)), flush=True)
    if args.seeds:
        runs: dict[str, list[dict[str, float]]] = {"EKF": [], "GraphSLAM": []}
        cross = []
        for seed in range(args.seeds):
            sim = simulate_landmarks(25, 150, seed=100 + seed, density=0.06)
            traj: list[Any] = []
            for method in runs:
                runs[method].append(_run(sim, method, traj))
            # e_f = e_s + d: the EKF's error is GraphSLAM's plus the difference of the estimates
            truth = np.asarray(sim.true_poses)[1:, :2]
            e_f, e_s = (t[:, 1:3] - truth for t in traj)
            cross.append(2.0 * float(np.sum(e_s * (e_f - e_s))))
        for method, rs in runs.items():
            mean = {k: float(np.mean([r[k] for r in rs])) for k in rs[0]}
            print(_row(f"simulation, mean of {args.seeds} seeds", method, mean))
        print()
        for key in ("robot", "robot_aligned"):
            ratio = np.array(
                [g[key] / e[key] for g, e in zip(runs["GraphSLAM"], runs["EKF"], strict=True)]
            )
            print(
                f"simulation, GraphSLAM / EKF {key.replace('_', ' ')} RMSE per seed: mean "
                f"{ratio.mean():.3f}, min {ratio.min():.3f}, max {ratio.max():.3f}, at or below "
                f"1 in {int((ratio <= 1).sum())} of {ratio.size}"
            )
        c = np.array(cross)
        print(
            "simulation, cross term 2 e_s.d of |e_f|^2 = |e_s|^2 + |d|^2 + 2 e_s.d (m^2, sum "
            f"over a run): mean {c.mean():.4f}, standard error "
            f"{c.std(ddof=1) / np.sqrt(c.size):.4f} (zero for the optimal smoother)"
        )


if __name__ == "__main__":
    main()
