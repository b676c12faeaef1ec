"""Loop-closure search: branch and bound beside brute force over the same window, one core.

Usage::

    python benchmarks/bench_loop_closure.py [--trials 20] [--brute-trials 5] [--seed 0]

The submap is the simulated building of ``probmap.sim.floorplan`` (20 x 12 m, rooms off a
corridor, 0.05 m cells) mapped with the true poses, its match field ``sigma = 0.05 m`` (the
graph-SLAM matcher's). Each trial takes a scan of the tour (180 endpoints, 8 m range, 180 deg)
and a window centre off its true pose by up to 70 % of the window in x, y and heading; the
heading step is the default (one cell at the farthest endpoint). Per window: branch and bound
(``min_score`` 0 and 0.55, the front end's threshold) on every trial, brute force on the first
``--brute-trials`` (speed-up = median of the per-trial time ratios; "same" = the same pose and
score bit for bit), and how often the best pose lies within 0.1 m and 2 deg of the truth (the
building repeats its rooms every 4 m, so a wide window can hold a better-scoring twin, and a
scan of a single wall scores as well anywhere along it).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--brute-trials", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    from rich.console import Console
    from rich.table import Table

    from probmap.geometry.se2 import wrap_angle
    from probmap.grid.occupancy import OccupancyGrid
    from probmap.sim.floorplan import simulate_laser_world
    from probmap.slam.laser.loop_closure import (
        PrecomputedGrids,
        branch_and_bound_search,
        brute_force_search,
    )
    from probmap.slam.laser.scan_matching import MatchField, scan_points

    world = simulate_laser_world(seed=1, range_noise=0.01)
    grid = OccupancyGrid(resolution=0.05)
    grid.integrate_scans(world.poses, world.ranges, world.angles, max_range=world.max_range)
    field = MatchField.from_grid(grid, sigma=0.05)
    PrecomputedGrids.from_field(field)  # compile
    t0 = time.perf_counter()
    grids = {d: PrecomputedGrids.from_field(field, depth=d) for d in (6, 7)}
    pre_ms = (time.perf_counter() - t0) / 2 * 1e3
    console = Console(width=160)
    h, w = field.values.shape
    console.print(
        f"submap {h} x {w} cells; max-grids (depth 6) {grids[6].nbytes / 2**20:.2f} MiB, "
        f"built in {pre_ms:.1f} ms"
    )

    rng = np.random.default_rng(args.seed)
    windows = [(1.0, 20.0), (3.0, 25.0), (7.0, 30.0)]
    table = Table(title="loop-closure search, 180 points, 0.05 m cells (times in ms)")
    for col in ("window", "depth", "headings", "candidates", "B&B median", "B&B max",
                "nodes scored", "B&B min 0.55", "brute force", "speed-up", "same",
                "truth found"):  # fmt: skip
        table.add_column(col, justify="right")
    for lin, ang_deg in windows:
        ang = math.radians(ang_deg)
        trials = []
        for k in rng.choice(len(world.poses), args.trials, replace=False):
            pts = scan_points(world.ranges[k], world.angles, world.max_range)
            pts = pts[np.linspace(0, len(pts) - 1, min(180, len(pts))).astype(int)]
            err = rng.uniform(-0.7, 0.7, 3) * np.array([lin, lin, ang])
            trials.append((pts, world.poses[k], world.poses[k] + err))
        branch_and_bound_search(grids[6], trials[0][0], trials[0][2], lin, ang)  # compile
        brute_force_search(grids[6], trials[0][0], trials[0][2], 0.1, 0.01)
        for depth in (6, 7) if lin == 7.0 else (6,):
            g = grids[depth]
            times, times_ms, nodes, cands, heads, found = [], [], [], [], [], 0
            brute, ratios, same = [], [], 0
            for i, (pts, truth, centre) in enumerate(trials):
                t = time.perf_counter()
                r = branch_and_bound_search(g, pts, centre, lin, ang)
                times.append(time.perf_counter() - t)
                t = time.perf_counter()
                branch_and_bound_search(g, pts, centre, lin, ang, min_score=0.55)
                times_ms.append(time.perf_counter() - t)
                assert r is not None
                nodes.append(r.evaluated)
                cands.append(r.candidates)
                heads.append(2 * math.floor(ang / r.angular_step + 1e-9) + 1)
                err_xy = math.hypot(r.pose[0] - truth[0], r.pose[1] - truth[1])
                err_th = abs(float(wrap_angle(r.pose[2] - truth[2])))
                found += err_xy <= 0.1 and err_th <= math.radians(2.0)
                if i < args.brute_trials and depth == 6:
                    t = time.perf_counter()
                    b = brute_force_search(g, pts, centre, lin, ang)
                    brute.append(time.perf_counter() - t)
                    ratios.append(brute[-1] / times[-1])
                    assert b is not None
                    same += b.score == r.score and bool(np.array_equal(b.pose, r.pose))
            table.add_row(
                f"±{lin:g} m ±{ang_deg:g}°",
                str(depth),
                f"{np.median(heads):.0f}",
                f"{np.median(cands):,.0f}",
                f"{np.median(times) * 1e3:.2f}",
                f"{np.max(times) * 1e3:.2f}",
                f"{np.median(nodes):,.0f}",
                f"{np.median(times_ms) * 1e3:.2f}",
                f"{np.median(brute) * 1e3:,.0f}" if brute else "-",
                f"{np.median(ratios):,.0f}x" if ratios else "-",
                f"{same}/{len(ratios)}" if ratios else "-",
                f"{found}/{len(trials)}",
            )
    console.print(table)


if __name__ == "__main__":
    main()
