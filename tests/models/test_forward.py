"""Forward sensor models: kernels against slow pure-Python references, brute-force distance
transform, analytic wall distances, normalisation of the beam model density, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.grid.spec import GridSpec
from probmap.models.beam import BeamModel
from probmap.models.grid_map import occupied_mask
from probmap.models.likelihood_field import LikelihoodField


def _world():
    spec = GridSpec(0.1, (-1.0, -2.0), (40, 60))
    occ = np.zeros(spec.shape, dtype=bool)
    occ[0, :] = occ[-1, :] = True
    occ[:, 0] = occ[:, -1] = True
    occ[10:25, 30] = True  # interior wall at x in [2.0, 2.1)
    occ[30, 10:20] = True
    return spec, occ


def _brute_distance(occ, res):
    """Distance (m) from each cell centre to the nearest occupied cell centre, by brute force."""
    oy, ox = np.nonzero(occ)
    h, w = occ.shape
    d = np.empty((h, w))
    for iy in range(h):
        for ix in range(w):
            d[iy, ix] = (
                math.sqrt(min((ix - a) ** 2 + (iy - b) ** 2 for a, b in zip(ox, oy, strict=True)))
                * res
            )
    return d


def _ref_likelihood_field(
    spec, occ, poses, ranges, angles, offset, z_hit, z_rand, sigma, zmax, dmax
):
    d = np.minimum(_brute_distance(occ, spec.resolution), dmax)
    out = np.zeros((len(poses), len(ranges)))
    for n, (x, y, th) in enumerate(poses):
        # sensor pose = robot pose composed with the offset
        sx = x + math.cos(th) * offset[0] - math.sin(th) * offset[1]
        sy = y + math.sin(th) * offset[0] + math.cos(th) * offset[1]
        for b, (r, a) in enumerate(zip(ranges, angles, strict=True)):
            if not np.isfinite(r) or r >= zmax:
                continue  # Table 6.3 line 4
            ex = sx + r * math.cos(th + offset[2] + a)
            ey = sy + r * math.sin(th + offset[2] + a)
            ix = math.floor((ex - spec.origin[0]) / spec.resolution)
            iy = math.floor((ey - spec.origin[1]) / spec.resolution)
            dist = d[iy, ix] if 0 <= ix < occ.shape[1] and 0 <= iy < occ.shape[0] else dmax
            p = z_hit * math.exp(-0.5 * dist**2 / sigma**2) / (math.sqrt(2 * math.pi) * sigma)
            out[n, b] = math.log(p + z_rand / zmax)
    return out


def test_likelihood_field_matches_reference():
    spec, occ = _world()
    rng = np.random.default_rng(0)
    poses = np.column_stack(
        [rng.uniform(0, 3, 25), rng.uniform(-1, 1.5, 25), rng.uniform(-3, 3, 25)]
    )
    angles = np.linspace(-np.pi / 2, np.pi / 2, 19)
    ranges = rng.uniform(0.1, 6.0, 19)
    ranges[3] = 8.0  # max range: skipped
    ranges[5] = np.nan  # dropped reading: skipped
    offset = (0.1, -0.05, 0.2)
    lf = LikelihoodField(
        spec, occ, max_range=8.0, sigma_hit=0.15, z_hit=0.8, z_rand=0.2, max_distance=1.0
    )
    got = lf.log_likelihood(poses, ranges, angles, offset)
    ref = _ref_likelihood_field(spec, occ, poses, ranges, angles, offset, 0.8, 0.2, 0.15, 8.0, 1.0)
    # the table is float32
    assert np.allclose(got, ref, atol=1e-5)
    assert np.all(got[:, [3, 5]] == 0.0)
    assert np.allclose(lf.log_likelihood_sum(poses, ranges, angles, offset), got.sum(axis=1))
    # the precomputed distance field is the brute-force one, clipped, as float32
    assert lf.distance.dtype == np.float32
    assert np.allclose(lf.distance, np.minimum(_brute_distance(occ, 0.1), 1.0), atol=1e-6)


def test_likelihood_field_peaks_at_true_pose():
    spec, occ = _world()
    bm = BeamModel(spec, occ, max_range=8.0)
    angles = np.linspace(-np.pi / 2, np.pi / 2, 31)
    truth = np.array([0.5, 0.0, 0.1])
    ranges = bm.expected_ranges(truth, angles)[0]
    lf = LikelihoodField(spec, occ, max_range=8.0)
    shifted = truth + np.array([[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0], [0, 0, 0.1]])
    s = lf.log_likelihood_sum(shifted, ranges, angles)
    assert np.argmax(s) == 0


def _ref_cast(occ, dist, x0, y0, res, sx, sy, dx, dy, zmax):
    """Sphere tracing written out plainly: the method the kernel documents."""
    t = 0.0
    while t < zmax:
        fx, fy = (sx + t * dx - x0) / res, (sy + t * dy - y0) / res
        if fx < 0 or fy < 0 or fx >= occ.shape[1] or fy >= occ.shape[0]:
            return zmax
        ix, iy = int(fx), int(fy)
        if occ[iy, ix]:
            return t
        t += max(float(dist[iy, ix]) - math.sqrt(2) * res, 0.5 * res)
    return zmax


def test_ray_casting_matches_reference_and_walls():
    spec, occ = _world()
    bm = BeamModel(spec, occ, max_range=5.0)
    rng = np.random.default_rng(1)
    poses = np.column_stack(
        [rng.uniform(0, 1.5, 10), rng.uniform(-1, 1.5, 10), rng.uniform(-3, 3, 10)]
    )
    angles = np.linspace(-np.pi, np.pi, 37)
    got = bm.expected_ranges(poses, angles)
    for n, (x, y, th) in enumerate(poses):
        for b, a in enumerate(angles):
            ref = _ref_cast(
                occ, bm.distance, -1.0, -2.0, 0.1, x, y, math.cos(th + a), math.sin(th + a), 5.0
            )
            assert got[n, b] == pytest.approx(ref, abs=1e-9)
    # analytic: facing the interior wall whose face is at x = 2.0
    r = bm.expected_ranges([[0.55, -0.5, 0.0], [0.55, -0.5, 0.3]], [0.0])
    assert 1.45 <= r[0, 0] <= 1.45 + 0.5 * 0.1 + 1e-9
    assert 1.45 / math.cos(0.3) <= r[1, 0] <= 1.45 / math.cos(0.3) + 0.05 + 1e-9
    # nothing within range: max range
    assert bm.expected_ranges([[0.55, -0.5, np.pi / 2]], [0.0], (0, 0, 0))[0, 0] <= 5.0


def _ref_beam(z, zs, zmax, zh, zsh, zm, zr, sigma, lam):
    p = 0.0
    if z >= zmax:
        return math.log(zm)
    eta = 0.5 * (
        math.erf((zmax - zs) / (sigma * math.sqrt(2))) + math.erf(zs / (sigma * math.sqrt(2)))
    )
    p += zh * math.exp(-0.5 * (z - zs) ** 2 / sigma**2) / (math.sqrt(2 * math.pi) * sigma) / eta
    if z <= zs:
        p += zsh * lam * math.exp(-lam * z) / (1 - math.exp(-lam * zs))
    p += zr / zmax
    return math.log(p)


def test_beam_model_matches_table_6_1_reference():
    spec, occ = _world()
    params = dict(z_hit=0.7, z_short=0.1, z_max=0.1, z_rand=0.1, sigma_hit=0.2, lambda_short=0.5)
    bm = BeamModel(spec, occ, max_range=5.0, **params)
    poses = np.array([[0.5, 0.0, 0.1], [1.0, 1.0, -2.0]])
    angles = np.linspace(-np.pi / 2, np.pi / 2, 9)
    ranges = np.array([0.3, 1.0, 2.5, 5.0, 7.0, 0.0, 1.7, 3.3, 4.9])
    got = bm.log_likelihood(poses, ranges, angles)
    zs = bm.expected_ranges(poses, angles)
    for n in range(2):
        for b in range(9):
            ref = _ref_beam(min(ranges[b], 5.0), zs[n, b], 5.0, 0.7, 0.1, 0.1, 0.1, 0.2, 0.5)
            assert got[n, b] == pytest.approx(ref, rel=1e-9, abs=1e-12)


def test_beam_model_density_is_normalised():
    # integral over [0, z_max) of the continuous part plus the max-range mass = 1
    spec, occ = _world()
    w = dict(z_hit=0.6, z_short=0.2, z_max=0.05, z_rand=0.15, sigma_hit=0.3, lambda_short=0.8)
    bm = BeamModel(spec, occ, max_range=5.0, **w)
    pose = np.array([[0.55, -0.5, 0.0]])
    z = np.linspace(0.0, 5.0, 200001)[:-1] + 0.5 * 5.0 / 200000
    lik = np.array(
        [
            np.exp(bm.log_likelihood(pose, z[i : i + 5000], np.zeros(5000)))[0]
            for i in range(0, z.size, 5000)
        ]
    ).ravel()
    total = lik.sum() * (5.0 / 200000) + math.exp(bm.log_likelihood(pose, [5.0], [0.0])[0, 0])
    assert total == pytest.approx(1.0, abs=2e-3)


def test_probability_map_with_unknown_cells():
    spec, occ = _world()
    prob = np.where(occ, 0.9, 0.1)
    prob[5:8, 5:8] = np.nan
    mask = occupied_mask(prob)
    assert np.array_equal(mask, occ)
    a = LikelihoodField(spec, prob, max_range=8.0)
    b = LikelihoodField(spec, occ, max_range=8.0)
    assert np.array_equal(a.table, b.table)


def test_bad_input():
    spec, occ = _world()
    with pytest.raises(ValueError, match="does not match"):
        LikelihoodField(spec, occ[:-1], max_range=8.0)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        BeamModel(spec, occ * 2.0, max_range=8.0)
    with pytest.raises(ValueError, match="max_range"):
        LikelihoodField(spec, occ, max_range=0.0)
    with pytest.raises(ValueError, match="spec"):
        LikelihoodField(object(), occ, max_range=8.0)  # type: ignore[arg-type]
    lf = LikelihoodField(spec, occ, max_range=8.0)
    with pytest.raises(ValueError, match="equal length"):
        lf.log_likelihood([[0, 0, 0]], [1.0, 2.0], [0.0])
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        lf.log_likelihood([[0, 0]], [1.0], [0.0])
    with pytest.raises(ValueError, match="non-negative"):
        lf.log_likelihood([[0, 0, 0]], [-1.0], [0.0])


def _ref_exact_cast(occ, gx, gy, dx, dy, limit):
    """Exact traversal written out plainly (cell units): step to the nearer of the next x or
    y cell boundary, one cell at a time, until an occupied cell is entered."""
    ix, iy = math.floor(gx), math.floor(gy)
    t = 0.0
    while t < limit:
        if not (0 <= ix < occ.shape[1] and 0 <= iy < occ.shape[0]):
            return limit
        if occ[iy, ix]:
            return t
        # parameters at which the ray reaches the next vertical / horizontal boundary
        tx = ((ix + (dx > 0)) - gx) / dx if dx != 0 else math.inf
        ty = ((iy + (dy > 0)) - gy) / dy if dy != 0 else math.inf
        if tx < ty:
            t, ix = tx, ix + (1 if dx > 0 else -1)
        else:
            t, iy = ty, iy + (1 if dy > 0 else -1)
    return limit


def test_exact_ray_casting_matches_reference_and_raycast_module():
    from probmap.grid.raycast import cast_rays

    spec, occ = _world()
    bm = BeamModel(spec, occ, max_range=5.0, ray_casting="exact")
    rng = np.random.default_rng(2)
    poses = np.column_stack(
        [rng.uniform(0, 1.5, 12), rng.uniform(-1, 1.5, 12), rng.uniform(-3, 3, 12)]
    )
    angles = np.linspace(-np.pi, np.pi, 41)
    offset = (0.1, -0.05, 0.3)
    got = bm.expected_ranges(poses, angles, offset)
    for n, (x, y, th) in enumerate(poses):
        sx = x + math.cos(th) * offset[0] - math.sin(th) * offset[1]
        sy = y + math.sin(th) * offset[0] + math.cos(th) * offset[1]
        gx, gy = (sx + 1.0) / 0.1, (sy + 2.0) / 0.1
        for b, a in enumerate(angles):
            h = th + offset[2] + a
            ref = _ref_exact_cast(occ, gx, gy, math.cos(h), math.sin(h), 50.0) * 0.1
            assert got[n, b] == pytest.approx(min(ref, 5.0), abs=1e-9)
    # the Amanatides-Woo caster of probmap.grid.raycast agrees (no sensor offset)
    assert np.allclose(bm.expected_ranges(poses, angles), cast_rays(occ, spec, poses, angles, 5.0))
    # analytic: the interior wall's face is at x = 2.0
    r = bm.expected_ranges([[0.55, -0.5, 0.0], [0.55, -0.5, 0.3]], [0.0])
    assert r[:, 0] == pytest.approx([1.45, 1.45 / math.cos(0.3)], abs=1e-9)


def test_table_ray_casting_is_exact_at_cell_centres_and_bin_headings():
    spec, occ = _world()
    k_bins = 70  # no bin at 45 degrees: rays from a centre through exact cell corners tie
    tb = BeamModel(spec, occ, max_range=5.0, ray_casting="table", heading_bins=k_bins)
    ex = BeamModel(spec, occ, max_range=5.0, ray_casting="exact")
    ix, iy = np.meshgrid(np.arange(1, 59, 3), np.arange(1, 39, 3))
    centres = np.column_stack([-1.0 + (ix.ravel() + 0.5) * 0.1, -2.0 + (iy.ravel() + 0.5) * 0.1])
    bins = np.arange(k_bins) * (2 * np.pi / k_bins)
    poses = np.column_stack([centres, np.zeros(len(centres))])
    assert np.count_nonzero(tb.range_table) == 0  # nothing cast before it is asked for
    got = tb.expected_ranges(poses, bins)
    assert np.abs(got - ex.expected_ranges(poses, bins)).max() <= tb.range_quantum / 2 + 1e-12
    assert tb.range_table.shape == (40, 60, k_bins) and tb.range_table.dtype == np.uint16
    assert np.count_nonzero(tb.range_table) == len(centres) * k_bins
    # the nearest bin is found for negative headings and headings past 2 pi, and within a cell
    th = -7.3 * 2 * np.pi / k_bins
    angles = bins - th + np.tile([0.0, 2 * np.pi, -4 * np.pi], k_bins)[:k_bins]
    shifted = np.column_stack([centres + 0.04, np.full(len(centres), th)])
    assert np.array_equal(tb.expected_ranges(shifted, angles), got)
    # sensor outside the map: max range, as a ray leaving the map
    assert np.all(tb.expected_ranges([[-5.0, 0.0, 0.0]], [0.0, 1.0]) == 5.0)


def test_table_ray_casting_error_against_exact_casting():
    # snapping to the cell centre (<= res / sqrt 2) and to the nearest of 360 bins (<= 0.5 deg)
    spec, occ = _world()
    tb = BeamModel(spec, occ, max_range=5.0, ray_casting="table")
    ex = BeamModel(spec, occ, max_range=5.0, ray_casting="exact")
    rng = np.random.default_rng(3)
    free = np.argwhere(~occ)
    cells = free[rng.integers(0, len(free), 400)]
    poses = np.column_stack(
        [
            -1.0 + (cells[:, 1] + rng.uniform(0, 1, 400)) * 0.1,
            -2.0 + (cells[:, 0] + rng.uniform(0, 1, 400)) * 0.1,
            rng.uniform(-np.pi, np.pi, 400),
        ]
    )
    angles = np.linspace(-np.pi / 2, np.pi / 2, 31)
    err = np.abs(tb.expected_ranges(poses, angles) - ex.expected_ranges(poses, angles))
    # measured here: median 0.031 m, 95th percentile 0.10 m (0.1 m cells); rays that graze a
    # corner may hit a different wall, hence no bound on the maximum
    assert np.median(err) < 0.06
    assert np.percentile(err, 90) < 0.15
    assert np.mean(err < 0.25) > 0.95


def test_table_beam_model_matches_table_6_1_reference():
    spec, occ = _world()
    params = dict(z_hit=0.7, z_short=0.1, z_max=0.1, z_rand=0.1, sigma_hit=0.2, lambda_short=0.5)
    bm = BeamModel(spec, occ, max_range=5.0, ray_casting="table", heading_bins=720, **params)
    poses = np.array([[0.5, 0.0, 0.1], [1.0, 1.0, -2.0], [-3.0, 0.0, 0.0], [1.2, -0.4, 9.0]])
    angles = np.linspace(-np.pi / 2, np.pi / 2, 10)
    ranges = np.array([0.3, 1.0, 2.5, 5.0, 7.0, 0.0, 1.7, 3.3, 4.9, np.nan])
    got = bm.log_likelihood(poses, ranges, angles, (0.05, 0.0, 0.1))
    zs = bm.expected_ranges(poses, angles, (0.05, 0.0, 0.1))
    for n in range(len(poses)):
        for b in range(9):
            ref = _ref_beam(min(ranges[b], 5.0), zs[n, b], 5.0, 0.7, 0.1, 0.1, 0.1, 0.2, 0.5)
            assert got[n, b] == pytest.approx(ref, rel=1e-9, abs=1e-12)
    assert np.all(got[:, 9] == 0.0)
    # the other casting methods give the same mixture for their own expected ranges
    for method in ("sphere", "exact"):
        other = BeamModel(spec, occ, max_range=5.0, ray_casting=method, **params)
        zo = other.expected_ranges(poses, angles)
        lo = other.log_likelihood(poses, ranges, angles)
        ref = _ref_beam(min(ranges[2], 5.0), zo[1, 2], 5.0, 0.7, 0.1, 0.1, 0.1, 0.2, 0.5)
        assert lo[1, 2] == pytest.approx(ref, rel=1e-9)


def test_ray_casting_bad_input():
    spec, occ = _world()
    with pytest.raises(ValueError, match="ray_casting"):
        BeamModel(spec, occ, max_range=5.0, ray_casting="bresenham")
    with pytest.raises(ValueError, match="heading_bins"):
        BeamModel(spec, occ, max_range=5.0, ray_casting="table", heading_bins=2)


@pytest.mark.parametrize("kind", ["beam", "beam-table", "field"])
def test_both_models_share_the_scan_likelihood_interface(kind):
    """One home (models.grid_map.ScanLikelihood): the scan sum is the sum of the per-beam terms,
    for the beam model (sum of its beams) and the likelihood field (its own summing kernel), and
    both refuse bad poses and scans with the same words, poses first."""
    from probmap.models.grid_map import ScanLikelihood

    spec, occ = _world()
    if kind == "field":
        model = LikelihoodField(spec, occ, max_range=4.0, sigma_hit=0.2)
    else:
        casting = "table" if kind == "beam-table" else "sphere"
        model = BeamModel(spec, occ, max_range=4.0, ray_casting=casting, heading_bins=64)
    assert isinstance(model, ScanLikelihood)
    rng = np.random.default_rng(3)
    poses = np.column_stack([rng.uniform(0, 4, 5), rng.uniform(-1, 1.5, 5), rng.uniform(-3, 3, 5)])
    angles = np.linspace(-1.5, 1.5, 21)
    ranges = rng.uniform(0.2, 5.0, 21)  # some beyond max_range
    offset = (0.1, -0.05, 0.2)
    per_beam = model.log_likelihood(poses, ranges, angles, offset)
    assert per_beam.shape == (5, 21) and np.all(np.isfinite(per_beam))
    np.testing.assert_allclose(
        model.log_likelihood_sum(poses, ranges, angles, offset), per_beam.sum(axis=1), rtol=1e-6
    )
    one = model.log_likelihood(poses[2], ranges, angles, offset)  # one pose (3,) is one row
    np.testing.assert_allclose(one, per_beam[2:3])
    for method in (model.log_likelihood, model.log_likelihood_sum):
        with pytest.raises(ValueError, match="poses must be finite"):
            method([np.nan, 0.0, 0.0], ranges[:3], angles[3:])  # bad poses named before the scan
        with pytest.raises(ValueError, match="ranges and angles must be 1-D arrays of equal"):
            method(poses, ranges[:3], angles)
        with pytest.raises(ValueError, match="sensor_offset must be a finite"):
            method(poses, ranges, angles, (0.0, 0.0))
