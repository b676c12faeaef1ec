"""Grid SLAM on simulated featureless corridor loops: the plain improved proposal beside the
degeneracy-guarded one (the default), with the odometry, in the same run.

Usage::

    python benchmarks/bench_grid_slam_corridor.py [--seeds 4] [--particles 10]

Per seed: a 92 m ring of 2 m wide, 36 m long featureless corridors (8 m laser range), driven
1.1 times; the worst and the final position error relative to the start, metres.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--particles", type=int, default=10)
    args = ap.parse_args()

    from rich.console import Console
    from rich.table import Table

    from probmap.geometry.se2 import between
    from probmap.sim.corridor import simulate_corridor_loop
    from probmap.slam.laser.rbpf import RbpfConfig, run_rbpf

    warnings.simplefilter("ignore", UserWarning)
    table = Table(title=f"featureless corridor loop, {args.particles} particles")
    for col in ("seed", "odometry worst m", "plain worst m", "plain final m", "guarded worst m",
                "guarded final m", "plain s", "guarded s"):  # fmt: skip
        table.add_column(col, justify="right")
    for seed in range(args.seeds):
        w = simulate_corridor_loop(seed=seed)
        truth = between(w.poses[0], w.poses)

        def errors(poses: np.ndarray, truth: np.ndarray = truth) -> np.ndarray:
            d = between(poses[0], poses) - truth
            return np.hypot(d[:, 0], d[:, 1])

        cells = [str(seed), f"{errors(w.odometry).max():.2f}"]
        secs = []
        for guard in (False, True):
            cfg = RbpfConfig(particles=args.particles, seed=seed, degeneracy_guard=guard)
            t0 = time.perf_counter()
            res = run_rbpf(w.times, w.ranges, w.angles, w.odometry, w.max_range, cfg)
            secs.append(time.perf_counter() - t0)
            e = errors(res.poses)
            cells += [f"{e.max():.2f}", f"{e[-1]:.2f}"]
        table.add_row(*cells, *(f"{s:.1f}" for s in secs))
    Console(width=150).print(table)


if __name__ == "__main__":
    main()
