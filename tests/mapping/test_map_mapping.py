"""MAP occupancy grid mapping: kernels against pure-Python references, the hill climber's
properties (every flip raises the objective, the result is a local optimum), the open-door
corridor with a wide-beam sonar, bad input, and the Intel corrected log."""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.grid.raycast import cast_rays
from probmap.grid.spec import GridSpec
from probmap.mapping import _map_kernels as _k
from probmap.mapping.map_mapping import (
    BeamIndex,
    MapMapper,
    MapMappingConfig,
    cone_offsets,
    map_mapping,
)
from probmap.models.beam import BeamModelParams

# ----------------------------------------------------------------------------- references


def ref_log_likelihood(z, zs, zmax, p: BeamModelParams) -> float:
    """Eq. 6.12 written out term by term (Table 6.1)."""
    if z >= zmax:
        return math.log(p.z_max)
    s = p.sigma_hit
    norm = 0.5 * (math.erf((zmax - zs) / (s * math.sqrt(2))) + math.erf(zs / (s * math.sqrt(2))))
    hit = math.exp(-0.5 * ((z - zs) / s) ** 2) / (s * math.sqrt(2 * math.pi)) / norm
    lam = p.lambda_short
    short = lam * math.exp(-lam * z) / (1 - math.exp(-lam * zs)) if (z <= zs and zs > 0) else 0.0
    return math.log(p.z_hit * hit + p.z_short * short + p.z_rand / zmax)


def ref_window(spec: GridSpec, sx, sy, theta, length, offsets) -> dict[int, float]:
    """Cells a cone's sub-rays cross before ``length`` and the range where each is first met,
    by intersecting every ray with every cell box (slab method)."""
    h, w = spec.shape
    r = spec.resolution
    x0, y0 = spec.origin
    out: dict[int, float] = {}
    for off in offsets:
        dx, dy = math.cos(theta + off), math.sin(theta + off)
        for iy in range(h):
            for ix in range(w):
                lo_t, hi_t = 0.0, math.inf
                ok = True
                for s, d, a, b in (
                    (sx, dx, x0 + ix * r, x0 + (ix + 1) * r),
                    (sy, dy, y0 + iy * r, y0 + (iy + 1) * r),
                ):
                    if d == 0.0:
                        ok = ok and a <= s < b
                        continue
                    t1, t2 = (a - s) / d, (b - s) / d
                    lo_t, hi_t = max(lo_t, min(t1, t2)), min(hi_t, max(t1, t2))
                if ok and hi_t > lo_t and lo_t < length:
                    c = iy * w + ix
                    out[c] = min(out.get(c, math.inf), lo_t)
    return out


def _beams(poses, ranges, angles, max_range, window):
    """Windowed beams in the order BeamIndex uses: (sx, sy, theta, z, length)."""
    si, bi = np.nonzero(np.isfinite(ranges) & (ranges > 0) & (ranges < max_range))
    z = ranges[si, bi]
    return [
        (poses[s, 0], poses[s, 1], poses[s, 2] + angles[b], zz, min(zz + window, max_range))
        for s, b, zz in zip(si, bi, z, strict=True)
    ]


def ref_objective(occ, windows, beams, n_max, max_range, p, l0) -> float:
    flat = occ.ravel()
    total = n_max * math.log(p.z_max) + l0 * int(flat.sum())
    for win, (_, _, _, z, length) in zip(windows, beams, strict=True):
        hits = [d for c, d in win.items() if flat[c]]
        total += ref_log_likelihood(z, min(hits) if hits else length, max_range, p)
    return total


def small_world(seed: int, *, cone: bool = False):
    rng = np.random.default_rng(seed)
    spec = GridSpec(0.25, (-1.0, -0.5), (12, 15))
    truth = rng.random(spec.shape) < 0.12
    truth[0, :] = truth[-1, :] = truth[:, 0] = truth[:, -1] = True
    poses = np.column_stack(
        [rng.uniform(0.0, 1.8, 4), rng.uniform(0.5, 1.8, 4), rng.uniform(-np.pi, np.pi, 4)]
    )
    angles = np.linspace(-1.2, 1.2, 5)
    opening, subrays = (0.4, 3) if cone else (0.0, 1)
    true_r = cast_rays(truth, spec, poses, angles, 6.0)
    ranges = np.clip(true_r + rng.normal(0, 0.08, true_r.shape), 0.05, 6.0)
    ranges[0, 0] = 6.0  # a max-range reading
    cfg = MapMappingConfig(
        resolution=0.25, p0=0.4, opening=opening, subrays=subrays, window=0.4, max_sweeps=30
    )
    return spec, truth, poses, ranges, angles, cfg


