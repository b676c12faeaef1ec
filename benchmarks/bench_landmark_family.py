"""The landmark SLAM family on one log, and GraphSLAM's batch solve against GTSAM (issue 22).

Part 1 runs EKF SLAM, SEIF, GraphSLAM and FastSLAM 2.0 on the same data (default: all of
Victoria Park, unknown correspondences), each with its dataset defaults, each in a fresh process
(so that the peak memory column is the method's own), one BLAS thread, and prints one table: time
per step (GraphSLAM: recording plus the batch solve, spread over the steps), total time, peak
resident memory, landmarks mapped and the GPS error after an SE(2) fit.

Part 2 takes GraphSLAM's final factor graph on that log (its poses, odometry factors, range-
bearing factors with the correspondences the front end and the merges found) and solves it from
the same starting point (the front end's poses, landmarks at their first sighting) twice:
GraphSLAM's Gauss-Newton/Levenberg-Marquardt
(:func:`probmap.slam.landmark.graphslam.optimize_graphslam`, no covariances) and GTSAM's
``LevenbergMarquardtOptimizer`` on the same graph built from GTSAM's
own factors (``PriorFactorPose2``, ``BetweenFactorPose2`` with the same odometry and noise,
``BearingRangeFactor2D`` with the same noise). GTSAM's range-bearing factor has no sensor offset,
so its pose variables are the laser's poses ``x (+) o`` (the odometry conjugated by ``o``, its
noise moved by the adjoint), an exact re-parametrization; its odometry residual is the Pose2
logarithm where GraphSLAM takes the difference in the start pose's frame, so the two costs agree
to first order only: the table gives each solution's cost under both, and its GPS error. The
process is pinned to one core (``sched_setaffinity``), so GTSAM's threads run single-threaded
as GraphSLAM does.

Part 3 is FastSLAM 2.0 per step at 1,000 landmarks against the EKF
(:func:`fastslam_vs_ekf_at_1000_landmarks`, the world of ``bench_fastslam.py``).

``--dataset mrclam7 --robot N`` runs part 1 on an MRCLAM robot (known ids; the table then has
the robot and landmark RMSE after the SE(2) fit); ``fastslam1`` is FastSLAM 1.0.

Run: ``PROBMAP_DATA=../shared/data python benchmarks/bench_landmark_family.py
[--end-time S] [--methods ekf,seif,graphslam,fastslam,fastslam1] [--dataset NAME --robot N]
[--no-gtsam] [--no-fastslam-speed]``.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import time

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from typing import Any  # noqa: E402

import numpy as np  # noqa: E402


def _dataset(end_time: float | None, name: str = "victoria-park", robot: int | None = None) -> Any:
    from probmap.datasets import registry

    options: dict[str, Any] = {"end_time": end_time}
    if robot is not None:
        options["robot"] = robot
    return registry.load(name, **options)


def _estimator(method: str, ds: Any) -> Any:
    from probmap.pipelines.landmark_slam import default_ekf_config, default_graphslam_config

    if method == "ekf":
        from probmap.slam.landmark.ekf import EKFSLAM

        return EKFSLAM(
            ds.motion_model,
            ds.measurement_model,
            ds.initial_pose,
            ds.initial_covariance,
            default_ekf_config(ds),
        )
    if method == "seif":
        from probmap.slam.landmark.seif import build_seif

        return build_seif(ds)
    if method == "graphslam":
        from probmap.slam.landmark.graphslam import build_graphslam

        return build_graphslam(ds, default_graphslam_config(ds))
    if method in ("fastslam", "fastslam1"):
        import dataclasses

        from probmap.pipelines.landmark_slam import default_fastslam_config
        from probmap.slam.landmark.fastslam import FastSLAM

        cfg = default_fastslam_config(ds)
        if method == "fastslam1":
            cfg = dataclasses.replace(cfg, version=1)
        return FastSLAM(ds.motion_model, ds.measurement_model, ds.initial_pose, cfg)
    raise ValueError(f"unknown method {method!r}")


def _run_method(
    method: str, end_time: float | None, name: str = "victoria-park", robot: int | None = None
) -> dict[str, float]:
    """One method on the log, in its own process (peak RSS is this process's)."""
    from probmap.pipelines.landmark_slam import evaluate, run_landmark_slam

    ds = _dataset(end_time, name, robot)
    est = _estimator(method, ds)
    t0 = time.perf_counter()
    res = run_landmark_slam(est, ds)
    seconds = time.perf_counter() - t0
    m = evaluate(res, ds, with_dead_reckoning=False)
    return {
        "steps": float(m["steps"]),
        "ms_per_step": 1e3 * seconds / max(m["steps"], 1),
        "seconds": seconds,
        "peak_mib": m["peak_rss_mb"],
        "landmarks": float(m["landmarks_mapped"]),
        "gps": float(m.get("gps", {}).get("rmse_m", float("nan"))),
        "ate_aligned": float(
            m.get("ate_aligned", {}).get("translation_m", {}).get("rmse", float("nan"))
        ),
        "landmarks_aligned": float(
            m.get("landmarks_aligned", {}).get("error_m", {}).get("rmse", float("nan"))
        ),
    }


def _in_process(
    method: str, end_time: float | None, name: str = "victoria-park", robot: int | None = None
) -> dict[str, float]:
    ctx = mp.get_context("spawn")
    with ctx.Pool(1) as pool:
        return pool.apply(_run_method, (method, end_time, name, robot))


# ------------------------------------------------------------------------------ GTSAM
def graphslam_problem(ds: Any) -> tuple[Any, Any, Any, Any, Any]:
    """GraphSLAM's final problem on ``ds`` (front end, merges), the starting point for part 2,
    the config and the node times."""
    from dataclasses import replace

    from probmap.pipelines.landmark_slam import default_graphslam_config
    from probmap.slam.landmark.graphslam import (
        build_graphslam,
        graphslam_associate,
        optimize_graphslam_front_end,
    )

    cfg = replace(default_graphslam_config(ds), covariances=False)
    est = build_graphslam(ds, cfg)
    for st in ds:
        est.predict(st.control, st.dt)
        est.update(st.z, st.ids)
    full = est.problem()
    _, prob = optimize_graphslam_front_end(full, cfg)
    _, X0, _ = graphslam_associate(
        full,
        gate_probability=cfg.association_probability,
        new_landmark_probability=cfg.new_landmark_probability,
        floor=cfg.motion_noise_floor,
    )
    L0 = np.zeros((prob.n_landmarks, 2))
    first = np.unique(prob.obs_landmark, return_index=True)[1]
    for j, i in enumerate(first):  # every landmark at its first sighting (Table 11.1)
        L0[j] = prob.measurement_model.inverse(X0[prob.obs_node[i]], prob.z[i])[0]
    times = np.array([st.time for st in ds])
    node_times = np.concatenate([[times[0]], times[prob.seg_ptr[1:] - 1]])
    return prob, (X0, L0), replace(cfg, solver="sparse"), node_times, full


def gtsam_graph(prob: Any, cfg: Any) -> tuple[Any, Any, Any, Any]:
    """The same factor graph in GTSAM (laser poses as variables; see the module docstring).

    Returns the graph, a function ``values(X, Lm)`` that turns GraphSLAM's poses and landmarks
    into GTSAM values, a function ``poses(values)`` back, and the sensor offset."""
    import gtsam

    from probmap.slam.landmark.graphslam.correspondence import _body_increments

    d, Sig = _body_increments(prob, cfg.motion_noise_floor)
    O = gtsam.Pose2(*prob.measurement_model.sensor_offset)
    Oi = O.inverse()
    Ad = Oi.AdjointMap()  # tangent vectors of x to tangent vectors of x (+) o

    def xk(i: int) -> int:
        return int(gtsam.symbol("x", i))

    def lk(j: int) -> int:
        return int(gtsam.symbol("l", j))

    graph = gtsam.NonlinearFactorGraph()
    P0 = np.linalg.inv(prob.prior_information)
    prior = gtsam.Pose2(*prob.prior_mean).compose(O)
    graph.add(
        gtsam.PriorFactorPose2(xk(0), prior, gtsam.noiseModel.Gaussian.Covariance(Ad @ P0 @ Ad.T))
    )
    for s in range(prob.n_nodes - 1):
        c, sn = np.cos(d[s, 2]), np.sin(d[s, 2])
        Rd = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
        # GraphSLAM's noise is on the translation error in the start frame; Pose2's tangent at
        # the prediction is in the end frame: rotate by the increment's heading
        cov = Ad @ (Rd.T @ Sig[s] @ Rd) @ Ad.T
        between = Oi.compose(gtsam.Pose2(*d[s])).compose(O)
        graph.add(
            gtsam.BetweenFactorPose2(
                xk(s), xk(s + 1), between, gtsam.noiseModel.Gaussian.Covariance(cov)
            )
        )
    Q = np.asarray(prob.measurement_model.R, dtype=np.float64)
    noise = gtsam.noiseModel.Gaussian.Covariance(Q[::-1, ::-1].copy())  # (bearing, range)
    for i in range(prob.z.shape[0]):
        graph.add(
            gtsam.BearingRangeFactor2D(
                xk(int(prob.obs_node[i])),
                lk(int(prob.obs_landmark[i])),
                gtsam.Rot2(float(prob.z[i, 1])),
                float(prob.z[i, 0]),
                noise,
            )
        )

    def values(X: Any, Lm: Any) -> Any:
        v = gtsam.Values()
        for s in range(X.shape[0]):
            v.insert(xk(s), gtsam.Pose2(*X[s]).compose(O))
        for j in range(Lm.shape[0]):
            v.insert(lk(j), gtsam.Point2(*Lm[j]))
        return v

    def poses(v: Any) -> Any:
        out = np.empty((prob.n_nodes, 3))
        for s in range(prob.n_nodes):
            p = v.atPose2(xk(s)).compose(Oi)
            out[s] = (p.x(), p.y(), p.theta())
        return out

    return graph, values, poses, O


def graphslam_against_gtsam(end_time: float | None) -> list[str]:
    """Part 2: GraphSLAM's batch solve and GTSAM's LM on the same factor graph."""
    import gtsam

    from probmap.pipelines.landmark_slam import _gps_metrics
    from probmap.slam.landmark.graphslam import optimize_graphslam
    from probmap.slam.landmark.graphslam.linearize import _Linearizer

    ds = _dataset(end_time)
    t0 = time.perf_counter()
    prob, (X0, L0), cfg, node_times, _ = graphslam_problem(ds)
    t_front = time.perf_counter() - t0
    optimize_graphslam(prob, cfg, initial=(X0, L0))  # warm the numba cache
    t0 = time.perf_counter()
    ours = optimize_graphslam(prob, cfg, initial=(X0, L0))
    t_ours = time.perf_counter() - t0
    graph, values, poses, _ = gtsam_graph(prob, cfg)
    init = values(X0, L0)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(cfg.relative_tolerance)
    params.setAbsoluteErrorTol(0.0)
    params.setMaxIterations(cfg.max_iterations)
    t0 = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, init, params)
    sol = opt.optimize()
    t_gtsam = time.perf_counter() - t0
    X_g = poses(sol)
    L_g = np.array([sol.atPoint2(gtsam.symbol("l", j)) for j in range(prob.n_landmarks)])
    lin = _Linearizer(prob, cfg)

    def gps(X: Any) -> float:
        m = _gps_metrics(np.column_stack([node_times, X]), np.asarray(ds.gps), "")
        return float(m["gps"]["rmse_m"])

    rows = [
        f"GraphSLAM's final graph: {prob.n_nodes:,} poses, {prob.n_landmarks:,} landmarks, "
        f"{prob.z.shape[0]:,} range-bearing factors (front end + merges: {t_front:.1f} s)",
        "",
        "| solver | time s | iterations | GraphSLAM cost (ours) | GTSAM error | GPS RMSE m |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name, secs, its, X, Lm in (
        ("GraphSLAM (GN/LM, sparse Cholesky)", t_ours, ours.iterations, ours.nodes, ours.landmarks),
        ("GTSAM LevenbergMarquardtOptimizer", t_gtsam, opt.iterations(), X_g, L_g),
    ):
        cost = lin.residuals(X, Lm, False)[0]
        rows.append(
            f"| {name} | {secs:.2f} | {its} | {cost:.2f} | {graph.error(values(X, Lm)):.2f} | "
            f"{gps(X):.3f} |"
        )
    rows.append(f"\nstarting point: GTSAM error {graph.error(init):.1f}")
    return rows


