"""Is local SLAM's scan-to-submap matcher biased in step length? (issue 18, the hospital seam)

A controlled experiment with known truth: a robot drives down a long corridor with door
recesses and a few pillars (walls are exact line segments, ranges are cast analytically, so
nothing is quantised before the matcher sees it) with a forward-facing 180-degree laser (as
the Freiburg hospital's) or a 360-degree one. :class:`~probmap.slam.laser.submap_slam.SubmapSlam` runs
with loop closure and optimization off, and its *local-SLAM* poses (scan-to-submap matching
only) are compared with the truth:

- ``ratio``: median over node pairs about 1 m apart of (estimated length) / (true length);
- ``drift``: the final node's error along the corridor (metres; + = too far);
- ``lateral``: its error across the corridor.

Run: ``python benchmarks/bench_matcher_bias.py [--fov 180 360] [--set local.matcher.sigma=0.1]
[--seeds 3] [--field known]``; every ``--fov`` is a row (``--heading`` rotates the whole world:
a check that nothing depends on the map frame, since the submaps are laid out in their anchor's
frame). ``--field VARIANT --diagnose --log clinic`` runs ``graph_slam_diagnose.py`` on a real
log with the same change to the submaps' match field.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray


def corridor_segments(
    length: float = 60.0, width: float = 2.4, features: bool = True
) -> NDArray[np.float64]:
    """Walls (K, 4) ``(x0, y0, x1, y1)`` of a corridor along +x from x = 0 to ``length`` (m),
    centre line y = 0, with a door recess (1 m wide, 0.25 m deep) every 3.7 m on the left and
    every 4.3 m on the right, a pillar (0.4 m square, against a wall) every 9.1 m, end walls."""
    h = width / 2
    segs: list[tuple[float, float, float, float]] = []
    for side, period, phase in ((+1.0, 3.7, 1.3), (-1.0, 4.3, 2.9)):
        x = 0.0
        doors = np.arange(phase, length - 1.5, period) if features else np.zeros(0)
        for d in doors:
            segs.append((x, side * h, d, side * h))
            segs.append((d, side * h, d, side * (h + 0.25)))
            segs.append((d, side * (h + 0.25), d + 1.0, side * (h + 0.25)))
            segs.append((d + 1.0, side * (h + 0.25), d + 1.0, side * h))
            x = d + 1.0
        segs.append((x, side * h, length, side * h))
    for px in np.arange(5.2, length - 2.0, 9.1) if features else []:
        side = 1.0 if int(px) % 2 else -1.0
        y0, y1 = side * h, side * (h - 0.4)
        segs += [(px, y0, px, y1), (px, y1, px + 0.4, y1), (px + 0.4, y1, px + 0.4, y0)]
    segs.append((0.0, -h - 0.3, 0.0, h + 0.3))
    segs.append((length, -h - 0.3, length, h + 0.3))
    return np.asarray(segs, dtype=np.float64)


def cast(
    segs: NDArray[np.float64], poses: NDArray[np.float64], angles: NDArray[np.float64], rmax: float
) -> NDArray[np.float64]:
    """Exact ranges (S, B) from sensor poses (S, 3) to the nearest segment (``rmax`` if none)."""
    a = segs[:, :2]
    e = segs[:, 2:] - a  # (K, 2)
    out = np.full((len(poses), len(angles)), rmax)
    for s, (x, y, th) in enumerate(poses):
        d = np.column_stack([np.cos(th + angles), np.sin(th + angles)])  # (B, 2)
        # o + t d = a + u e  ->  t d - u e = a - o
        den = d[:, None, 0] * (-e[None, :, 1]) - d[:, None, 1] * (-e[None, :, 0])  # (B, K)
        w = a - np.array([x, y])  # (K, 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[None, :, 0] * (-e[None, :, 1]) - w[None, :, 1] * (-e[None, :, 0])) / den
            u = (d[:, None, 0] * w[None, :, 1] - d[:, None, 1] * w[None, :, 0]) / den
        ok = (np.abs(den) > 1e-12) & (t > 1e-9) & (u >= 0) & (u <= 1)
        t = np.where(ok, t, np.inf).min(axis=1)
        out[s] = np.minimum(t, rmax)
    return out


def simulate(
    *,
    fov_deg: float,
    heading: float,
    seed: int,
    step: float = 0.05,
    length: float = 60.0,
    range_noise: float = 0.01,
    odo_noise: float = 0.0,
    max_range: float = 30.0,
    start: float = 1.5,
    end: float = 45.0,
    weave: float = 0.15,
    jitter: float = 0.01,
    features: bool = True,
) -> dict[str, Any]:
    """True sensor poses, odometry, ranges and beam angles of one drive down the corridor,
    the whole world rotated by ``heading`` (radians) about the origin."""
    rng = np.random.default_rng(seed)
    n = int((end - start) / step) + 1
    xs = start + step * np.arange(n)
    ys = weave * np.sin(xs / 3.0)  # a gentle weave
    th = np.arctan2(np.gradient(ys), np.gradient(xs)) + rng.normal(0, jitter, n)
    c, s = math.cos(heading), math.sin(heading)
    poses = np.column_stack([c * xs - s * ys, s * xs + c * ys, th + heading])
    segs = corridor_segments(length, features=features)
    segs_w = np.column_stack(
        [
            c * segs[:, 0] - s * segs[:, 1],
            s * segs[:, 0] + c * segs[:, 1],
            c * segs[:, 2] - s * segs[:, 3],
            s * segs[:, 2] + c * segs[:, 3],
        ]
    )
    fov = math.radians(fov_deg)
    nb = int(round(fov_deg)) + (1 if fov_deg < 360 else 0)
    if fov_deg >= 360:
        angles = -math.pi + np.arange(nb, dtype=np.float64) * (2 * math.pi / nb)
    else:
        angles = np.linspace(-fov / 2, fov / 2, nb, dtype=np.float64)
    ranges = cast(segs_w, poses, angles, max_range + 50.0)
    hit = ranges < max_range
    ranges = np.where(hit, ranges + rng.normal(0, range_noise, ranges.shape), max_range + 50.0)
    # odometry: the true increments (robot frame) with a forward / turn noise per metre
    odo = poses.copy()
    for k in range(1, n):
        dx, dy = poses[k, :2] - poses[k - 1, :2]
        ck, sk = math.cos(poses[k - 1, 2]), math.sin(poses[k - 1, 2])
        fwd, lat = ck * dx + sk * dy, -sk * dx + ck * dy
        dist = math.hypot(dx, dy)
        fwd += rng.normal(0, odo_noise * dist + 1e-12)
        dth = poses[k, 2] - poses[k - 1, 2] + rng.normal(0, odo_noise * dist + 1e-12)
        co, so = math.cos(odo[k - 1, 2]), math.sin(odo[k - 1, 2])
        odo[k] = odo[k - 1] + np.array([co * fwd - so * lat, so * fwd + co * lat, dth])
    return {
        "poses": poses,
        "odometry": odo,
        "ranges": ranges,
        "angles": angles,
        "max_range": max_range + 50.0,
        "heading": heading,
    }


def local_slam_bias(world: dict[str, Any], cfg: Any) -> dict[str, float]:
    """Run local SLAM (closures and optimization off) and measure its step bias."""
    from probmap.geometry.se2 import between
    from probmap.slam.laser.submap_slam import SubmapSlam

    closures = replace(cfg.closures, every=10**9, wide_search_every=0)
    cfg = replace(cfg, closures=closures, optimization=replace(cfg.optimization, every=0))
    slam = SubmapSlam(cfg, max_range=float(world["max_range"]))
    for k in range(len(world["poses"])):
        slam.add_scan(0.1 * k, world["ranges"][k], world["angles"], world["odometry"][k])
    est = np.asarray(slam.local)
    true = world["poses"][np.asarray(slam.node_scan)]
    # node pairs about 1 m apart (5 nodes at 0.2 m)
    gap = 5
    le = np.hypot(*between(est[:-gap], est[gap:])[:, :2].T)
    lt = np.hypot(*between(true[:-gap], true[gap:])[:, :2].T)
    # the final pose error in the true corridor frame (the estimate's frame is the truth's:
    # the first node is the first odometry pose, which is true)
    h = world["heading"]
    d = est[-1, :2] - true[-1, :2]
    along = math.cos(h) * d[0] + math.sin(h) * d[1]
    across = -math.sin(h) * d[0] + math.cos(h) * d[1]
    travel = float(np.hypot(*np.diff(true[:, :2], axis=0).T).sum())
    return {
        "ratio": float(np.median(le / lt)),
        "drift": along,
        "drift_pct": 100.0 * along / travel,
        "lateral": across,
        "failed": float(slam.failed_matches),
        "nodes": float(len(est)),
    }


FIELD_VARIANTS = ("default", "exact", "known", "exact-known")


def use_field_variant(name: str) -> None:
    """Replace how active submaps keep their match field (an experiment, process-wide).

    ``default`` leaves the library alone (new occupied cells splat onto the kept field; cells
    freed since keep their values until every ``Submap.refresh_every``-th insert recomputes
    it); ``exact`` recomputes the field from the grid after every insert; ``known`` sets the
    field to 0 in cells the submap never observed (log odds exactly 0), kept incrementally as
    ``default``; ``exact-known`` does both.
    """
    from probmap.slam.laser import submaps as S

    if name not in FIELD_VARIANTS:
        raise ValueError(f"field variant must be one of {FIELD_VARIANTS}, got {name!r}")
    if name == "default":
        return
    insert0, field0 = S.Submap.insert, S.Submap.field
    exact = name.startswith("exact")
    known = name.endswith("known")

    def insert(self: Any, *args: Any, **kwargs: Any) -> None:
        insert0(self, *args, **kwargs)
        if exact:
            self._field = None
        elif known and self._field is not None and self.grid is not None:
            self._field.values[self.grid.log_odds == 0.0] = 0.0

    def field(self: Any) -> Any:
        fresh = self._field is None
        f = field0(self)
        if known and fresh and self.grid is not None:
            f.values[self.grid.log_odds == 0.0] = 0.0
        return f

    S.Submap.insert = insert  # type: ignore[method-assign]
    S.Submap.field = field  # type: ignore[method-assign]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fov", type=float, nargs="+", default=[180.0, 360.0], help="degrees")
    ap.add_argument("--heading", type=float, nargs="+", default=[0.0], help="degrees")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--odo-noise", type=float, default=0.0, help="per metre (m/m and rad/m)")
    ap.add_argument("--range-noise", type=float, default=0.01)
    ap.add_argument("--end", type=float, default=45.0, help="where the drive ends, m")
    ap.add_argument("--weave", type=float, default=0.15, help="amplitude of the weave, m")
    ap.add_argument("--plain", action="store_true", help="no door recesses or pillars")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    ap.add_argument("--field", choices=FIELD_VARIANTS, default="default",
                    help="how active submaps keep their match field (see use_field_variant)")  # fmt: skip
    ap.add_argument("--diagnose", nargs=argparse.REMAINDER, default=None,
                    help="run graph_slam_diagnose.py with the rest of the line instead, under "
                    "--field (e.g. --field known --diagnose --log clinic --end 600)")  # fmt: skip
    args = ap.parse_args()
    use_field_variant(args.field)
    if args.diagnose is not None:
        import runpy
        import sys
        from pathlib import Path

        script = Path(__file__).with_name("graph_slam_diagnose.py")
        sys.argv = [str(script), *args.diagnose]
        print(f"field {args.field}")
        runpy.run_path(str(script), run_name="__main__")
        return
    from graph_slam_diagnose import configure  # the same --set parser (this folder)

    cfg = configure(args.set)
    print(f"field {args.field}, settings: {' '.join(args.set) or 'default'}; odometry noise {args.odo_noise}/m, "
          f"range noise {args.range_noise} m")  # fmt: skip
    print("| FOV deg | heading deg | step ratio (1 m) | drift along m (% of travel) "
          "| lateral m | failed | s |")  # fmt: skip
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for fov in args.fov:
        for hd in args.heading:
            rows = []
            t0 = time.perf_counter()
            for seed in range(args.seeds):
                w = simulate(
                    fov_deg=fov, heading=math.radians(hd), seed=seed, end=args.end,
                    range_noise=args.range_noise, odo_noise=args.odo_noise, weave=args.weave,
                    features=not args.plain,
                )  # fmt: skip
                rows.append(local_slam_bias(w, cfg))
            secs = time.perf_counter() - t0
            r = {k: float(np.mean([x[k] for x in rows])) for k in rows[0]}
            print(f"| {fov:g} | {hd:g} | {r['ratio']:.4f} | {r['drift']:+.3f} "
                  f"({r['drift_pct']:+.2f} %) | {r['lateral']:+.3f} | {r['failed']:.0f} "
                  f"| {secs:.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