# ----------------------------------------------------------------------------- the model


def test_log_likelihood_matches_reference_and_forward_model():
    from probmap.models import _beam_kernels as bk

    p = BeamModelParams()
    rng = np.random.default_rng(1)
    for _ in range(300):
        zs = float(rng.uniform(0.0, 9.0))
        z = float(rng.choice([rng.uniform(0.0, 10.0), zs + rng.normal(0, 0.2), 10.0]))
        z = min(max(z, 0.0), 10.0)
        ours = float(p.log_likelihood(z, zs, 10.0))
        assert ours == pytest.approx(ref_log_likelihood(z, zs, 10.0, p), rel=1e-12, abs=1e-12)
        # the particle filter's beam model (Table 6.1) calls the same scalar kernel
        theirs = bk.beam_log_likelihood(z, zs, 10.0, *p.as_array())
        assert ours == pytest.approx(theirs, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("zs", [0.3, 2.0, 7.9])
def test_beam_density_integrates_to_one(zs):
    """The mixture is a density on [0, z_max) plus the point mass z_max at z_max."""
    p = BeamModelParams()
    zmax = 8.0
    z = np.linspace(0.0, zmax, 400_001)[:-1]
    dens = np.exp(p.log_likelihood(z, np.full_like(z, zs), zmax))
    integral = float(np.sum(0.5 * (dens[1:] + dens[:-1]) * np.diff(z)))  # trapezoid rule
    assert integral + p.z_max == pytest.approx(1.0, abs=2e-3)


def test_params_validation_keeps_likelihoods_positive():
    with pytest.raises(ValueError, match="z_rand"):
        BeamModelParams(z_hit=0.85, z_rand=0.0)
    with pytest.raises(ValueError, match="z_max"):
        BeamModelParams(z_hit=0.85, z_max=0.0)
    with pytest.raises(ValueError, match="sum to 1"):
        BeamModelParams(z_hit=0.5)
    with pytest.raises(ValueError, match="sigma_hit"):
        BeamModelParams(sigma_hit=-0.1)


# ----------------------------------------------------------------------------- the index


@pytest.mark.parametrize("cone", [False, True])
def test_windows_match_slab_reference(cone):
    spec, _, poses, ranges, angles, cfg = small_world(3, cone=cone)
    index = BeamIndex.build(poses, ranges, angles, 6.0, cfg, spec=spec)
    beams = _beams(poses, ranges, angles, 6.0, cfg.window_m)
    assert index.beams == len(beams)
    assert index.max_range_beams == 1
    offs = cone_offsets(cfg.opening, cfg.subrays)
    for b, (sx, sy, th, _, length) in enumerate(beams):
        ref = ref_window(spec, sx, sy, th, length, offs)
        sl = slice(index.f_ptr[b], index.f_ptr[b + 1])
        got = dict(zip(index.f_cell[sl].tolist(), index.f_dist[sl].tolist(), strict=True))
        assert set(got) == set(ref), f"beam {b}"
        for c, d in ref.items():
            assert got[c] == pytest.approx(d, abs=1e-9)
        assert np.all(np.diff(index.f_dist[sl]) >= 0)  # sorted by range
    # the inverse index names every (cell, beam) dependency exactly once
    pairs = {(int(c), int(index.e_beam[e])) for e, c in enumerate(index.f_cell)}
    inv = set()
    for c in range(spec.shape[0] * spec.shape[1]):
        for i in range(index.i_ptr[c], index.i_ptr[c + 1]):
            inv.add((c, int(index.e_beam[index.i_entry[i]])))
    assert inv == pairs and len(pairs) == index.entries


def test_expected_range_is_the_exact_ray_cast():
    """With a window reaching the maximum range, z* is the lead's exact traversal's range."""
    spec, truth, poses, ranges, angles, _ = small_world(5)
    cfg = MapMappingConfig(resolution=0.25, window=100.0)
    far = np.full_like(ranges, 0.01)  # every beam windowed up to max range
    index = BeamIndex.build(poses, far, angles, 6.0, cfg, spec=spec)
    first = np.empty(index.beams, dtype=np.int64)
    ll = np.empty(index.beams)
    _k.evaluate_beams(
        truth.ravel().astype(np.uint8), index.f_ptr, index.f_cell, index.f_ll, index.far_ll,
        first, ll,
    )  # fmt: skip
    zs = np.where(first >= 0, index.f_dist[np.maximum(first, 0)], 6.0)
    expected = cast_rays(truth, spec, poses, angles, 6.0).ravel()
    np.testing.assert_allclose(zs, expected, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("cone", [False, True])
def test_objective_matches_reference(seed, cone):
    spec, truth, poses, ranges, angles, cfg = small_world(seed, cone=cone)
    index = BeamIndex.build(poses, ranges, angles, 6.0, cfg, spec=spec)
    beams = _beams(poses, ranges, angles, 6.0, cfg.window_m)
    offs = cone_offsets(cfg.opening, cfg.subrays)
    windows = [ref_window(spec, sx, sy, th, ln, offs) for sx, sy, th, _, ln in beams]
    rng = np.random.default_rng(seed)
    for occ in (truth, np.zeros_like(truth), rng.random(truth.shape) < 0.3):
        ref = ref_objective(occ, windows, beams, 1, 6.0, cfg.model, cfg.l0)
        assert index.objective(occ, cfg.l0) == pytest.approx(ref, rel=1e-10)


# ----------------------------------------------------------------------------- hill climbing


@pytest.mark.parametrize("seed", range(6))
def test_every_flip_raises_objective_and_result_is_local_optimum(seed):
    """Property over random small worlds: each accepted flip raises the objective by exactly its
    computed gain (checked from scratch by the reference), and at the end no flip helps."""
    spec, _, poses, ranges, angles, cfg = small_world(seed, cone=seed % 2 == 1)
    index = BeamIndex.build(poses, ranges, angles, 6.0, cfg, spec=spec)
    beams = _beams(poses, ranges, angles, 6.0, cfg.window_m)
    offs = cone_offsets(cfg.opening, cfg.subrays)
    windows = [ref_window(spec, sx, sy, th, ln, offs) for sx, sy, th, _, ln in beams]
    mapper = MapMapper(index, cfg.l0)
    args = mapper._args()
    occ = mapper._occ
    before = ref_objective(occ.reshape(spec.shape), windows, beams, 1, 6.0, cfg.model, cfg.l0)
    flips = 0
    for _ in range(30):  # Table 9.3, one flip at a time, checked against the reference
        changed = False
        for c in mapper._cells:
            gain = _k.flip_gain(c, *args, cfg.l0)
            if gain > cfg.tol:
                _k.apply_flip(c, *args)
                after = ref_objective(
                    occ.reshape(spec.shape), windows, beams, 1, 6.0, cfg.model, cfg.l0
                )
                assert after > before
                assert after - before == pytest.approx(gain, rel=1e-9, abs=1e-9)
                before, changed, flips = after, True, flips + 1
        if not changed:
            break
    assert flips > 0
    final = occ.reshape(spec.shape).copy()
    # local optimum, by brute force over every cell of the grid
    for c in range(final.size):
        trial = final.copy().ravel()
        trial[c] = not trial[c]
        obj = ref_objective(trial.reshape(spec.shape), windows, beams, 1, 6.0, cfg.model, cfg.l0)
        assert obj <= before + 1e-9
    # the kernel sweeps, in either order, reach local optima with exact bookkeeping
    from dataclasses import replace

    for order in ("gain", "raster"):
        res = map_mapping(poses, ranges, angles, 6.0, replace(cfg, order=order), spec=spec)
        assert res.converged
        objs = [r.objective for r in res.history]
        assert all(b > a for a, b in zip(objs[:-2], objs[1:-1], strict=True))
        assert objs[-1] == pytest.approx(res.objective, rel=1e-9)
        assert np.all(MapMapper(res.index, cfg.l0, res.occupied).flip_gains() <= cfg.tol)
        final_ref = ref_objective(res.occupied, windows, beams, 1, 6.0, cfg.model, cfg.l0)
        assert final_ref == pytest.approx(res.objective, rel=1e-9)


def test_objective_stays_finite_by_construction():
    """Zero-probability beams are impossible: readings of 0+, at z* = 0 (sensor inside an
    obstacle), far short of or beyond every obstacle all give finite log-likelihoods."""
    spec = GridSpec(0.5, (-2.0, -2.0), (8, 8))
    poses = np.array([[0.1, 0.1, 0.0], [1.0, -1.0, 2.0]])
    angles = np.linspace(-np.pi, np.pi, 9)[:-1]
    ranges = np.array([[1e-9, 0.2, 1.5, 2.9999999, 3.0, 50.0, 1.0, 2.0]] * 2)
    cfg = MapMappingConfig(resolution=0.5, model=BeamModelParams(sigma_hit=0.01), window=0.0)
    index = BeamIndex.build(poses, ranges, angles, 3.0, cfg, spec=spec)
    for occ in (np.ones(spec.shape, bool), np.zeros(spec.shape, bool)):
        assert np.isfinite(index.beam_log_likelihoods(occ)).all()
        assert math.isfinite(index.objective(occ, cfg.l0))
    assert np.isfinite(index.f_ll).all() and np.isfinite(index.far_ll).all()
    res = map_mapping(poses, ranges, angles, 3.0, cfg, spec=spec)
    assert all(math.isfinite(r.objective) for r in res.history)


# ----------------------------------------------------------------------------- the open door


def test_open_door_with_sonar_beats_log_odds():
    """Probabilistic Robotics 9.4: a wide cone in a corridor with an open door."""
    from probmap.mapping.sonar import cone_log_odds_grid, corridor_with_door

    w = corridor_with_door(step=0.2)
    cfg = MapMappingConfig(
        resolution=w.spec.resolution,
        opening=w.opening,
        subrays=w.subrays,
        model=BeamModelParams(sigma_hit=0.1),
    )
    res = map_mapping(w.poses, w.ranges, w.angles, w.max_range, cfg, spec=w.spec)
    grid = cone_log_odds_grid(
        w.poses, w.ranges, w.angles, w.max_range, w.spec, opening=w.opening, subrays=w.subrays
    )
    log_odds = grid.classify(0.5, 0.5) == 1
    obs = res.observed
    obj_lo = res.index.objective(log_odds, cfg.l0)
    acc_lo = float((log_odds[obs] == w.truth[obs]).mean())
    acc_map = float((res.occupied[obs] == w.truth[obs]).mean())
    print(
        f"\nopen door, sonar {math.degrees(w.opening):.0f} deg: objective log-odds {obj_lo:.1f}"
        f" vs MAP {res.objective:.1f}; accuracy log-odds {100 * acc_lo:.2f} %"
        f" vs MAP {100 * acc_map:.2f} % of {int(obs.sum())} cells"
    )
    assert res.converged
    assert res.objective > obj_lo
    assert acc_map > acc_lo
    # the door (cells of the wall gap) stays open in the MAP map
    door = w.spec.world_to_cell([[4.0, 2.7]])[0]
    assert not res.occupied[door[1] - 1 : door[1] + 2, door[0] - 2 : door[0] + 3].any()
    # starting from the log-odds map can only improve on it
    res2 = map_mapping(w.poses, w.ranges, w.angles, w.max_range, cfg, spec=w.spec, init=log_odds)
    assert res2.history[0].objective == pytest.approx(obj_lo, rel=1e-9)
    assert res2.objective >= obj_lo


def test_log_odds_init_option():
    spec, _, poses, ranges, angles, cfg = small_world(2)
    from dataclasses import replace

    res = map_mapping(poses, ranges, angles, 6.0, replace(cfg, init="log-odds"), spec=spec)
    assert res.converged
    assert res.objective >= res.history[0].objective


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"poses": np.zeros((2, 2))}, "poses must have shape"),
        ({"poses": np.array([[0, 0, 0], [np.nan, 0, 0]])}, "pose 1"),
        ({"ranges": np.ones((3, 5))}, "ranges must have shape"),
        ({"angles": np.zeros(4)}, "angles shape"),
        ({"max_range": -1.0}, "max_range"),
        ({"max_range": np.inf}, "max_range"),
    ],
)
def test_bad_input(kwargs, match):
    args = {
        "poses": np.zeros((2, 3)),
        "ranges": np.ones((2, 5)),
        "angles": np.zeros(5),
        "max_range": 5.0,
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        map_mapping(args["poses"], args["ranges"], args["angles"], args["max_range"])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"p0": 1.0}, "p0"),
        ({"init": "ones"}, "init"),
        ({"subrays": 3}, "subrays"),
        ({"opening": 4.0, "subrays": 3}, "opening"),
        ({"max_sweeps": 0}, "max_sweeps"),
        ({"window": -1.0}, "window"),
        ({"resolution": 0.0}, "resolution"),
        ({"order": "random"}, "order"),
    ],
)
def test_bad_config(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MapMappingConfig(**kwargs)


def test_bad_init_shape():
    spec, _, poses, ranges, angles, cfg = small_world(0)
    with pytest.raises(ValueError, match="does not match the grid"):
        map_mapping(poses, ranges, angles, 6.0, cfg, spec=spec, init=np.zeros((3, 3), bool))


# ----------------------------------------------------------------------------- real data


def test_intel_corrected_converges(shared_data):
    from probmap.datasets.carmen import load_scans
    from probmap.pipelines import MappingConfig, map_log_map

    log = shared_data("intel-research-lab/intel-corrected.log.gz")
    sweeps = []
    result = map_log_map(log, MappingConfig(resolution=0.1), sweeps.append)
    ex = result.extra
    print(
        f"\nIntel corrected at 0.1 m: {int(ex['sweeps'])} sweeps, objective "
        f"{ex['objective_0']:.0f} -> {ex['objective']:.0f}, index {ex['index_seconds']:.2f} s, "
        f"sweeps {ex['sweep_seconds']:.2f} s"
    )
    assert ex["converged"] == 1.0
    assert len(sweeps) == int(ex["sweeps"]) + 1
    objs = [r.objective for r in sweeps]
    assert all(b >= a for a, b in zip(objs, objs[1:], strict=False))
    assert math.isfinite(ex["objective"])
    # most scan endpoints fall in (or next to) an occupied MAP cell
    batch = load_scans(log)
    occ = result.grid.classify(0.5, 0.5) == 1
    spec = result.grid.spec
    hit = batch.ranges < batch.max_range
    p = np.asarray(batch.laser_poses)[:, None, :]
    a = p[..., 2] + np.asarray(batch.angles)
    ex_, ey_ = p[..., 0] + batch.ranges * np.cos(a), p[..., 1] + batch.ranges * np.sin(a)
    cells = spec.world_to_cell(np.column_stack([ex_[hit], ey_[hit]]))
    near = np.zeros(len(cells), bool)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            c = cells + [dx, dy]
            inside = spec.contains(c)
            near[inside] |= occ[c[inside, 1], c[inside, 0]]
    rate = float(near.mean())
    print(f"Intel MAP: {100 * rate:.1f} % of endpoints within one cell of an occupied cell")
    assert rate > 0.85


# ----------------------------------------------------------------------------- sonar cones


@pytest.mark.parametrize("tilt", [0.0, 0.2, 0.5])
def test_cone_reading_is_nearest_subray_to_a_wall(tilt):
    """A wall at x = 3 m: each sub-ray at angle a from the normal reads 3 / cos(a) (minus the
    sensor's x); the cone reads the smallest."""
    from probmap.mapping.sonar import simulate_cone_ranges

    spec = GridSpec(0.05, (-1.0, -5.0), (200, 120))
    occ = np.zeros(spec.shape, bool)
    occ[:, spec.world_to_cell([[3.0, 0.0]])[0, 0] :] = True
    pose = np.array([[0.0, 0.0, 0.0]])
    z = simulate_cone_ranges(occ, spec, pose, [tilt], 8.0, opening=0.6, subrays=7)
    expected = min(3.0 / math.cos(tilt + o) for o in cone_offsets(0.6, 7))
    assert z[0, 0] == pytest.approx(expected, abs=1e-9)
