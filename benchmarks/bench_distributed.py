"""Distributed mapping on a Dask LocalCluster beside sequential mapping in this process.

Three workloads, each timed as: sequential (``map_log`` / one grid, in this process, the
reference), then ``map_logs_distributed`` on a LocalCluster of 1 and of 2 single-threaded worker
processes, started by ``probmap.pipelines.distributed.local_cluster`` as ``probmap map --workers N`` does
(cluster start-up timed apart; every worker loads the compiled kernels before timing). Every
time is the best of ``--repeat`` runs, sequential and Dask alike (the machine's other load only
ever adds time):

* the raw Intel log (13 631 scans) split into ``--chunks`` chunks (read once, then one task per
  chunk and a tree sum);
* ``--logs`` simulated logs of a fleet touring the same building (CARMEN files written here),
  one task per log;
* the overhead per task: the Intel log in 4 and in 64 chunks on the largest cluster,
  ``(t64 - t4) / (tasks64 - tasks4)``, and an empty Dask task's round trip.

Prints a table of wall times and speed-ups over the sequential run of the same workload.

Run:  python benchmarks/bench_distributed.py [--chunks 8] [--logs 48] [--workers 1 2] [--repeat 3]
      [--no-intel]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

INTEL = Path(__file__).resolve().parents[1] / "shared" / "data" / "intel-research-lab"
INTEL_ALT = Path("/work/shared/data/intel-research-lab")


def write_carmen(path: Path, poses: np.ndarray, ranges: np.ndarray, max_range: float) -> Path:
    """A minimal CARMEN log (format: /work/shared/data/README.md): PARAM + FLASER lines."""
    lines = [f"PARAM robot_front_laser_max {max_range}"]
    for i, (p, r) in enumerate(zip(poses, ranges, strict=True)):
        rs = " ".join("nan" if not np.isfinite(v) else f"{v:.3f}" for v in r)
        pose = f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}"
        lines.append(f"FLASER {len(r)} {rs} {pose} {pose} {i * 0.1:.3f} sim {i * 0.1:.3f}")
    path.write_text("\n".join(lines) + "\n")
    return path


def fleet(folder: Path, n: int) -> list[Path]:
    from probmap.sim.floorplan import simulate_laser_world

    out = []
    for seed in range(n):
        w = simulate_laser_world(seed=seed, size=(24.0, 12.0), range_noise=0.02, dropout=0.01)
        poses = w.poses + np.array([0.0123, 0.0077, 0.0])
        out.append(write_carmen(folder / f"robot{seed}.log", poses, w.ranges, w.max_range))
    return out


def sequential(paths: list[Path], cfg) -> float:  # type: ignore[no-untyped-def]
    """All logs into one grid, in order, in this process (reading included)."""
    from probmap.datasets.carmen import load_scans

    t = time.perf_counter()
    grid = cfg.make_grid()
    for p in paths:
        b = load_scans(p, poses=cfg.poses, max_range=cfg.max_range)
        mr = cfg.max_range if cfg.max_range is not None else b.max_range
        grid.integrate_scans(b.laser_poses, b.ranges, b.angles, max_range=mr)
    grid.cropped()
    return time.perf_counter() - t


def warm_worker() -> None:
    """Import probmap and load the compiled kernels in a worker process."""
    from probmap.grid.increments import integrate_increments
    from probmap.pipelines import MappingConfig

    angles = np.linspace(-1.5, 1.5, 5)
    integrate_increments(np.zeros((2, 3)), np.ones((2, 5)), angles, 8.0, MappingConfig())


def read_seconds(path: Path, cfg) -> float:  # type: ignore[no-untyped-def]
    from probmap.datasets.carmen import load_scans

    t = time.perf_counter()
    load_scans(path, poses=cfg.poses, max_range=cfg.max_range)
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--chunks", type=int, default=8, help="chunks of the Intel log")
    ap.add_argument("--logs", type=int, default=48, help="simulated logs")
    ap.add_argument("--repeat", type=int, default=3, help="runs per timing (best is kept)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="cluster sizes")
    ap.add_argument("--no-intel", action="store_true")
    args = ap.parse_args()

    from distributed import Client
    from rich.console import Console
    from rich.table import Table

    from probmap.pipelines import MappingConfig
    from probmap.pipelines.distributed import (
        DistributedOptions,
        local_cluster,
        map_logs_distributed,
    )

    intel = INTEL if INTEL.is_dir() else INTEL_ALT
    intel_log = intel / "intel.clf.bz2"
    cfg = MappingConfig(resolution=0.05)
    sim_cfg = MappingConfig(resolution=0.05, max_range=8.0)
    tmp = tempfile.TemporaryDirectory()
    logs = fleet(Path(tmp.name), args.logs)
    workloads = []
    if not args.no_intel and intel_log.is_file():
        workloads.append(("Intel raw, chunks", [intel_log], cfg, args.chunks))
    workloads.append((f"{args.logs} simulated logs", logs, sim_cfg, 1))

    sequential(logs[:1], sim_cfg)  # compile / load the kernels in this process
    rows: list[tuple[str, str, str, str, str]] = []
    rep = max(1, args.repeat)
    ref = {name: min(sequential(paths, c) for _ in range(rep)) for name, paths, c, _ in workloads}
    for name, paths, c, _ in workloads:
        rows.append((name, "sequential (this process)", "1", f"{ref[name]:.2f}", "1.00"))
        rows.append(
            (
                name,
                "  of which reading the logs",
                "1",
                f"{read_seconds(paths[0], c) * len(paths):.2f}",
                "",
            )
        )
    overhead = None
    for n_workers in args.workers:
        t = time.perf_counter()
        cluster = local_cluster(n_workers)
        client = Client(cluster)
        startup = time.perf_counter() - t
        try:
            client.run(warm_worker)
            for name, paths, c, chunks in workloads:
                opts = DistributedOptions(mode="increments", chunks=chunks)
                dt = float("inf")
                for _ in range(rep):
                    t = time.perf_counter()
                    res = map_logs_distributed(
                        paths, c, client=client, progress=False, options=opts
                    )
                    dt = min(dt, time.perf_counter() - t)
                rows.append(
                    (name, f"Dask, {res.tasks} tasks", str(n_workers), f"{dt:.2f}",
                     f"{ref[name] / dt:.2f}")
                )  # fmt: skip
            if n_workers == max(args.workers) and workloads[0][0].startswith("Intel"):
                times = {}
                for chunks in (4, 64):
                    opts = DistributedOptions(mode="increments", chunks=chunks)
                    t = time.perf_counter()
                    res = map_logs_distributed(
                        [intel_log], cfg, client=client, progress=False, options=opts
                    )
                    times[chunks] = (time.perf_counter() - t, res.tasks)
                overhead = (times[64][0] - times[4][0]) / (times[64][1] - times[4][1])
            t = time.perf_counter()
            client.gather(client.map(int, range(200), pure=False))
            noop = (time.perf_counter() - t) / 200
            rows.append(
                ("empty task round trip", "Dask", str(n_workers), f"{noop * 1e3:.2f} ms", "")
            )
            rows.append(("cluster start-up", "LocalCluster", str(n_workers), f"{startup:.2f}", ""))
        finally:
            client.close()
            cluster.close()
    if overhead is not None:
        rows.append(("overhead per mapping task", "Intel 4 vs 64 chunks", str(max(args.workers)),
                     f"{overhead * 1e3:.1f} ms", ""))  # fmt: skip
    table = Table(title="distributed mapping (wall seconds; speed-up = sequential / Dask)")
    for col in ("workload", "run", "workers", "time [s]", "speed-up"):
        table.add_column(col)
    for r in rows:
        table.add_row(*r)
    Console().print(table)
    tmp.cleanup()


if __name__ == "__main__":
    main()
