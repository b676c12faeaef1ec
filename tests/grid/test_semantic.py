"""Semantic grid: pure-Python reference of the kernel, the exact K = 1 reduction, closed forms,
the once-per-scan rule with pooled endpoints, posterior numerics and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.grid.logodds import logit
from probmap.grid.occupancy import GridBoundsError, InverseSensorModel, OccupancyGrid
from probmap.grid.semantic import (
    LabelledInverseModel,
    SemanticGrid,
    class_entropy,
    class_posterior,
    inverse_term,
    map_argmax,
    occupancy_log_odds,
)
from probmap.grid.spec import GridSpec

# --------------------------------------------------------------------------- reference


def segment_cells(gx0, gy0, gx1, gy1):
    """Cells whose square meets the segment, in order along it (Liang-Barsky clipping of every
    cell of the bounding box; independent of the kernel's incremental walk)."""
    found = []
    for ix in range(math.floor(min(gx0, gx1)), math.floor(max(gx0, gx1)) + 1):
        for iy in range(math.floor(min(gy0, gy1)), math.floor(max(gy0, gy1)) + 1):
            t_in, t_out, empty = 0.0, 1.0, False
            for p, q in (
                (-(gx1 - gx0), gx0 - ix),
                (gx1 - gx0, ix + 1 - gx0),
                (-(gy1 - gy0), gy0 - iy),
                (gy1 - gy0, iy + 1 - gy0),
            ):
                if p == 0:
                    empty = empty or q < 0
                elif p < 0:
                    t_in = max(t_in, q / p)
                else:
                    t_out = min(t_out, q / p)
            if not empty and t_in <= t_out:
                found.append((t_in, ix, iy))
    return [(ix, iy) for _, ix, iy in sorted(found)]


def reference_semantic(grid, poses, ranges, angles, max_range, q_of_beam):
    """Slow reference of the multi-class update with the once-per-scan rule and pooled endpoints.

    ``q_of_beam(s, b)`` gives p(m = k | z) for classes 1..K of beam b's endpoint in scan s.
    Returns (log_odds, observed) computed from scratch on ``grid.spec``.
    """
    spec, model = grid.spec, grid.model
    K = grid.n_classes
    lp = [float(v) for v in grid.l_prior]
    lo = np.empty((*spec.shape, K), np.float32)
    lo[...] = np.float32(grid.l_prior)
    seen = np.zeros(spec.shape, bool)
    ox, oy = spec.origin
    inv = 1.0 / spec.resolution
    clear = max_range if model.max_clear_range is None else model.max_clear_range
    q_free = [model.p_miss / K] * K

    def delta(q):
        log_q0 = math.log1p(-sum(q))
        return [math.log(qk) - log_q0 - lp[k] for k, qk in enumerate(q)]

    def apply(ix, iy, d):
        if 0 <= ix < spec.width and 0 <= iy < spec.height:
            for k in range(K):
                v = float(lo[iy, ix, k]) + d[k]
                lo[iy, ix, k] = min(max(v, grid.l_min[k]), grid.l_max[k])
            seen[iy, ix] = True

    for s in range(len(poses)):
        px, py, th = poses[s]
        gx0, gy0 = (px - ox) * inv, (py - oy) * inv
        hits: dict[tuple[int, int], list[tuple[float, ...]]] = {}
        free = set()
        for b, (r, a) in enumerate(zip(ranges[s], angles, strict=True)):
            if not (r > 0) or not math.isfinite(r):
                continue
            c, sn = math.cos(th + a), math.sin(th + a)
            if r >= max_range:
                if clear <= 0:
                    continue
                ex, ey = (px + clear * c - ox) * inv, (py + clear * sn - oy) * inv
            else:
                ex, ey = (px + r * c - ox) * inv, (py + r * sn - oy) * inv
                tx = (px + (r + model.thickness) * c - ox) * inv
                ty = (py + (r + model.thickness) * sn - oy) * inv
                for cell in segment_cells(ex, ey, tx, ty):
                    hits.setdefault(cell, []).append(tuple(q_of_beam(s, b)))
            free.update(segment_cells(gx0, gy0, ex, ey)[:-1])
        for (ix, iy), qs in hits.items():
            pooled = [sum(q[k] for q in qs) / len(qs) for k in range(K)]
            apply(ix, iy, delta(pooled))
        for ix, iy in free - set(hits):
            apply(ix, iy, delta(q_free))
    return lo, seen


def random_scans(rng, n_scans, n_beams, spread=3.0):
    poses = np.column_stack(
        [
            rng.uniform(-1, 1, n_scans),
            rng.uniform(-1, 1, n_scans),
            rng.uniform(-np.pi, np.pi, n_scans),
        ]
    )
    ranges = rng.uniform(0.05, spread, (n_scans, n_beams))
    ranges[rng.random(ranges.shape) < 0.05] = np.nan
    ranges[rng.random(ranges.shape) < 0.05] = -1.0
    ranges[rng.random(ranges.shape) < 0.1] = spread + 1.0
    # bunches of beams with nearly equal angles so that many endpoints share cells
    angles = np.sort(np.round(rng.uniform(-np.pi, np.pi, n_beams), 1))
    return poses, ranges, angles


CLASSES = ("free", "wall", "door", "chair")


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("thickness,clear", [(0.0, None), (0.12, 1.5), (0.0, 0.0)])
@pytest.mark.parametrize("soft", [False, True])
def test_kernel_matches_reference(seed, thickness, clear, soft):
    rng = np.random.default_rng(seed)
    res = float(rng.choice([0.05, 0.1, 0.23]))
    poses, ranges, angles = random_scans(rng, 5, 40)
    model = LabelledInverseModel(
        p_hit=0.75, p_miss=0.35, p_correct=0.8, thickness=thickness, max_clear_range=clear
    )
    spec = GridSpec(res, (-6.0, -6.5), (int(13 / res), int(12 / res)))
    grid = SemanticGrid(
        CLASSES,
        resolution=res,
        prior=[0.4, 0.3, 0.2, 0.1],
        clamp=(0.02, 0.95),
        model=model,
        spec=spec,
        fixed=True,
    )
    K = grid.n_classes
    if soft:
        v = rng.dirichlet(np.ones(K), ranges.shape)
        grid.integrate_scans(poses, ranges, angles, probabilities=v, max_range=3.5)
        table = model.hit_probabilities(v)

        def q_of_beam(s, b):
            return table[s, b]
    else:
        labels = rng.integers(1, K + 1, ranges.shape)
        grid.integrate_scans(poses, ranges, angles, labels=labels, max_range=3.5)
        table = model.hit_probabilities(model.confusion(K))

        def q_of_beam(s, b):
            return table[labels[s, b] - 1]

    lo, seen = reference_semantic(grid, poses, ranges, angles, 3.5, q_of_beam)
    np.testing.assert_array_equal(grid.observed, seen)
    # pooled cells go through log() in numba and in Python: equal up to float32 rounding
    np.testing.assert_allclose(grid.log_odds, lo, rtol=0, atol=2e-6)
    assert grid.observed.sum() > 100


@pytest.mark.parametrize("seed", range(8))
def test_one_class_is_exactly_the_binary_grid(seed):
    """K = 1 (free, occupied): the same cells and bit-identical float32 log odds."""
    rng = np.random.default_rng(100 + seed)
    poses, ranges, angles = random_scans(rng, 12, 60)
    p0 = [0.5, 0.45, 0.3, 0.6][seed % 4]
    thickness = [0.0, 0.1][seed % 2]
    clear = [None, 1.5, 0.0][seed % 3]
    clamp = [(0.12, 0.97), (0.2, 0.9)][seed % 2]
    res = [0.05, 0.1, 0.23][seed % 3]
    binary = OccupancyGrid(
        res,
        p0=p0,
        clamp=clamp,
        model=InverseSensorModel(p_hit=0.7, p_miss=0.4, thickness=thickness, max_clear_range=clear),
    )
    semantic = SemanticGrid(
        ["free", "occupied"],
        resolution=res,
        prior=[1 - p0, p0],
        clamp=clamp,
        model=LabelledInverseModel(
            p_hit=0.7, p_miss=0.4, thickness=thickness, max_clear_range=clear
        ),
    )
    for part in np.array_split(np.arange(len(poses)), 3):  # growth between batches
        sb = binary.integrate_scans(poses[part], ranges[part], angles, max_range=3.5)
        ss = semantic.integrate_scans(
            poses[part], ranges[part], angles, labels=np.ones((len(part), 60), int), max_range=3.5
        )
        assert sb == ss
    assert semantic.spec == binary.spec
    np.testing.assert_array_equal(semantic.observed, binary.observed)
    assert semantic.log_odds.dtype == np.float32
    np.testing.assert_array_equal(semantic.log_odds[..., 0], binary.log_odds)
    # and the derived occupancy grid is the binary grid again
    occ = semantic.to_occupancy()
    np.testing.assert_array_equal(occ.log_odds, binary.log_odds)
    np.testing.assert_array_equal(occ.probability(), binary.probability())


# --------------------------------------------------------------------------- closed forms


def test_update_is_the_multiclass_log_odds_recursion():
    """l_t[k] = inverse term + prior term + l_{t-1}[k], term by term."""
    prior = np.array([0.5, 0.2, 0.2, 0.1])
    model = LabelledInverseModel(p_hit=0.8, p_miss=0.3, p_correct=0.85, label_floor=0.0)
    grid = SemanticGrid(CLASSES, resolution=0.1, prior=prior, clamp=(1e-9, 1 - 1e-9), model=model)
    for _ in range(3):
        grid.integrate_scan([0.0, 0.0, 0.0], [1.0], [0.0], labels=[2], max_range=5.0)
    l0 = np.log(prior[1:] / prior[0])
    # endpoint: p(free) = 0.2, p(door) = 0.8 * 0.85, others 0.8 * 0.075
    q_hit = np.array([0.8 * 0.075, 0.8 * 0.85, 0.8 * 0.075])
    inv_hit = np.log(q_hit / 0.2)
    inv_free = np.log(np.full(3, 0.1) / 0.7)
    end = grid.spec.world_to_cell([1.05, 0.0])
    mid = grid.spec.world_to_cell([0.55, 0.0])
    np.testing.assert_allclose(grid.log_odds[end[1], end[0]], l0 + 3 * (inv_hit - l0), atol=1e-5)
    np.testing.assert_allclose(grid.log_odds[mid[1], mid[0]], l0 + 3 * (inv_free - l0), atol=1e-5)
    # posterior by Bayes' rule directly: p(k | z1..z3) ~ p(k) * prod_t p(k | z_t) / p(k)
    post = prior * (np.r_[0.2, q_hit] / prior) ** 3
    np.testing.assert_allclose(grid.probabilities()[end[1], end[0]], post / post.sum(), rtol=1e-5)
    assert grid.classes[grid.argmax()[end[1], end[0]]] == "door"
    assert grid.argmax()[mid[1], mid[0]] == 0


def test_unobserved_cells_hold_the_prior():
    prior = [0.6, 0.3, 0.1]
    grid = SemanticGrid(["free", "a", "b"], resolution=0.1, prior=prior)
    grid.integrate_scan([0.0, 0.0, 0.0], [1.0], [0.0], labels=[1], max_range=5.0)
    far = ~grid.observed
    np.testing.assert_allclose(grid.probabilities()[far], np.tile(prior, (far.sum(), 1)), atol=1e-6)
    assert (grid.classify()[far] == -1).all()


def test_once_per_scan_endpoints_pool_and_win():
    spec = GridSpec(0.1, (-2.0, -2.0), (40, 40))
    model = LabelledInverseModel(p_correct=0.9)
    K = 3

    def fresh():
        return SemanticGrid(CLASSES, resolution=0.1, spec=spec, model=model, fixed=True)

    end = spec.world_to_cell([1.05, 0.0])
    mid = spec.world_to_cell([0.55, 0.0])
    # 50 identical beams in one scan: exactly one update, identical to a single beam
    g1, g50 = fresh(), fresh()
    g1.integrate_scan([0, 0, 0], [1.0], [0.0], labels=[1], max_range=5.0)
    g50.integrate_scan(
        [0, 0, 0], np.full(50, 1.0), np.zeros(50), labels=np.ones(50, int), max_range=5
    )
    np.testing.assert_array_equal(g1.log_odds, g50.log_odds)
    # a wall and a door endpoint in one cell: the pooled (averaged) distribution, in any order
    ga, gb = fresh(), fresh()
    ga.integrate_scan([0, 0, 0], [1.0, 1.0], [0.0, 0.0], labels=[1, 2], max_range=5.0)
    gb.integrate_scan([0, 0, 0], [1.0, 1.0], [0.0, 0.0], labels=[2, 1], max_range=5.0)
    np.testing.assert_array_equal(ga.log_odds, gb.log_odds)
    conf = model.hit_probabilities(model.confusion(K))
    want = inverse_term((conf[0] + conf[1]) / 2)  # uniform prior: l_prior = 0
    np.testing.assert_allclose(ga.log_odds[end[1], end[0]], want, atol=1e-6)
    p = ga.probabilities()[end[1], end[0]]
    assert p[1] == pytest.approx(p[2], rel=1e-5) and p[1] > p[3]
    # an endpoint wins over another beam's free space through the same cell
    gc = fresh()
    gc.integrate_scan([0, 0, 0], [1.5, 0.55], [0.0, 0.0], labels=[1, 3], max_range=5.0)
    assert gc.argmax()[mid[1], mid[0]] == 3
    np.testing.assert_allclose(gc.log_odds[mid[1], mid[0]], inverse_term(conf[2]), atol=1e-6)


def test_per_class_clamping():
    clamp = np.array([[0.1, 0.9], [0.2, 0.8], [0.3, 0.95]])
    grid = SemanticGrid(CLASSES, resolution=0.1, clamp=clamp)
    for _ in range(60):
        grid.integrate_scan([0.0, 0.0, 0.0], [1.0], [0.0], labels=[3], max_range=5.0)
    end = grid.spec.world_to_cell([1.05, 0.0])
    mid = grid.spec.world_to_cell([0.55, 0.0])
    np.testing.assert_allclose(
        grid.log_odds[end[1], end[0]], [logit(0.1), logit(0.2), logit(0.95)], atol=1e-6
    )
    np.testing.assert_allclose(grid.log_odds[mid[1], mid[0]], logit(clamp[:, 0]), atol=1e-6)
    assert (grid.log_odds >= grid.l_min.astype(np.float32)).all()
    assert (grid.log_odds <= grid.l_max.astype(np.float32)).all()


def test_growth_keeps_the_map():
    rng = np.random.default_rng(3)
    poses, ranges, angles = random_scans(rng, 10, 50)
    poses[:, :2] *= 4.0
    labels = rng.integers(1, 4, ranges.shape)
    big = SemanticGrid(CLASSES, resolution=0.1, spec=GridSpec(0.1, (-15.0, -15.0), (300, 300)))
    grown = SemanticGrid(CLASSES, resolution=0.1)
    big.integrate_scans(poses, ranges, angles, labels=labels, max_range=3.5)
    for s in range(len(poses)):
        grown.integrate_scans(
            poses[s : s + 1], ranges[s : s + 1], angles, labels=labels[s : s + 1], max_range=3.5
        )
    ox = round((grown.spec.origin[0] + 15.0) / 0.1)
    oy = round((grown.spec.origin[1] + 15.0) / 0.1)
    h, w = grown.spec.shape
    np.testing.assert_array_equal(big.log_odds[oy : oy + h, ox : ox + w], grown.log_odds)
    assert big.observed.sum() == grown.observed.sum()


def test_fixed_grid_refuses_to_grow():
    grid = SemanticGrid(CLASSES, spec=GridSpec(0.1, (0.0, 0.0), (10, 10)), fixed=True)
    with pytest.raises(GridBoundsError, match="outside the fixed grid"):
        grid.integrate_scan([0.5, 0.5, 0.0], [3.0], [0.0], labels=[1], max_range=5.0)


# --------------------------------------------------------------------------- posterior numerics


def test_posterior_functions_against_direct_formulas():
    rng = np.random.default_rng(0)
    l = rng.normal(0, 3, (50, 4))
    full = np.concatenate([np.zeros((50, 1)), l], axis=1)
    direct = np.exp(full) / np.exp(full).sum(axis=1, keepdims=True)
    np.testing.assert_allclose(class_posterior(l), direct, rtol=1e-12)
    np.testing.assert_allclose(class_entropy(l), -(direct * np.log(direct)).sum(axis=1), rtol=1e-10)
    np.testing.assert_array_equal(map_argmax(l), direct.argmax(axis=1))
    np.testing.assert_allclose(
        occupancy_log_odds(l), np.log((1 - direct[:, 0]) / direct[:, 0]), rtol=1e-10
    )


def test_posterior_does_not_overflow():
    l = np.array([[5000.0, -5000.0], [-800.0, -900.0], [800.0, 800.0]])
    p = class_posterior(l)
    assert np.isfinite(p).all()
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    np.testing.assert_allclose(p[0], [0, 1, 0], atol=1e-300)
    np.testing.assert_allclose(p[1], [1, 0, 0], atol=1e-300)
    np.testing.assert_allclose(p[2], [0, 0.5, 0.5], atol=1e-300)
    h = class_entropy(l)
    assert np.isfinite(h).all()
    np.testing.assert_allclose(h, [0.0, 0.0, math.log(2)], atol=1e-12)
    assert math.isfinite(float(occupancy_log_odds(l)[2]))


def test_inverse_term_is_logit_for_one_class():
    for p in (0.1, 0.4, 0.7, 0.97):
        assert float(inverse_term([p])[0]) == logit(p)


# --------------------------------------------------------------------------- bad input


def _grid():
    return SemanticGrid(CLASSES, resolution=0.1)


def test_labels_out_of_range_name_the_scan():
    labels = np.ones((3, 4), int)
    labels[2, 1] = 4
    with pytest.raises(ValueError, match=r"scan 2: label 4 of beam 1 is outside 1\.\.3"):
        _grid().integrate_scans(np.zeros((3, 3)), np.ones((3, 4)), np.zeros(4), labels=labels)
    labels[2, 1] = 0
    with pytest.raises(ValueError, match="scan 2"):
        _grid().integrate_scans(np.zeros((3, 3)), np.ones((3, 4)), np.zeros(4), labels=labels)
    # beams without an endpoint may carry any label
    r = np.ones((3, 4))
    r[2, 1] = np.nan
    _grid().integrate_scans(np.zeros((3, 3)), r, np.zeros(4), labels=labels, max_range=5)


def test_bad_probability_vectors_name_the_scan():
    v = np.full((2, 3, 3), 1 / 3)
    v[1, 2] = [0.5, 0.6, -0.1]
    with pytest.raises(ValueError, match="scan 1: probability vector of beam 2 has negative"):
        _grid().integrate_scans(np.zeros((2, 3)), np.ones((2, 3)), np.zeros(3), probabilities=v)
    v[1, 2] = [0.5, 0.6, 0.1]
    with pytest.raises(ValueError, match="scan 1: probability vector of beam 2 does not sum to 1"):
        _grid().integrate_scans(np.zeros((2, 3)), np.ones((2, 3)), np.zeros(3), probabilities=v)
    v[1, 2] = [0.5, 0.4999, 0.0]  # within the tolerance: accepted and renormalised
    _grid().integrate_scans(np.zeros((2, 3)), np.ones((2, 3)), np.zeros(3), probabilities=v)
    with pytest.raises(ValueError, match=r"probabilities must have shape \(S, B, 3\)"):
        _grid().integrate_scans(
            np.zeros((2, 3)), np.ones((2, 3)), np.zeros(3), probabilities=v[..., :2]
        )


def test_mismatched_lengths_name_the_scan():
    ranges = [np.ones(5), np.ones(5), np.ones(5)]
    labels = [np.ones(5, int), np.ones(4, int), np.ones(5, int)]
    with pytest.raises(ValueError, match="scan 1: labels has 4 entries, ranges has 5 beams"):
        _grid().integrate_scans(np.zeros((3, 3)), ranges, np.zeros(5), labels=labels)
    with pytest.raises(ValueError, match="scan 2: ranges has 3 entries"):
        _grid().integrate_scans(
            np.zeros((3, 3)), [np.ones(5), np.ones(5), np.ones(3)], np.zeros(5), labels=labels
        )
    with pytest.raises(ValueError, match="labels has 2 scans, ranges has 3"):
        _grid().integrate_scans(np.zeros((3, 3)), np.ones((3, 5)), np.zeros(5), labels=labels[:2])
    with pytest.raises(ValueError, match="not both"):
        _grid().integrate_scans(
            np.zeros((1, 3)),
            np.ones((1, 5)),
            np.zeros(5),
            labels=np.ones((1, 5), int),
            probabilities=np.full((1, 5, 3), 1 / 3),
        )
    with pytest.raises(ValueError, match="labels or probabilities are needed"):
        _grid().integrate_scans(np.zeros((1, 3)), np.ones((1, 5)), np.zeros(5))


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"classes": ["free"]}, "at least one more"),
        ({"classes": ["free", "a", "a"]}, "unique"),
        ({"prior": [0.5, 0.5]}, "one probability per class"),
        ({"prior": [0.5, 0.3, 0.3, 0.1]}, "sum to 1"),
        ({"prior": [0.97, 0.01, 0.01, 0.01], "clamp": (0.1, 0.9)}, "inside the clamping"),
        ({"clamp": (0.9, 0.1)}, "p_min <= p_max"),
        ({"colors": [[0, 0, 0]]}, r"shape \(4, 3\)"),
        ({"colors": np.full((4, 3), 300)}, "0..255"),
    ],
)
def test_bad_construction(kwargs, match):
    args = {"classes": CLASSES, **kwargs}
    with pytest.raises(ValueError, match=match):
        SemanticGrid(args.pop("classes"), **args)


def test_bad_model():
    with pytest.raises(ValueError, match="p_correct"):
        LabelledInverseModel(p_correct=0.0)
    with pytest.raises(ValueError, match="p_hit"):
        LabelledInverseModel(p_hit=1.0)


@pytest.mark.parametrize(
    "field,bad,good,rule",
    [
        ("p_hit", 1.0, 0.6, "must lie in (0, 1), got 1.0"),
        ("p_miss", 0.0, 0.3, "must lie in (0, 1), got 0.0"),
        ("thickness", math.inf, 0.1, "must be >= 0 m, got inf"),
        ("thickness", math.nan, 0.0, "must be >= 0 m, got nan"),
        ("max_clear_range", -1.0, None, "must be >= 0 m or None, got -1.0"),
    ],
)
def test_both_inverse_models_share_the_beam_fields_rules(field, bad, good, rule):
    # the fields both inverse models have mean the same: one verdict, each naming its class
    for cls in (InverseSensorModel, LabelledInverseModel):
        with pytest.raises(ValueError) as err:
            cls(**{field: bad})
        assert str(err.value) == f"{cls.__name__}.{field} {rule}"
        assert getattr(cls(**{field: good}), field) == good
