"""FastSLAM 2.0 (100 particles, shared landmark tree) beside our EKF: time per step at 100 to
2,000 landmarks (issue 22: at 1,000 landmarks FastSLAM 2.0 should be at least as fast per step).

Every run drives the same loop (radius 15 m, same landmark density, so the same number of
observations per step) through a simulated world of ``n`` landmarks. The whole map is in the
state from the start as a prior (each landmark at its true position, 0.5 m standard deviation,
known ids), so both filters really hold ``n`` landmarks while the robot moves: the EKF a
``(3 + 2n)^2`` covariance, FastSLAM one tree shared by its particles (``FastSLAM.add_landmarks``).
Times are per step (predict + update), median and mean over the timed steps (the first fifth
is warm-up), one BLAS thread, the same process. The tree's copy count per step is the
``O(M log n)`` of the book; the flat store (``--flat``) copies ``O(M n)`` on every resample.

Run: ``python benchmarks/bench_fastslam.py`` (``--quick`` for a short smoke run).
"""

from __future__ import annotations

import argparse
import os
import sys

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core, as the CLI runs (set before numpy loads)

import numpy as np  # noqa: E402

from probmap.datasets.simulation import simulate_landmarks  # noqa: E402
from probmap.slam.landmark.fastslam import FastSLAM, FastSLAMConfig  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_seif import PRIOR_SD, _ekf_with_prior, _time_steps  # noqa: E402


def _fastslam_with_prior(ds, lm: np.ndarray, particles: int, store: str) -> FastSLAM:
    fs = FastSLAM(ds.motion_model, ds.measurement_model, ds.initial_pose,
                  FastSLAMConfig(particles, 2, seed=0, landmark_store=store))  # fmt: skip
    n = lm.shape[0]
    fs.add_landmarks(np.arange(n), lm, np.broadcast_to(PRIOR_SD**2 * np.eye(2), (n, 2, 2)))
    return fs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--sizes", default="100,1000,2000")
    ap.add_argument("--flat", action="store_true", help="also time the flat landmark store")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    sizes = [int(v) for v in args.sizes.split(",")]
    steps_n = args.steps
    if args.quick:
        sizes, steps_n = [100, 1000], 100
    warm = steps_n // 5
    stores = ["tree", "flat"] if args.flat else ["tree"]
    rows = []
    for n in sizes:
        ds = simulate_landmarks(n, steps_n, seed=1, density=0.03, loop_radius=15.0)
        lm = ds.landmarks_xy
        assert lm is not None  # a simulation carries its true landmarks
        steps = list(ds)
        row: dict[str, float] = {"n": n, "obs": float(np.mean([s.z.shape[0] for s in steps]))}
        for store in stores:
            fs = _fastslam_with_prior(ds, lm, args.particles, store)
            copied0 = fs.store.nodes_copied if store == "tree" else 0
            t = _time_steps(fs, steps)[warm:]
            row[f"{store}_ms"] = 1e3 * float(np.median(t))
            row[f"{store}_mean_ms"] = 1e3 * float(np.mean(t))
            row[f"{store}_mib"] = fs.state_nbytes() / 2**20
            if store == "tree":
                row["copied_per_step"] = (fs.store.nodes_copied - copied0) / len(steps)
                row["resamples"] = fs.resamples
        ekf = _ekf_with_prior(ds, lm)
        t = _time_steps(ekf, steps)[warm:]
        row["ekf_ms"] = 1e3 * float(np.median(t))
        row["ekf_mean_ms"] = 1e3 * float(np.mean(t))
        row["ekf_mib"] = 8.0 * (3 + 2 * n) ** 2 / 2**20
        rows.append(row)
        print(f"done n={n}", flush=True)

    flat_head = " | FS2 flat median ms | FS2 flat MiB" if args.flat else ""
    print(
        f"\nFastSLAM 2.0, {args.particles} particles, tree store; {steps_n} steps, the first "
        f"{warm} not timed\n"
    )
    print(
        "| landmarks | obs/step | EKF median ms | EKF mean ms | FS2 median ms | FS2 mean ms "
        f"| EKF / FS2 (median) | EKF / FS2 (mean) | FS2 tree nodes copied/step | resamples "
        f"| EKF MiB | FS2 MiB{flat_head} |"
    )
    print("|---:" * (12 + 2 * len(stores) - 2) + "|")
    for r in rows:
        flat = f" | {r['flat_ms']:.3f} | {r['flat_mib']:.2f}" if args.flat else ""
        print(
            f"| {int(r['n']):,} | {r['obs']:.1f} | {r['ekf_ms']:.3f} | {r['ekf_mean_ms']:.3f} "
            f"| {r['tree_ms']:.3f} | {r['tree_mean_ms']:.3f} "
            f"| {r['ekf_ms'] / r['tree_ms']:.2f} | {r['ekf_mean_ms'] / r['tree_mean_ms']:.2f} "
            f"| {r['copied_per_step']:.0f} | {int(r['resamples'])} | {r['ekf_mib']:.1f} "
            f"| {r['tree_mib']:.2f}{flat} |"
        )


if __name__ == "__main__":
    main()
