"""Where graph SLAM's relation error comes from, on one log (issue 18's hospital seam).

Runs ``run_submap_slam`` (the default ``SubmapSlamConfig`` unless ``--set`` changes a field) and
splits the relation error (Kuemmerle et al. 2009) of the estimate and of raw odometry into

- *local* relations, whose two times lie less than ``--local-seconds`` apart (the shape of the
  trajectory over a few metres), and
- *loop* relations, further apart in time (a revisit: they score the loop closures);

with, for each, the median ratio of the estimated relation length to the reference one (a
scale disagreement between laser and wheels shows there), how many accepted closures the
robust cost overruled (weight below 0.5), and the loop relations' error over the log's time
(where a seam opens).

Run: ``PROBMAP_DATA=../shared/data python benchmarks/graph_slam_diagnose.py
[--log clinic|intel] [--end SECONDS] [--set local.odometry_sd_rate=0.002,0.02 --set local.matcher.sigma=0.035]``.
"""

from __future__ import annotations

import argparse
import os
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


def _value(text: str) -> Any:
    parts = [p.strip() for p in text.split(",")]
    vals: list[Any] = []
    for p in parts:
        if p.lower() in ("true", "false"):  # check_odometry=false
            vals.append(p.lower() == "true")
            continue
        try:
            vals.append(int(p))
        except ValueError:
            try:
                vals.append(float(p))
            except ValueError:
                vals.append(p)
    return tuple(vals) if len(vals) > 1 else vals[0]


def configure(settings: list[str]) -> Any:
    """The default SubmapSlamConfig with ``section.field=value`` (``closures.min_score=0.6``,
    ``local.matcher.sigma=0.04``) applied."""
    from probmap.slam.laser.submap_slam import SubmapSlamConfig

    def put(obj: Any, path: list[str], value: Any) -> Any:
        if len(path) == 1:
            return replace(obj, **{path[0]: value})
        return replace(obj, **{path[0]: put(getattr(obj, path[0]), path[1:], value)})

    cfg = SubmapSlamConfig()
    for s in settings:
        key, _, text = s.partition("=")
        cfg = put(cfg, key.split("."), _value(text))
    return cfg


def split(times: np.ndarray, poses: np.ndarray, rel: Any, local_s: float) -> dict[str, Any]:
    from probmap.geometry.se2 import between
    from probmap.metrics.relations import relation_errors

    e = relation_errors(times, poses, rel)
    u = e.used
    t1, t2 = rel.t1[u], rel.t2[u]
    local = np.abs(t2 - t1) < local_s
    i1 = np.searchsorted(times, t1).clip(0, len(times) - 1)
    i2 = np.searchsorted(times, t2).clip(0, len(times) - 1)
    est = between(poses[i1], poses[i2])
    ref = rel.delta[u]
    lref = np.hypot(ref[:, 0], ref[:, 1])
    ok = local & (lref > 0.5)
    ratio = float(np.median(np.hypot(est[ok, 0], est[ok, 1]) / lref[ok])) if ok.any() else np.nan
    return {
        "all": float(e.translation.mean()),
        "local": float(e.translation[local].mean()),
        "local_median": float(np.median(e.translation[local])),
        "loop": float(e.translation[~local].mean()) if (~local).any() else np.nan,
        "n_local": int(local.sum()),
        "n_loop": int((~local).sum()),
        "ratio": ratio,
        "err": e.translation,
        "t2": t2,
        "is_loop": ~local,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", choices=sorted(LOGS), default="clinic")
    ap.add_argument("--end", type=float, default=None, help="first SECONDS of the log only")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    ap.add_argument("--local-seconds", type=float, default=60.0)
    args = ap.parse_args()
    from probmap.metrics.relations import read_relations
    from probmap.pipelines.laser_slam import load_laser_log, run_submap_slam

    data = Path(os.environ.get("PROBMAP_DATA", "../shared/data"))
    log, relf = LOGS[args.log]
    batch = load_laser_log(data / log, end_time=args.end)
    rel = read_relations(data / relf)
    cfg = configure(args.set)
    t0 = time.perf_counter()
    run = run_submap_slam(batch, cfg)
    secs = time.perf_counter() - t0
    rows = {
        "graph SLAM": split(run.times, run.poses, rel, args.local_seconds),
        "raw odometry": split(run.times, np.asarray(batch.robot_poses), rel, args.local_seconds),
    }
    w = run.closure_weights
    print(f"{args.log}{'' if args.end is None else f' (first {args.end:g} s)'}, settings: "
          f"{' '.join(args.set) or 'default'}; {secs:.1f} s")  # fmt: skip
    n_loc, n_loop = rows["graph SLAM"]["n_local"], rows["graph SLAM"]["n_loop"]
    print(f"| trajectory | all m | local m ({n_loc}) | local median m | loop m ({n_loop}) "
          "| length ratio (local) |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|")
    for name, r in rows.items():
        print(f"| {name} | {r['all']:.4f} | {r['local']:.4f} | {r['local_median']:.4f} | "
              f"{r['loop']:.3f} | {r['ratio']:.4f} |")  # fmt: skip
    print(f"closures accepted {len(w)}, overruled (weight < 0.5) {int((w < 0.5).sum())}")
    r = rows["graph SLAM"]
    if r["n_loop"]:
        t0_log = float(run.times[0])
        loop = np.flatnonzero(r["is_loop"])
        loop = loop[np.argsort(r["t2"][loop])]
        print("loop relations over time (second time, s after start: mean error m):")
        edges = np.linspace(r["t2"][loop].min(), r["t2"][loop].max() + 1e-9, 9)
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            m = loop[(r["t2"][loop] >= a) & (r["t2"][loop] < b)]
            if m.size:
                print(f"  {a - t0_log:7.0f}-{b - t0_log:7.0f}: {r['err'][m].mean():.3f} ({m.size})")


if __name__ == "__main__":
    main()
