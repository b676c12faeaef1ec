"""Monte Carlo localization speed: probmap's compiled update vs straightforward vectorised numpy.

All figures are measured in one run on the simulated world of ``probmap demo --localize``
(20 x 12 m, 0.05 m cells, 60 beams over 180 degrees, 8 m maximum range), one core.

1. Whole MCL update, likelihood field: sample the odometry model (Table 5.6), weight by the
   likelihood field (Table 6.3), low-variance resampling (Table 4.4) -- every update resamples.
   Three times: with MCLConfig's defaults (Table 8.2 as printed); as ``probmap localize``
   tracks (``LocalizeConfig``'s defaults: tempered likelihood, the likelihood averages of
   augmented MCL kept, KLD-sampling's count, which a tight cloud leaves at N); and with
   ``localize``'s adaptive tempering as well (the exponent found by bisection, 31 ESS
   evaluations, wherever one scan would leave fewer than 30 % effective particles: in this
   world at every update).
   probmap: ``MonteCarloLocalization.predict_and_weight`` (one fused numba pass over particles,
   beam endpoints rotated once per particle, float32 log-likelihood table) + ``resample``.
   numpy: the same three steps on (N, B) arrays with the float32 distance field.
2. Likelihood-field weighting alone (particle-beam evaluations per second).
3. Beam model (Table 6.1) with ray casting. probmap ``ray_casting="table"``: a lookup table of
   expected ranges per cell x 360 heading bins, each entry cast exactly (Amanatides-Woo) from the
   cell centre when first needed, then one lookup, one exp and one log per particle and beam.
   numpy peers: (a) sphere tracing on the Euclidean distance transform (step = clearance - one
   cell diagonal, at least half a cell, stop in the first occupied cell) over all unfinished rays
   at once, (b) plain half-cell marching, (c) lookups in the same, already filled table. The
   last row is probmap's sphere tracing (``ray_casting="sphere"``) against (a).

Run:  python benchmarks/bench_mcl.py [--particles 10000] [--beam-particles 1000]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import numpy as np


def numpy_update(parts, odo0, odo1, alphas, dist, frame, lx, ly, sigma, z_hit, z_rand, zmax, rng):
    """Motion + likelihood-field weighting + low-variance resampling, plain numpy."""
    from probmap.models.sampling import sample_motion_model_odometry

    parts = sample_motion_model_odometry(parts, odo0, odo1, alphas, rng)
    c, s = np.cos(parts[:, 2:3]), np.sin(parts[:, 2:3])
    ex = parts[:, 0:1] + c * lx - s * ly
    ey = parts[:, 1:2] + s * lx + c * ly
    ix = np.floor((ex - frame.x0) / frame.resolution).astype(np.int64)
    iy = np.floor((ey - frame.y0) / frame.resolution).astype(np.int64)
    h, w = dist.shape
    inside = (ix >= 0) & (iy >= 0) & (ix < w) & (iy < h)
    d = np.full(ex.shape, 2.0, dtype=np.float32)
    d[inside] = dist[iy[inside], ix[inside]]
    p = z_hit * np.exp(-0.5 * (d / sigma) ** 2) / (math.sqrt(2 * math.pi) * sigma) + z_rand / zmax
    lw = np.log(p).sum(axis=1)
    wgt = np.exp(lw - lw.max())
    wgt /= wgt.sum()
    n = parts.shape[0]
    u = (rng.uniform() + np.arange(n)) / n
    idx = np.minimum(np.searchsorted(np.cumsum(wgt), u, side="right"), n - 1)
    return parts[idx]


def numpy_lf_weights(parts, dist, frame, lx, ly, sigma, z_hit, z_rand, zmax):
    c, s = np.cos(parts[:, 2:3]), np.sin(parts[:, 2:3])
    ex = parts[:, 0:1] + c * lx - s * ly
    ey = parts[:, 1:2] + s * lx + c * ly
    ix = np.floor((ex - frame.x0) / frame.resolution).astype(np.int64)
    iy = np.floor((ey - frame.y0) / frame.resolution).astype(np.int64)
    h, w = dist.shape
    inside = (ix >= 0) & (iy >= 0) & (ix < w) & (iy < h)
    d = np.full(ex.shape, 2.0, dtype=np.float32)
    d[inside] = dist[iy[inside], ix[inside]]
    p = z_hit * np.exp(-0.5 * (d / sigma) ** 2) / (math.sqrt(2 * math.pi) * sigma) + z_rand / zmax
    return np.log(p).sum(axis=1)


def numpy_beam_model(parts, ranges, angles, dist, occ, frame, zmax, params):
    """Ray casting by vectorised sphere tracing, then the Table 6.1 mixture, plain numpy."""
    from scipy.special import erf

    z_hit, z_short, z_max, z_rand, sigma, lam = params
    n, b = parts.shape[0], angles.shape[0]
    th = parts[:, 2:3] + angles[None, :]
    dx, dy = np.cos(th).ravel(), np.sin(th).ravel()
    sx = np.repeat(parts[:, 0], b)
    sy = np.repeat(parts[:, 1], b)
    t = np.zeros(n * b)
    zs = np.full(n * b, zmax)
    active = np.arange(n * b)
    res = frame.resolution
    h, w = occ.shape
    while active.size:
        fx = (sx[active] + t[active] * dx[active] - frame.x0) / res
        fy = (sy[active] + t[active] * dy[active] - frame.y0) / res
        out = (fx < 0) | (fy < 0) | (fx >= w) | (fy >= h) | (t[active] >= zmax)
        ix = np.where(out, 0, fx).astype(np.int64)
        iy = np.where(out, 0, fy).astype(np.int64)
        hit = ~out & occ[iy, ix]
        zs[active[hit]] = t[active[hit]]
        go = ~out & ~hit
        step = np.maximum(dist[iy[go], ix[go]] - math.sqrt(2) * res, 0.5 * res)
        t[active[go]] += step
        active = active[go]
    zs = zs.reshape(n, b)
    z = np.minimum(np.broadcast_to(ranges, zs.shape), zmax)
    eta = 0.5 * (erf((zmax - zs) / (sigma * math.sqrt(2))) + erf(zs / (sigma * math.sqrt(2))))
    p_hit = np.exp(-0.5 * ((z - zs) / sigma) ** 2) / (math.sqrt(2 * math.pi) * sigma * eta)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        p_short = np.where(
            (z <= zs) & (zs > 0), lam * np.exp(-lam * z) / (1 - np.exp(-lam * zs)), 0.0
        )
    below = z < zmax
    p = np.where(below, z_hit * p_hit + z_short * p_short + z_rand / zmax, z_max)
    return np.log(p)


def numpy_fixed_step_beam_model(parts, ranges, angles, occ, frame, zmax, params):
    """Ray casting by plain marching in half-cell steps (all rays per step), then Table 6.1."""
    from scipy.special import erf

    z_hit, z_short, z_max, z_rand, sigma, lam = params
    n, b = parts.shape[0], angles.shape[0]
    th = parts[:, 2:3] + angles[None, :]
    dx, dy = np.cos(th).ravel(), np.sin(th).ravel()
    sx = np.repeat(parts[:, 0], b)
    sy = np.repeat(parts[:, 1], b)
    zs = np.full(n * b, zmax)
    active = np.arange(n * b)
    res = frame.resolution
    h, w = occ.shape
    for t in np.arange(0.0, zmax, 0.5 * res):
        ix = np.floor((sx[active] + t * dx[active] - frame.x0) / res).astype(np.int64)
        iy = np.floor((sy[active] + t * dy[active] - frame.y0) / res).astype(np.int64)
        out = (ix < 0) | (iy < 0) | (ix >= w) | (iy >= h)
        hit = ~out & occ[np.where(out, 0, iy), np.where(out, 0, ix)]
        zs[active[hit]] = t
        active = active[~out & ~hit]
        if active.size == 0:
            break
    zs = zs.reshape(n, b)
    z = np.minimum(np.broadcast_to(ranges, zs.shape), zmax)
    eta = 0.5 * (erf((zmax - zs) / (sigma * math.sqrt(2))) + erf(zs / (sigma * math.sqrt(2))))
    p_hit = np.exp(-0.5 * ((z - zs) / sigma) ** 2) / (math.sqrt(2 * math.pi) * sigma * eta)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        p_short = np.where(
            (z <= zs) & (zs > 0), lam * np.exp(-lam * z) / (1 - np.exp(-lam * zs)), 0.0
        )
    below = z < zmax
    p = np.where(below, z_hit * p_hit + z_short * p_short + z_rand / zmax, z_max)
    return np.log(p)


def numpy_table_beam_model(parts, ranges, angles, table, quantum, frame, zmax, params):
    """Expected ranges read from the same (already filled) lookup table, then Table 6.1."""
    from scipy.special import erf

    z_hit, z_short, z_max, z_rand, sigma, lam = params
    h, w, nk = table.shape
    fx = (parts[:, 0] - frame.x0) / frame.resolution
    fy = (parts[:, 1] - frame.y0) / frame.resolution
    inside = (fx >= 0) & (fy >= 0) & (fx < w) & (fy < h)
    ix = np.where(inside, fx, 0).astype(np.int64)[:, None]
    iy = np.where(inside, fy, 0).astype(np.int64)[:, None]
    k = np.floor((parts[:, 2:3] + angles[None, :]) / (2 * np.pi / nk) + 0.5).astype(np.int64) % nk
    zs = np.where(inside[:, None], (table[iy, ix, k].astype(np.float64) - 1) * quantum, zmax)
    z = np.minimum(np.broadcast_to(ranges, zs.shape), zmax)
    eta = 0.5 * (erf((zmax - zs) / (sigma * math.sqrt(2))) + erf(zs / (sigma * math.sqrt(2))))
    p_hit = np.exp(-0.5 * ((z - zs) / sigma) ** 2) / (math.sqrt(2 * math.pi) * sigma * eta)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        p_short = np.where(
            (z <= zs) & (zs > 0), lam * np.exp(-lam * z) / (1 - np.exp(-lam * zs)), 0.0
        )
    below = z < zmax
    p = np.where(below, z_hit * p_hit + z_short * p_short + z_rand / zmax, z_max)
    return np.log(p)


def timed(fn, repeats: int) -> float:
    """Seconds per call (best of three batches of ``repeats``)."""
    best = math.inf
    for _ in range(3):
        t = time.perf_counter()
        for _ in range(repeats):
            fn()
        best = min(best, (time.perf_counter() - t) / repeats)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=10000)
    ap.add_argument("--beam-particles", type=int, default=1000)
    args = ap.parse_args()

    from probmap.filters.mcl import MCLConfig, MonteCarloLocalization
    from probmap.models.beam import BeamModel
    from probmap.models.likelihood_field import LikelihoodField
    from probmap.models.sampling import OdometryMotionModel
    from probmap.sim.localization import simulate_localization_world

    world = simulate_localization_world(0)
    zmax = world.max_range
    sigma, z_hit, z_rand = 0.2, 0.9, 0.1
    lf = LikelihoodField(
        world.spec,
        world.occupied,
        max_range=zmax,
        sigma_hit=sigma,
        z_hit=z_hit,
        z_rand=z_rand,
        max_distance=2.0,
    )
    motion = OdometryMotionModel(0.05, 0.05, 0.05, 0.05)
    n = args.particles
    rng = np.random.default_rng(0)
    # a scan whose 60 beams all return (max-range readings are skipped by the likelihood field)
    full = np.flatnonzero((world.ranges < world.max_range).all(axis=1))
    k = int(full[full >= 1][0])
    odo0, odo1 = world.odometry[k - 1], world.odometry[k]
    ranges, angles = world.ranges[k], world.angles
    lx, ly, valid = lf.endpoints(ranges, angles)
    lx, ly = lx[valid], ly[valid]
    b = lx.size

    cov = np.diag([0.05, 0.05, 0.02])
    cfg = MCLConfig(n_particles=n, resample_threshold=1.0)
    mcl = MonteCarloLocalization.from_pose(lf, motion, rng, world.poses[k - 1], cov, cfg)

    def pm_update() -> None:
        mcl.predict_and_weight(odo0, odo1, lx, ly, lf, motion)
        mcl.resample()

    state = {"p": mcl.particles.copy()}

    def np_update() -> None:
        state["p"] = numpy_update(
            state["p"],
            odo0,
            odo1,
            motion.alphas,
            lf.distance,
            lf.frame,
            lx,
            ly,
            sigma,
            z_hit,
            z_rand,
            zmax,
            rng,
        )

    # the update as probmap localize tracks (LocalizeConfig's defaults): the scan tempered to
    # 10 independent beams, the augmented-MCL averages kept (random particles only while lost:
    # none here), KLD-sampling's count at every resampling (the cloud is tight: it keeps N);
    # then also adaptive tempering, which takes less of a scan that would leave fewer than
    # 30 % effective particles (a bisection on the exponent: here, at every update)
    from probmap.filters.kld import KLDConfig
    from probmap.pipelines.localize import LocalizeConfig

    dflt = LocalizeConfig()
    cfg_d = MCLConfig(
        n_particles=n, resample_threshold=1.0,
        independent_measurements=dflt.independent_beams,
        kld=KLDConfig(n_min=n, n_max=50 * n) if dflt.kld else None,
    )  # fmt: skip
    cfg_e = dataclasses.replace(cfg_d, min_ess_fraction=dflt.min_ess_fraction)
    mcl_d, mcl_e = (
        MonteCarloLocalization.from_pose(
            lf, motion, np.random.default_rng(0), world.poses[k - 1], cov, c
        )
        for c in (cfg_d, cfg_e)
    )

    def pm_default() -> None:
        mcl_d.predict_and_weight(odo0, odo1, lx, ly, lf, motion)
        mcl_d.resample()

    def pm_tempered() -> None:
        mcl_e.predict_and_weight(odo0, odo1, lx, ly, lf, motion)
        mcl_e.resample()

    pm_update()  # compile
    pm_default()
    pm_tempered()
    t_pm = timed(pm_update, 50)
    t_pm_d = timed(pm_default, 50)
    t_pm_e = timed(pm_tempered, 50)
    t_np = timed(np_update, 5)

    parts = mcl.particles.copy()

    def pm_w():
        return lf.log_likelihood_sum_prepared(parts, lx, ly, np.ones(b, dtype=bool))

    def np_w():
        return numpy_lf_weights(parts, lf.distance, lf.frame, lx, ly, sigma, z_hit, z_rand, zmax)

    assert np.allclose(pm_w(), np_w(), atol=1e-3 * b)
    t_pm_w = timed(pm_w, 50)
    t_np_w = timed(np_w, 5)

    bm = BeamModel(world.spec, world.occupied, max_range=zmax)
    nb = args.beam_particles
    bparts = np.ascontiguousarray(parts[:nb])

    def pm_b():
        return bm.log_likelihood(bparts, ranges, angles)

    def np_b():
        return numpy_beam_model(
            bparts, ranges, angles, bm.distance, bm.occupied, bm.frame, zmax, bm.params
        )

    def np_f():
        return numpy_fixed_step_beam_model(
            bparts, ranges, angles, bm.occupied, bm.frame, zmax, bm.params
        )

    assert np.allclose(pm_b(), np_b(), atol=1e-6)
    t_pm_b = timed(pm_b, 5)
    t_np_b = timed(np_b, 2)
    t_np_f = timed(np_f, 1)

    # the lookup table of exact casts (filled for this particle cloud by the first call)
    bt = BeamModel(world.spec, world.occupied, max_range=zmax, ray_casting="table")

    def pm_t():
        return bt.log_likelihood(bparts, ranges, angles)

    def np_t():
        return numpy_table_beam_model(
            bparts, ranges, angles, bt.range_table, bt.range_quantum, bt.frame, zmax, bt.params
        )

    pm_t()
    assert np.allclose(pm_t(), np_t(), atol=1e-6)
    t_pm_t = timed(pm_t, 20)
    t_np_t = timed(np_t, 5)

    nba = nb * angles.size
    rows = [
        (f"whole update, likelihood field ({n} x {b})", n * b, t_pm, t_np),
        (f"whole update, localize defaults ({n} x {b})", n * b, t_pm_d, t_np),
        (f"the same, adaptive tempering too ({n} x {b})", n * b, t_pm_e, t_np),
        (f"likelihood-field weights only ({n} x {b})", n * b, t_pm_w, t_np_w),
        (f"beam model ({nb} x {angles.size}), table vs numpy sphere tracing", nba, t_pm_t, t_np_b),
        (
            f"beam model ({nb} x {angles.size}), table vs numpy half-cell marching",
            nba,
            t_pm_t,
            t_np_f,
        ),
        (
            f"beam model ({nb} x {angles.size}), table vs numpy on the same table",
            nba,
            t_pm_t,
            t_np_t,
        ),
        (f"beam model ({nb} x {angles.size}), sphere vs numpy sphere tracing", nba, t_pm_b, t_np_b),
    ]
    print(
        "| measurement | probmap updates/s | numpy updates/s | probmap evals/s | numpy evals/s "
        "| speed-up |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for name, evals, tp, tn in rows:
        print(
            f"| {name} | {1 / tp:,.0f} | {1 / tn:,.1f} | {evals / tp / 1e6:,.1f} M "
            f"| {evals / tn / 1e6:,.1f} M | **{tn / tp:.1f}x** |"
        )


if __name__ == "__main__":
    main()
