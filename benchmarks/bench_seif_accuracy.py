"""SEIF accuracy and consistency against EKF as a function of ``max_active``.

Runs EKF and SEIF (max_active = 2, 4, 7, 10, 20, unbounded, least-recently-observed
deactivation; and max_active = 10 with the weakest-link deactivation) on the same data in one
process: simulation (seeds 0-7 by default), MRCLAM Dataset 7 robots 1-3 (known ids) and Victoria
Park (unknown ids). Prints one markdown table (robot RMSE against ground truth or GPS, landmark
RMSE, pose ANEES, ms per step), the per-run and pooled (RMS over the simulation seeds) ratios to
the EKF at max_active = 10, and writes ``docs/seif_max_active.png``.

Run: ``PROBMAP_DATA=../shared/data python benchmarks/bench_seif_accuracy.py
[--end-time S] [--vp-end-time S] [--seeds 0-7] [--sim-only] [--only-10 | --sweep-context]``.
``--only-10`` runs the EKF and SEIF-10 (with and without ``context_hops = 1``) for many seeds,
with ``--sim-only`` also GTSAM's iSAM2 when ``gtsam`` is installed (``pip install -e '.[bench]'``);
``--sweep-context`` runs the weakest-link SEIF at each ``max_active`` with ``context_hops`` 0 and 1.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from probmap.datasets import registry  # noqa: E402
from probmap.datasets.simulation import simulate_landmarks  # noqa: E402
from probmap.pipelines.landmark_slam import default_ekf_config, evaluate, run_landmark_slam  # noqa: E402
from probmap.slam.landmark.ekf import EKFSLAM  # noqa: E402
from probmap.slam.landmark.seif import SeifConfig, build_seif  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _isam2_peer  # noqa: E402

SETTINGS: list[int | None] = [2, 4, 7, 10, 20, None]
WEAKEST = "10w"  # max_active = 10, deactivation = "weakest" (the default SEIF)
CONTEXT = "10c"  # the default SEIF with context_hops = 1 (an extension of Table 12.4)
AT_10 = [10, WEAKEST, CONTEXT]
ISAM2 = "isam2"  # GTSAM's iSAM2, the optional peer (simulation only, --only-10)


def _get(m: dict[str, Any], *keys: str) -> float:
    v: Any = m
    for k in keys:
        if not isinstance(v, dict) or k not in v:
            return float("nan")
        v = v[k]
    return float(v)


def _run_isam2(ds: Any) -> dict[str, float]:
    """The optional GTSAM iSAM2 peer: online pose after each step, final map (simulation)."""
    peer = _isam2_peer.ISAM2Peer(ds)
    steps = list(ds)
    err = np.empty(len(steps))
    t = np.empty(len(steps))
    for i, s in enumerate(steps):
        t0 = time.perf_counter()
        peer.step(s.control, s.dt, s.z, s.ids)
        t[i] = time.perf_counter() - t0
        err[i] = np.sum((peer.pose[:2] - s.gt_pose[:2]) ** 2)
    ids, xy = peer.landmarks()
    lm = np.sqrt(np.mean(np.sum((xy - ds.landmarks_xy[ids]) ** 2, axis=1)))
    return {
        "robot": float(np.sqrt(err.mean())),
        "landmark": float(lm),
        "anees": float("nan"),
        "ms": 1e3 * float(t.mean()),
        "mapped": float(ids.size),
    }


def _run(ds: Any, max_active: int | None | str) -> dict[str, float]:
    if max_active == ISAM2:
        return _run_isam2(ds)
    if max_active == "ekf":
        est: Any = EKFSLAM(
            ds.motion_model,
            ds.measurement_model,
            ds.initial_pose,
            ds.initial_covariance,
            default_ekf_config(ds),
        )
    elif max_active == WEAKEST:
        est = build_seif(ds, SeifConfig(max_active=10, deactivation="weakest"))
    elif max_active == CONTEXT:
        est = build_seif(ds, SeifConfig(max_active=10, deactivation="weakest", context_hops=1))
    elif isinstance(max_active, tuple):  # (max_active, context_hops), weakest-link policy
        est = build_seif(ds, SeifConfig(max_active=max_active[0], context_hops=max_active[1]))
    else:
        est = build_seif(ds, SeifConfig(max_active=max_active, deactivation="oldest"))  # type: ignore[arg-type]
    m = evaluate(run_landmark_slam(est, ds), ds, with_dead_reckoning=False)
    robot = _get(m, "ate", "translation_m", "rmse")
    if np.isnan(robot):
        robot = _get(m, "gps", "rmse_m")
    return {
        "robot": robot,
        "landmark": _get(m, "landmarks", "error_m", "rmse"),
        "anees": _get(m, "pose_nees", "mean"),
        "ms": _get(m, "step_ms", "mean"),
        "mapped": float(m["landmarks_mapped"]),
    }


def _mc_ratio(sims: list[dict[Any, dict[str, float]]], k: Any, q: str) -> float:
    """Monte Carlo RMSE ratio to the EKF: root of the mean squared error over the runs."""
    se = np.mean([rows[k][q] ** 2 for rows in sims])
    return float(np.sqrt(se / np.mean([rows["ekf"][q] ** 2 for rows in sims])))


def _plot_context_sweep(sims: list[dict[Any, dict[str, float]]], out: Path) -> None:
    """Monte Carlo RMSE ratio and median pose ANEES vs max_active, context_hops 0 and 1."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ks = [k for k in SETTINGS if k is not None]
    xs = np.arange(len(ks))
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for h, style in ((0, "o-"), (1, "s--")):
        name = "Table 12.4" if h == 0 else f"context_hops = {h}"
        for q, color in (("robot", "C0"), ("landmark", "C1")):
            ratio = [_mc_ratio(sims, (k, h), q) for k in ks]
            axes[0].plot(xs, ratio, style, color=color, label=f"{q}, {name}")
        anees = [np.median([r[(k, h)]["anees"] for r in sims]) for k in ks]
        axes[1].plot(xs, anees, style, color="C2" if h == 0 else "C3", label=name)
    axes[1].axhline(np.median([r["ekf"]["anees"] for r in sims]), color="k", lw=0.8, label="EKF")
    axes[0].axhline(1.0, color="k", lw=0.8)
    axes[0].axhline(1.3, color="r", lw=0.8, ls="--")
    axes[0].set_ylabel(f"Monte Carlo RMSE, SEIF / EKF ({len(sims)} runs)")
    axes[1].set_yscale("log")
    axes[1].set_ylabel("median pose ANEES (3 = consistent)")
    for ax in axes:
        ax.set_xticks(xs, [str(k) for k in ks])
        ax.set_xlabel("max_active")
        ax.legend(fontsize=7)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--end-time", type=float, default=300.0, help="MRCLAM seconds per robot")
    ap.add_argument("--vp-end-time", type=float, default=150.0, help="Victoria Park seconds")
    ap.add_argument("--plot", default="docs/seif_max_active.png")
    ap.add_argument("--context-plot", default="docs/seif_context.png")
    ap.add_argument("--seeds", default="0-7", help="simulation seeds, a range A-B")
    ap.add_argument("--sim-only", action="store_true", help="skip MRCLAM and Victoria Park")
    ap.add_argument(
        "--only-10",
        action="store_true",
        help="run only the EKF and the max_active = 10 variants (for many seeds)",
    )
    ap.add_argument(
        "--sweep-context",
        action="store_true",
        help="weakest-link SEIF at max_active 2-20 with context_hops 0 and 1 (summary only)",
    )
    args = ap.parse_args()
    variants: list[Any] = [WEAKEST, CONTEXT] if args.only_10 else [*SETTINGS, WEAKEST, CONTEXT]
    if args.sweep_context:
        variants = [(k, h) for k in SETTINGS if k is not None for h in (0, 1)]
    peer = args.only_10 and args.sim_only and _isam2_peer.available()
    first, last = (int(v) for v in args.seeds.split("-"))
    datasets: list[tuple[str, Any]] = [
        (f"simulation seed {s}", simulate_landmarks(150, 600, seed=s, density=0.05))
        for s in range(first, last + 1)
    ]
    if not args.sim_only:
        for robot in (1, 2, 3):
            datasets.append(
                (
                    f"MRCLAM robot {robot}",
                    registry.load("mrclam7", robot=robot, end_time=args.end_time),
                )
            )
        datasets.append(
            ("Victoria Park", registry.load("victoria-park", end_time=args.vp_end_time))
        )
    results: dict[str, dict[Any, dict[str, float]]] = {}

    def label(k: Any) -> str:
        if k == WEAKEST:
            return "SEIF 10 weakest"
        if k == CONTEXT:
            return "SEIF 10 weakest, context 1"
        if isinstance(k, tuple):
            return f"SEIF {k[0]} weakest, context {k[1]}"
        if k == ISAM2:
            return "iSAM2 (GTSAM, smoother)"
        return "EKF" if k == "ekf" else f"SEIF {k or 'unbounded'}"

    for name, ds in datasets:
        results[name] = {"ekf": _run(ds, "ekf")}
        for k in variants:
            results[name][k] = _run(ds, k)
        if peer:
            results[name][ISAM2] = _run(ds, ISAM2)
        print(
            f"done {name}: "
            + ", ".join(
                f"{label(k)} {r['robot']:.3f}/{r['landmark']:.3f}/{r['anees']:.1f}"
                for k, r in results[name].items()
            ),
            flush=True,
        )

    print()
    print(
        "| dataset | estimator | robot RMSE m | landmark RMSE m | pose ANEES | ms/step | mapped |"
    )
    print("|---|---|---:|---:|---:|---:|---:|")
    for name, rows in results.items():
        for k, r in rows.items():
            print(
                f"| {name} | {label(k)} | {r['robot']:.3f} | {r['landmark']:.3f} "
                f"| {r['anees']:.2f} | {r['ms']:.3f} | {r['mapped']:.0f} |"
            )
    at10 = [k for k in AT_10 if k in variants]
    if at10:
        print(
            "\nratio to EKF at max_active = 10, robot RMSE, landmark RMSE ("
            + " | ".join(label(k) for k in at10)
            + "):"
        )
    for name, rows in results.items() if at10 else ():
        e = rows["ekf"]
        print(
            f"  {name}: "
            + " | ".join(
                f"{rows[k]['robot'] / e['robot']:.2f}, {rows[k]['landmark'] / e['landmark']:.2f}"
                for k in at10
            )
        )
    sims = [rows for name, rows in results.items() if name.startswith("simulation")]
    if sims:
        # Monte Carlo RMSE: the root of the mean squared error over the runs (each run's RMSE
        # squared is its mean squared error); 95 % interval of the ratio by bootstrapping seeds
        boot = np.random.default_rng(0).integers(0, len(sims), size=(2000, len(sims)))
        print(
            f"Monte Carlo RMSE over {len(sims)} simulation seeds, SEIF / EKF "
            "(95 % bootstrap interval over seeds), per-run ratios above 1.3:"
        )
        for k in [*variants, *([ISAM2] if peer else [])]:
            parts = []
            for q in ("robot", "landmark"):
                se = np.array([rows[k][q] ** 2 for rows in sims])
                ee = np.array([rows["ekf"][q] ** 2 for rows in sims])
                ratio = _mc_ratio(sims, k, q)
                bs = np.sqrt(se[boot].mean(1) / ee[boot].mean(1))
                lo, hi = np.percentile(bs, [2.5, 97.5])
                over = int(np.sum(np.sqrt(se / ee) > 1.3))
                parts.append(f"{q} {ratio:.2f} [{lo:.2f}, {hi:.2f}] ({over} > 1.3)")
            anees = [rows[k]["anees"] for rows in sims]
            print(
                f"  {label(k)}: "
                + ", ".join(parts)
                + (
                    f"; pose ANEES median {np.median(anees):.1f}, max {np.max(anees):.1f}"
                    if not np.any(np.isnan(anees))
                    else ""
                )
            )
        anees_e = [rows["ekf"]["anees"] for rows in sims]
        print(f"  EKF pose ANEES median {np.median(anees_e):.1f}, max {np.max(anees_e):.1f}")
    if args.sweep_context and sims:
        _plot_context_sweep(sims, Path(args.context_plot))
    if args.only_10 or args.sweep_context:
        return

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    xs = np.arange(len(SETTINGS))
    for name, rows in results.items():
        ratio = [rows[k]["robot"] / rows["ekf"]["robot"] for k in SETTINGS]
        axes[0].plot(xs, ratio, marker="o", label=name)
        anees = [rows[k]["anees"] for k in SETTINGS]
        if not np.all(np.isnan(anees)):
            axes[1].plot(xs, anees, marker="o", label=name)
    for ax in axes:
        ax.set_xticks(xs, [str(k) if k else "unbounded" for k in SETTINGS])
        ax.set_xlabel("max_active")
    axes[0].axhline(1.0, color="k", lw=0.8)
    axes[0].axhline(1.3, color="r", lw=0.8, ls="--")
    axes[0].set_ylabel("SEIF robot RMSE / EKF robot RMSE")
    axes[1].axhline(3.0, color="k", lw=0.8)
    axes[1].set_yscale("log")
    axes[1].set_ylabel("pose ANEES (3 = consistent)")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    out = Path(args.plot)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