# ------------------------------------------------------------------------------ FastSLAM slot
def fastslam_vs_ekf_at_1000_landmarks(steps: int = 300) -> list[str] | None:
    """Part 3: FastSLAM 2.0 with 100 particles (shared landmark tree) against the EKF, time
    per step (predict + update) with 1,000 landmarks in the map, on the loop world of
    ``bench_fastslam.py`` (the whole map given as a prior to both, so each really holds 1,000
    landmarks; the first fifth of the steps not timed). Returns markdown rows."""
    import sys

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from bench_fastslam import _fastslam_with_prior
    from bench_seif import _ekf_with_prior, _time_steps
    from probmap.datasets.simulation import simulate_landmarks

    ds = simulate_landmarks(1000, steps, seed=1, density=0.03, loop_radius=15.0)
    lm = ds.landmarks_xy
    assert lm is not None
    seq = list(ds)
    warm = steps // 5
    fs = _time_steps(_fastslam_with_prior(ds, lm, 100, "tree"), seq)[warm:]
    ekf = _time_steps(_ekf_with_prior(ds, lm), seq)[warm:]
    f_ms, e_ms = 1e3 * float(np.median(fs)), 1e3 * float(np.median(ekf))
    return [
        "| landmarks | EKF ms / step | FastSLAM 2.0 ms / step | EKF / FastSLAM |",
        "|---:|---:|---:|---:|",
        f"| 1,000 | {e_ms:.2f} | {f_ms:.2f} | {e_ms / f_ms:.1f}x |",
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--end-time", type=float, default=None)
    ap.add_argument("--methods", default="ekf,seif,graphslam,fastslam")
    ap.add_argument("--dataset", default="victoria-park", help="A registry name (mrclam7, ...).")
    ap.add_argument("--robot", type=int, default=None, help="MRCLAM robot (1-5).")
    ap.add_argument("--no-gtsam", action="store_true")
    ap.add_argument("--no-fastslam-speed", action="store_true")
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    where = args.dataset + (f" robot {args.robot}" if args.robot is not None else "")
    print(f"{where}, {'whole log' if args.end_time is None else f'first {args.end_time:g} s'}\n")
    print(
        "| method | ms / step | total s | peak RSS MiB | landmarks mapped | GPS RMSE m "
        "| robot RMSE aligned m | landmark RMSE aligned m |\n"
        "|---|---:|---:|---:|---:|---:|---:|---:|"
    )

    def fmt(v: float) -> str:
        return "-" if np.isnan(v) else f"{v:.3f}"

    for method in [m for m in args.methods.split(",") if m]:
        r = _in_process(method, args.end_time, args.dataset, args.robot)
        print(
            f"| {method} | {r['ms_per_step']:.3f} | {r['seconds']:.1f} | {r['peak_mib']:.0f} | "
            f"{int(r['landmarks'])} | {fmt(r['gps'])} | {fmt(r['ate_aligned'])} "
            f"| {fmt(r['landmarks_aligned'])} |",
            flush=True,
        )
    if not args.no_gtsam and args.dataset == "victoria-park":
        print()
        print("\n".join(graphslam_against_gtsam(args.end_time)), flush=True)
    if not args.no_fastslam_speed:
        rows = fastslam_vs_ekf_at_1000_landmarks()
        print("\nFastSLAM 2.0 (100 particles) vs EKF at 1,000 landmarks:")
        print("\n".join(rows or []))


if __name__ == "__main__":
    main()
