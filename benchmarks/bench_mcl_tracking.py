"""Monte Carlo localization on real logs, in the map that ``probmap slam grid`` builds from the
same log: what a user does (map the building, then localize in it). Issue 37.

For each log with relations in the data folder (Intel, the Freiburg hospital, Freiburg 079, the
Intel ROS bag), and the Freiburg campus (outdoor, a scan every metre; its raw-odometry log and
relations rebuilt from the corrected log in the cache by ``_campus.py``):

1. ``probmap slam grid LOG -o CACHE/NAME/ --save-session CACHE/NAME/slam.session`` once (about a
   minute each; later runs reuse CACHE).
2. Tracking: ``localize_scans`` with ``LocalizeConfig``'s defaults over the whole log, started
   at the session's first pose, as ``probmap localize SESSION LOG`` runs it (same laser mounting
   and start). Scored with the relation metric (Kuemmerle et al. 2009) on the robot poses,
   interpolated between the filter's updates at the relations' timestamps; the SLAM
   trajectory's own figure beside it (the map's quality bounds the filter's). "lost" counts the
   times the run said it lost track, with the spans (log time, from where it lost track to
   where it recovered); "outside lost spans" scores only the relations whose two poses lie
   outside them; "ended lost" whether it never recovered.
3. Global localization: ``--starts`` runs from particles over free space, each from a random
   scan (seeded), run as a user runs one: until the filter says it knows where the robot is
   (``localize_scans(..., until_localized=True)``), at most ``--updates`` updates (1,000 by
   default; about 130 m of travel on Freiburg 079) or to the log's end. A run *converged* when
   it says so (``LocalizationRun.localized``), and is *right* when its estimate at that moment
   lies within 0.3 m of the session's trajectory there (interpolated). "said so" counts the
   runs that did not converge and reported it. The updates and the odometry's travel from the
   start to the claim are given for the right runs (median, 90th percentile, maximum).
   ``--fixed`` runs the earlier protocol instead: exactly ``--updates`` updates (150 then), the
   claim judged at the last one.

``--kidnap`` makes the odometry jump 10 m sideways at the middle scan while the robot stays
where it is: tracking must say it lost track and find the robot again; "outside lost spans"
then scores the rest.

Run:  PROBMAP_DATA=/work/shared/data python benchmarks/bench_mcl_tracking.py \\
          [--cache /tmp/mcl_maps] [--logs intel hospital fr079 intelbag] [--starts 10]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

LOGS = {
    "intel": ("intel-research-lab/intel.clf.bz2", "intel-research-lab/intel.relations"),
    "hospital": (
        "freiburg-clinic/fr-clinic_robotlaser.clf.bz2",
        "freiburg-clinic/fr-clinic.relations",
    ),
    "fr079": ("freiburg-079/fr079.clf.bz2", "freiburg-079/fr079.relations"),
    "intelbag": ("intel-research-lab/intel.orig.bag", "intel-research-lab/intel.relations"),
    # rebuilt in the cache from the corrected log, relations from GMapping's poses (_campus.py)
    "campus": ("", ""),
}


def log_and_relations(name: str, cache: Path) -> tuple[Path, Any]:
    """The log of ``name`` and its relations; the campus log is rebuilt in ``cache``."""
    from probmap.metrics.relations import Relations, read_relations

    if name != "campus":
        return data_dir() / LOGS[name][0], read_relations(data_dir() / LOGS[name][1])
    import _campus

    log = cache / "campus.clf"
    cache.mkdir(parents=True, exist_ok=True)
    times, ref = _campus.rebuild(data_dir() / _campus.CORRECTED, log)
    local, loop = _campus.relations(times, ref)
    return log, Relations(
        np.concatenate([local.t1, loop.t1]),
        np.concatenate([local.t2, loop.t2]),
        np.concatenate([local.delta, loop.delta]),
    )


def data_dir() -> Path:
    return Path(os.environ.get("PROBMAP_DATA", Path(__file__).parents[2] / "shared" / "data"))


def session_for(name: str, log: Path, cache: Path) -> Path:
    """The slam grid session of ``log`` in ``cache``, built when missing or when this code
    cannot read it (an older format: its map may be another run's, so it is built again)."""
    from probmap.pipelines.localize import load_localization_map

    out = cache / name
    session = out / "slam.session"
    if session.is_file():
        try:
            load_localization_map(session)
        except ValueError as exc:
            print(f"<!-- {name}: {exc}; building it again -->", flush=True)
            session.unlink()
    if not session.is_file():
        out.mkdir(parents=True, exist_ok=True)
        cmd = [
            sys.executable, "-c", "from probmap.cli.app import main; main()", "slam", "grid",
            str(log), "-o", f"{out}/", "--save-session", str(session),
        ]  # fmt: skip
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return session


def relation_figure(times, poses, rel) -> str:
    from probmap.metrics.relations import relation_errors

    s = relation_errors(times, poses, rel).summary()
    return f"{s['trans_abs_mean_m']:.3f} ± {s['trans_abs_std_m']:.3f}"


def spread_of(values: list[float], fmt: str) -> str:
    """``median / 90th percentile / max`` of ``values``, or a dash."""
    if not values:
        return "-"
    v = np.asarray(values, dtype=np.float64)
    return " / ".join(format(float(x), fmt) for x in (np.median(v), np.percentile(v, 90), v.max()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/mcl_maps"))
    ap.add_argument("--logs", nargs="+", default=list(LOGS), choices=list(LOGS))
    ap.add_argument("--starts", type=int, default=10, help="global localizations per log")
    ap.add_argument("--updates", type=int, default=1000, help="updates per global run, at most")
    ap.add_argument(
        "--fixed", action="store_true", help="every global run exactly --updates updates long"
    )
    ap.add_argument(
        "--global-particles", type=int, default=None,
        help="a fixed count for global runs (KLD off); default: LocalizeConfig's (KLD-sampling "
        "from particle_density per m2 of free space)",
    )  # fmt: skip
    ap.add_argument("--no-tracking", action="store_true", help="global localization only")
    ap.add_argument(
        "--kidnap", action="store_true",
        help="tracking only: the odometry jumps 10 m sideways at the middle scan (the robot "
        "does not move), so the run must lose track and find the robot again",
    )  # fmt: skip
    args = ap.parse_args()

    from probmap.cli.localize import _laser_offset
    from probmap.datasets.scans import open_scans
    from probmap.geometry.se2 import compose, inverse
    from probmap.geometry.timesync import interpolate_poses
    from probmap.metrics.relations import read_trajectory
    from probmap.pipelines.localize import (
        LocalizeConfig,
        interpolate_run,
        load_localization_map,
        localize_scans,
    )

    print(
        "| log | SLAM relation error (m) | MCL relation error (m) | lost (spans, log time) "
        "| outside lost spans (m) | ended lost | updates | s | global: particles at the start "
        "| global: converged right / converged wrong / said not "
        "| updates to the claim (median / 90 % / max) | travel to the claim (m) | global s |"
    )
    print("| --- | ---: | ---: | --- | ---: | --- | ---: | ---: | ---: | --- | --- | --- | ---: |")
    for name in args.logs:
        log, rel = log_and_relations(name, args.cache)
        session = session_for(name, log, args.cache)
        m = load_localization_map(session)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            batch = open_scans(log, poses="corrected")
            mount = _laser_offset(log, batch, m, False, None)
        t = np.asarray(batch.times)
        odometry = np.asarray(batch.robot_poses, dtype=np.float64)
        if args.kidnap:
            odometry = odometry.copy()
            odometry[t.size // 2 :, 1] += 10.0
        args_run = (m.spec, m.probability, t, batch.ranges, batch.angles, odometry)
        pose0 = m.pose_at(float(t[0]))
        robot0 = compose(pose0, inverse(mount))
        slam_t, slam_p = read_trajectory(session.parent / "slam.trajectory.csv")
        slam_fig = relation_figure(slam_t, slam_p, rel)
        mcl_fig = outside = lost_txt = ended = n_upd = wall_txt = "-"
        if not args.no_tracking:
            cfg = LocalizeConfig(initial_pose=tuple(float(v) for v in robot0))
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                run = localize_scans(*args_run, batch.max_range, cfg, laser_offset=mount)
            wall = time.perf_counter() - t0
            ts = np.unique(np.r_[rel.t1, rel.t2])
            est = interpolate_run(run, ts)
            ok = np.all(np.isfinite(est), axis=1)
            mcl_fig = relation_figure(ts[ok], est[ok], rel)
            # the same, less the relations with a pose inside a span the run reported lost
            spans = [(e.time, e.recovered_time or np.inf) for e in run.episodes]
            keep = ok & ~np.any([(ts >= a) & (ts <= b) for a, b in spans] or [ts < -np.inf], axis=0)
            outside = relation_figure(ts[keep], est[keep], rel) if spans else "same"
            lost_txt = ", ".join(
                f"{a:.1f}-{b:.1f} s" if np.isfinite(b) else f"{a:.1f} s-end" for a, b in spans
            )
            lost_txt = f"{len(run.episodes)} {lost_txt}"
            ended, n_upd = ("yes" if run.ended_lost else "no"), f"{run.times.size:,}"
            wall_txt = f"{wall:.0f}"
        order = np.argsort(m.times, kind="stable")  # a log's clock may jitter back
        session_traj = np.column_stack([m.times[order], m.poses[order]])
        rng = np.random.default_rng(0)
        right = wrong = said = 0
        steps, travel, first = [], [], []
        moved = np.r_[
            0.0, np.cumsum(np.hypot(*np.diff(np.asarray(batch.robot_poses)[:, :2], axis=0).T))
        ]
        g0 = time.perf_counter()
        for i in range(args.starts):
            s = int(rng.integers(0, max(1, t.size - 3000)))
            gcfg = LocalizeConfig(global_localization=True, seed=i)
            if args.global_particles is not None:
                gcfg = dataclasses.replace(gcfg, n_particles=args.global_particles, kld=False)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                g = localize_scans(
                    *args_run, batch.max_range, gcfg, laser_offset=mount, start=s,
                    max_updates=args.updates, until_localized=not args.fixed,
                )  # fmt: skip
            first.append(int(g.particle_count[0]) if g.particle_count.size else 0)
            verdict = "not converged, said so"
            if not g.localized:
                said += 1
                print(f"  {name} start {i}: scan {s}, {verdict}", file=sys.stderr, flush=True)
                continue
            # the session keeps a pose at the scans it used: interpolated at the last update
            ref = interpolate_poses(session_traj, g.times[-1:])[0]
            err = float(np.hypot(*(g.laser_poses[-1, :2] - ref[:2])))  # NaN outside: wrong
            right, wrong = (right + 1, wrong) if err <= 0.3 else (right, wrong + 1)
            verdict = f"claimed, {err:.2f} m off the session"
            print(f"  {name} start {i}: scan {s}, {verdict}", file=sys.stderr, flush=True)
            if err <= 0.3:
                steps.append(g.times.size)
                travel.append(moved[g.scan_index[-1]] - moved[s])
        gwall = time.perf_counter() - g0
        print(
            f"| {name} | {slam_fig} | {mcl_fig} | {lost_txt} | {outside} | "
            f"{ended} | {n_upd} | {wall_txt} | {f'{first[0]:,}' if first else '-'} | "
            f"{right} / {wrong} / {said} of {args.starts} | {spread_of(steps, '.0f')} | "
            f"{spread_of(travel, '.1f')} | {gwall:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
