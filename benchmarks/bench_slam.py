"""EKF SLAM step time and memory vs the number of landmarks, side by side with a dense peer.

The peer is a re-implementation of the PythonRobotics ``ekf_slam.py`` step (full dense
``(3+2n)`` square Jacobians ``G = I + F_x^T g F_x``, dense ``G P G^T``, per observation a dense
``H = h F`` and ``P = (I - K H) P``), with its two bugs fixed (``G P G^T`` instead of
``G^T P G``, and the pose-landmark cross-covariances propagated through ``G``). Both run with known
correspondences on the same states and observations: one step = prediction + 10 observations.

Run:  python benchmarks/bench_slam.py [--threads 1] [--quick]
Prints a table: landmarks, probmap ms/step, peer ms/step, ratio, covariance MB, peak step MB,
and the fitted growth exponent of probmap's step time.
"""

from __future__ import annotations

import argparse
import os
import sys

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--threads", type=int, default=1, help="BLAS threads (default 1)")
parser.add_argument("--quick", action="store_true", help="fewer sizes and repetitions")
args = parser.parse_args()
for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[var] = str(args.threads)

import time  # noqa: E402
import tracemalloc  # noqa: E402

import numpy as np  # noqa: E402

from probmap.geometry.se2 import wrap_angle  # noqa: E402
from probmap.models.measurement import RangeBearingModel  # noqa: E402
from probmap.models.motion import VelocityModel  # noqa: E402
from probmap.slam.landmark.ekf import EKFSLAM  # noqa: E402

K_OBS = 10


class DensePeerEKF:
    """PythonRobotics-style dense EKF SLAM step (bugs fixed), known correspondences."""

    def __init__(self, motion, sensor, mu, P):
        self.motion, self.sensor = motion, sensor
        self.mu, self.P = mu.copy(), P.copy()

    def predict(self, u, dt):
        N = self.mu.size
        x_new, g, V = self.motion.predict(self.mu[:3], u, dt)
        Fx = np.hstack((np.eye(3), np.zeros((3, N - 3))))
        G = np.eye(N) + Fx.T @ (g - np.eye(3)) @ Fx
        Q = V @ self.motion.control_covariance(u, dt) @ V.T
        self.mu[:3] = x_new
        self.P = G @ self.P @ G.T + Fx.T @ Q @ Fx

    def update(self, z, ids):
        N = self.mu.size
        for (r, b), j in zip(z, ids, strict=True):
            c = 3 + 2 * int(j)
            zh, hx, hm = self.sensor.predict(self.mu[:3], self.mu[c : c + 2])
            F = np.zeros((5, N))
            F[:3, :3] = np.eye(3)
            F[3:, c : c + 2] = np.eye(2)
            H = np.hstack([hx, hm]) @ F
            S = H @ self.P @ H.T + self.sensor.R
            K = self.P @ H.T @ np.linalg.inv(S)
            y = np.array([r - zh[0], wrap_angle(b - zh[1])])
            self.mu = self.mu + K @ y
            self.mu[2] = wrap_angle(self.mu[2])
            self.P = (np.eye(N) - K @ H) @ self.P


def build(n, seed=0):
    """An EKF holding ``n`` mapped landmarks, and a generator of observation batches."""
    rng = np.random.default_rng(seed)
    motion = VelocityModel()
    sensor = RangeBearingModel()
    ekf = EKFSLAM(motion, sensor, np.zeros(3), np.eye(3) * 1e-4)
    ang = rng.uniform(-np.pi, np.pi, n)
    rad = rng.uniform(2.0, 30.0, n)
    lm = np.column_stack([rad * np.cos(ang), rad * np.sin(ang)])
    z, _, _ = sensor.predict_many(np.zeros(3), lm)
    ekf.update(z, np.arange(n))

    def batch():
        ids = rng.choice(n, size=K_OBS, replace=False)
        zt, _, _ = sensor.predict_many(ekf.pose, lm[ids])
        return zt + rng.normal(0, 1, zt.shape) * [0.1, 0.03], ids

    return ekf, batch


def time_steps(filt, batches, u=(1.0, 0.1), dt=0.1):
    out = []
    for z, ids in batches:
        t0 = time.perf_counter()
        filt.predict(np.array(u), dt)
        filt.update(z, ids)
        out.append(time.perf_counter() - t0)
    return float(np.median(out))


def main() -> None:
    sizes = [100, 400, 1000] if args.quick else [100, 400, 1000, 3000]
    peer_sizes = {100, 400}
    rows = []
    for n in sizes:
        ekf, batch = build(n)
        reps = 5 if n >= 3000 else 20
        batches = [batch() for _ in range(reps + 2)]
        peer_ms = float("nan")
        if n in peer_sizes:
            peer = DensePeerEKF(ekf.motion_model, ekf.measurement_model, ekf.mean, ekf.covariance)
            peer_ms = 1e3 * time_steps(peer, batches[: (3 if n >= 400 else reps)])
        ours_ms = 1e3 * time_steps(ekf, batches)
        tracemalloc.start()
        time_steps(ekf, [batch()])
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        cov_mb = ekf.covariance.nbytes / 2**20
        rows.append((n, ours_ms, peer_ms, cov_mb, peak / 2**20))
    ns = np.array([r[0] for r in rows], float)
    ts = np.array([r[1] for r in rows])
    big = ns >= 400  # fit where the O(n^2) term dominates the fixed Python overhead
    slope = np.polyfit(np.log(ns[big]), np.log(ts[big]), 1)[0]
    print(f"EKF SLAM step (predict + {K_OBS} observations), BLAS threads = {args.threads}")
    print(
        f"{'landmarks':>9} {'probmap ms':>11} {'peer ms':>9} {'peer/probmap':>12} "
        f"{'P MB':>7} {'peak step MB':>12}"
    )
    for n, ours, peer, cov, peak in rows:
        ratio = f"{peer / ours:12.0f}x" if np.isfinite(peer) else f"{'-':>13}"
        peer_s = f"{peer:9.1f}" if np.isfinite(peer) else f"{'-':>9}"
        print(f"{n:9d} {ours:11.3f} {peer_s} {ratio} {cov:7.1f} {peak:12.1f}")
    print(f"growth exponent of probmap step time (n >= 400): {slope:.2f}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
