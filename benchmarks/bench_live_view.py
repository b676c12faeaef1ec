"""What watching costs: ``probmap map`` and landmark SLAM with and without the live view.

Rows, in one process after a warm-up run that loads the cached kernels and rerun:

1. ``map_log`` of the Intel corrected log (0.05 m) without an observer, and with a
   :class:`~probmap.viz.live.MappingObserver` recording into a ``.rrd`` (the newest scan every
   20 scans, the map image and the trajectory at most once a second, as ``--viz-save`` does).
2. EKF SLAM on the seeded simulated landmark world (the ``simulation`` dataset: 200
   landmarks, 2,000 steps) without and with a :class:`~probmap.viz.live.LandmarkSlamObserver`
   (the robot and measurements at most every 5 steps, the map from a copy of the filter at
   most once a second).

Each row is the best of ``--repeat`` runs (seconds of wall time) and the recording's size.

Run:  python benchmarks/bench_live_view.py [--log PATH] [--repeat 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def table(title: str, header: list[str], rows: list[list[str]]) -> None:
    print(f"\n{title}\n")
    print("| " + " | ".join(header) + " |")
    print("| " + " | ".join(["---"] + ["---:"] * (len(header) - 1)) + " |")
    for r in rows:
        print("| " + " | ".join(r) + " |")


def best(run: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        run()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--log", type=Path, default=DATA / "intel-research-lab" / "intel-corrected.log.gz"
    )
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()

    from probmap.datasets.simulation import simulate_landmarks
    from probmap.pipelines import MappingConfig, map_log
    from probmap.pipelines.landmark_slam import default_ekf_config, run_landmark_slam
    from probmap.slam.landmark.ekf import EKFSLAM
    from probmap.viz.live import LandmarkSlamObserver, LiveView, MappingObserver

    tmp = Path(tempfile.mkdtemp(prefix="bench-live-"))
    cfg = MappingConfig(resolution=0.05)
    ds = simulate_landmarks(200, 2000, seed=0)

    def mapping(watch: bool) -> Callable[[], object]:
        def run() -> object:
            if not watch:
                return map_log(args.log, cfg)
            with LiveView("bench map", save=tmp / "map.rrd") as view:
                observer = MappingObserver(view)
                result = map_log(args.log, cfg, observer=observer)
                observer.finish(result)
            return result

        return run

    def ekf(watch: bool) -> Callable[[], object]:
        def run() -> object:
            est = EKFSLAM(
                ds.motion_model, ds.measurement_model, ds.initial_pose, ds.initial_covariance,
                default_ekf_config(ds),
            )  # fmt: skip
            if not watch:
                return run_landmark_slam(est, ds)
            with LiveView("bench ekf", save=tmp / "ekf.rrd") as view:
                observer = LandmarkSlamObserver(view, ds.measurement_model)
                result = run_landmark_slam(est, ds, observer=observer)
                observer.finish(result, ds)
            return result

        return run

    rows = []
    for name, make, rrd in (
        (f"map {args.log.name}", mapping, tmp / "map.rrd"),
        (f"EKF SLAM {ds.name}", ekf, tmp / "ekf.rrd"),
    ):
        make(True)()  # warm-up: kernels from the cache, rerun loaded
        plain = best(make(False), args.repeat)
        watched = best(make(True), args.repeat)
        rows.append(
            [
                name,
                f"{plain:.2f}",
                f"{watched:.2f}",
                f"{100 * (watched / plain - 1):+.0f} %",
                f"{rrd.stat().st_size / 2**20:.1f}",
            ]
        )
    table(
        f"live view cost (best of {args.repeat})",
        ["run", "plain s", "recorded s", "extra", "rrd MiB"],
        rows,
    )


if __name__ == "__main__":
    main()
