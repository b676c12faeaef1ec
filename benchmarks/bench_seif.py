"""SEIF scaling: time per step and bytes per landmark at 100 to 100,000 landmarks, beside our EKF.

Every run drives the same loop (radius 15 m, same landmark density, so the same number of
observations per step) through a world of ``n`` landmarks; the whole map is put in the state
first as a prior (each landmark at its true position with 0.5 m standard deviation, no
correlations), so the state really holds ``n`` landmarks while the robot moves. Known
correspondences. Times are per step (predict + update), median over the timed steps, in the same
process. EKF runs stop at the largest size whose dense covariance fits comfortably in memory.

Optional peer in the same run: GTSAM's iSAM2 (``pip install -e '.[bench]'``), one update per step
over the same odometry and bearing-range factors, with the same prior map as prior factors.

Run: ``python benchmarks/bench_seif.py`` (``--quick`` for a short smoke run).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core, as the CLI runs (set before numpy loads)

import numpy as np  # noqa: E402

from probmap.datasets.simulation import simulate_landmarks  # noqa: E402
from probmap.slam.landmark.ekf import EKFSLAM  # noqa: E402
from probmap.slam.landmark.seif import SeifConfig, build_seif  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _isam2_peer  # noqa: E402

PRIOR_SD = 0.5


def _ekf_with_prior(ds, lm: np.ndarray) -> EKFSLAM:
    """An EKF whose state already holds the prior map (EKFSLAM has no public prior-map API,
    so its arrays are set here, exactly as its own landmark augmentation lays them out)."""
    ekf = EKFSLAM(ds.motion_model, ds.measurement_model, ds.initial_pose, ds.initial_covariance)
    n = lm.shape[0]
    ekf._mu = np.concatenate([ekf._mu, lm.ravel()])
    P = np.zeros((3 + 2 * n, 3 + 2 * n))
    P[:3, :3] = ekf._P
    idx = np.arange(3, 3 + 2 * n)
    P[idx, idx] = PRIOR_SD**2
    ekf._P = P
    ekf._ids = np.arange(n, dtype=np.int64)
    ekf._slot = {i: i for i in range(n)}
    ekf._hits = np.ones(n, dtype=np.int64)
    ekf._misses = np.zeros(n, dtype=np.int64)
    ekf._confirmed = np.ones(n, dtype=bool)
    return ekf


def _time_steps(f, steps) -> np.ndarray:
    out = np.empty(len(steps))
    clock = time.perf_counter
    for i, s in enumerate(steps):
        t0 = clock()
        f.predict(s.control, s.dt)
        f.update(s.z, s.ids)
        out[i] = clock() - t0
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--max-active", type=int, default=10)
    ap.add_argument("--deactivation", choices=["weakest", "oldest"], default="weakest")
    ap.add_argument("--ekf-max", type=int, default=3000, help="largest n for the EKF")
    ap.add_argument(
        "--context-hops",
        default="0,1",
        help="SeifConfig.context_hops values to time, comma-separated (0 = Table 12.4)",
    )
    ap.add_argument("--quick", action="store_true")
    ap.add_argument(
        "--no-isam2", action="store_true", help="skip the GTSAM iSAM2 peer (pip install gtsam)"
    )
    args = ap.parse_args()
    hop_values = [int(v) for v in args.context_hops.split(",")]
    use_isam2 = not args.no_isam2 and _isam2_peer.available()
    if not args.no_isam2 and not use_isam2:
        print("gtsam is not installed (pip install -e '.[bench]'): no iSAM2 column")
    sizes = [100, 1000, 10000, 100000]
    ekf_sizes = [100, 300, 1000, 3000]
    steps_n = args.steps
    if args.quick:
        sizes, ekf_sizes, steps_n = [100, 1000], [100, 300], 150
    warm = steps_n // 5
    rows = []
    for n in sorted(set(sizes) | {s for s in ekf_sizes if s <= args.ekf_max}):
        ds = simulate_landmarks(n, steps_n, seed=1, density=0.03, loop_radius=15.0)
        lm = ds.landmarks_xy
        assert lm is not None  # a simulation carries its true landmarks
        steps = list(ds)
        obs = np.mean([s.z.shape[0] for s in steps])
        row = {"n": n, "obs": obs}
        if n in sizes:
            for hops in hop_values:
                seif = build_seif(
                    ds,
                    SeifConfig(
                        max_active=args.max_active,
                        deactivation=args.deactivation,
                        context_hops=hops,
                    ),
                )
                seif.add_landmarks(
                    np.arange(n), lm, np.broadcast_to(PRIOR_SD**2 * np.eye(2), (n, 2, 2))
                )
                t = _time_steps(seif, steps)[warm:]
                key = "" if hops == hop_values[0] else f"_h{hops}"
                row["seif_ms" + key] = 1e3 * float(np.median(t))
                row["seif_mean_ms" + key] = 1e3 * float(np.mean(t))
                row["bytes_per_lm" + key] = seif.state_nbytes() / seif.n_landmarks
                row["links" + key] = seif.store.block_counts()["landmark_links"]
        if n in sizes and use_isam2:
            peer = _isam2_peer.ISAM2Peer(ds)
            peer.add_landmark_priors(np.arange(n), lm, PRIOR_SD)
            t = _isam2_peer.time_steps(peer, steps)[warm:]
            row["isam2_ms"] = 1e3 * float(np.median(t))
        if n in ekf_sizes and n <= args.ekf_max:
            ekf = _ekf_with_prior(ds, lm)
            t = _time_steps(ekf, steps[: max(warm + 50, steps_n // (1 + n // 1000))])[warm:]
            row["ekf_ms"] = 1e3 * float(np.median(t))
            row["ekf_bytes_per_lm"] = 8.0 * (3 + 2 * n) ** 2 / n
        rows.append(row)
        print(f"done n={n}", flush=True)

    def fmt(v, spec):
        return format(v, spec) if v is not None else "-"

    print(
        f"\nSEIF columns: context_hops = {hop_values[0]}; extra columns: context_hops = "
        f"{hop_values[1:]} (median ms, bytes/landmark)"
    )
    extra = [f"_h{h}" for h in hop_values[1:]]
    head = "".join(f" | SEIF{k} median ms | SEIF{k} bytes/lm" for k in extra)
    print(
        "| landmarks | obs/step | SEIF median ms | SEIF mean ms | SEIF bytes/landmark "
        f"| SEIF links{head} | EKF median ms | EKF bytes/landmark | iSAM2 median ms |"
    )
    print("|---:|---:|---:|---:|---:|---:" + "|---:|---:" * len(extra) + "|---:|---:|---:|")
    for r in rows:
        cells = "".join(
            f" | {fmt(r.get('seif_ms' + k), '.3f')} | {fmt(r.get('bytes_per_lm' + k), '.0f')}"
            for k in extra
        )
        print(
            f"| {r['n']:,} | {r['obs']:.1f} | {fmt(r.get('seif_ms'), '.3f')} "
            f"| {fmt(r.get('seif_mean_ms'), '.3f')} | {fmt(r.get('bytes_per_lm'), '.0f')} "
            f"| {fmt(r.get('links'), 'd')}{cells} | {fmt(r.get('ekf_ms'), '.3f')} "
            f"| {fmt(r.get('ekf_bytes_per_lm'), ',.0f')} | {fmt(r.get('isam2_ms'), '.3f')} |"
        )
    seif_rows = [r for r in rows if "seif_ms" in r]
    for k in ["", *extra]:
        ratio = seif_rows[-1]["seif_ms" + k] / seif_rows[0]["seif_ms" + k]
        print(
            f"SEIF{k} t({seif_rows[-1]['n']:,}) / t({seif_rows[0]['n']:,}) = {ratio:.2f}, "
            f"t({seif_rows[-1]['n']:,}) / Table-12.4 t = "
            f"{seif_rows[-1]['seif_ms' + k] / seif_rows[-1]['seif_ms']:.2f}"
        )
    peer_rows = [r for r in rows if "isam2_ms" in r]
    if peer_rows:
        print(
            f"iSAM2 t({peer_rows[-1]['n']:,}) / t({peer_rows[0]['n']:,}) = "
            f"{peer_rows[-1]['isam2_ms'] / peer_rows[0]['isam2_ms']:.2f}; iSAM2 / SEIF: "
            + ", ".join(f"{r['n']:,}: {r['isam2_ms'] / r['seif_ms']:.2f}x" for r in peer_rows)
        )
    ekf_rows = [r for r in rows if "ekf_ms" in r]
    if len(ekf_rows) >= 2:
        x = np.log([r["n"] for r in ekf_rows])
        y = np.log([r["ekf_ms"] for r in ekf_rows])
        slope = np.polyfit(x, y, 1)[0]
        print(
            f"EKF growth exponent (log-log fit over n = {[r['n'] for r in ekf_rows]}): {slope:.2f}"
        )
        common = [r for r in rows if "ekf_ms" in r and "seif_ms" in r]
        for r in common:
            print(f"EKF / SEIF at n = {r['n']:,}: {r['ekf_ms'] / r['seif_ms']:.2f}x")


if __name__ == "__main__":
    main()
