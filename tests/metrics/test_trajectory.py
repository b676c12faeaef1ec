import json

import numpy as np
import pytest
from scipy.stats import chi2

from probmap.geometry.se2 import compose
from probmap.metrics.trajectory import (
    absolute_trajectory_error,
    align_se2,
    apply_se2,
    chi2_bounds,
    interpolate_poses,
    landmark_rmse,
    nees,
    reject_jumps,
    relative_pose_error,
    write_metrics_json,
)


def test_align_recovers_known_transform():
    rng = np.random.default_rng(0)
    p = rng.uniform(-10, 10, (40, 2))
    T = np.array([3.0, -2.0, 0.7])
    q = apply_se2(T, p)
    assert np.allclose(align_se2(p, q), T)
    # with noise the fit is the least-squares one: residual no worse than the true transform
    qn = q + rng.normal(0, 0.1, q.shape)
    Tf = align_se2(p, qn)
    r_fit = np.sum((apply_se2(Tf, p) - qn) ** 2)
    assert r_fit <= np.sum((apply_se2(T, p) - qn) ** 2) + 1e-12
    with pytest.raises(ValueError):
        align_se2(p[:1], q[:1])


def test_ate_closed_form_and_alignment():
    ref = np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)])
    est = ref + [0.0, 0.5, 0.0]
    t, r, _ = absolute_trajectory_error(est, ref)
    assert np.isclose(t.rmse, 0.5) and np.isclose(r.max, 0.0)
    moved = compose([1.0, 2.0, 0.3], ref)
    t, _, T = absolute_trajectory_error(moved, ref, align=True)
    assert t.rmse < 1e-9
    assert np.allclose(apply_se2(T, moved), ref, atol=1e-9)


def test_rpe_invariant_to_frame():
    rng = np.random.default_rng(1)
    ref = np.cumsum(rng.normal(0, 0.1, (50, 3)), axis=0)
    est = ref + rng.normal(0, 0.01, ref.shape)
    t1, r1 = relative_pose_error(est, ref, delta=3)
    t2, r2 = relative_pose_error(compose([5.0, -1.0, 2.0], est), ref, delta=3)
    assert np.allclose(t1.errors, t2.errors) and np.allclose(r1.errors, r2.errors)
    t0, _ = relative_pose_error(ref, ref)
    assert t0.max == 0.0


def test_nees_is_chi2_distributed():
    rng = np.random.default_rng(2)
    A = rng.normal(size=(3, 3))
    P = A @ A.T + np.eye(3)
    e = rng.multivariate_normal(np.zeros(3), P, size=4000)
    v = nees(e, np.broadcast_to(P, (4000, 3, 3)))
    lo, hi = chi2_bounds(3, 4000)
    assert lo < v.mean() < hi
    assert np.isclose(chi2_bounds(3, 50)[0], chi2.ppf(0.025, 150) / 50)
    assert np.allclose(chi2_bounds(3, 50), [2.360, 3.716], atol=1e-3)


def test_landmark_rmse_and_interpolation():
    truth = {1: np.array([0.0, 0.0]), 2: np.array([4.0, 0.0]), 3: np.array([0.0, 3.0])}
    xy = apply_se2([1.0, 1.0, 0.5], np.array([truth[1], truth[2], truth[3]]))
    err, _ = landmark_rmse([1, 2, 3, 99], np.vstack([xy, [[9, 9]]]), truth)
    assert err.errors.size == 3 and err.rmse < 1e-9
    err, _ = landmark_rmse([1, 2, 3], xy, truth, align=False)
    assert err.rmse > 1.0
    tr = np.array([[0.0, 0, 0, 3.0], [1.0, 2, 0, -3.0]])
    p = interpolate_poses(tr, [0.5, 2.0])
    assert np.allclose(p[0, :2], [1, 0]) and np.isclose(abs(p[0, 2]), np.pi, atol=1e-9)
    assert np.all(np.isnan(p[1]))


def test_reject_jumps():
    t = np.arange(10.0)
    gps = np.column_stack([t, t * 2.0, np.zeros(10)])
    gps[4, 2] = 100.0  # a jump
    keep = reject_jumps(gps, max_speed=5.0)
    assert list(np.flatnonzero(~keep)) == [4]


def test_write_metrics_json_round_trip(tmp_path):
    p = write_metrics_json(tmp_path / "metrics.json", {"a": np.float64(1.5), "b": [np.nan]})
    assert json.loads(p.read_text()) == {"a": 1.5, "b": [None]}
    assert list(tmp_path.iterdir()) == [p]


def test_landmark_rmse_nearest_matching():
    rng = np.random.default_rng(5)
    pts = rng.uniform(-20, 20, (30, 2))
    truth = {100 + i: p for i, p in enumerate(pts)}
    est = apply_se2([0.5, -0.3, 0.05], pts[:20] + rng.normal(0, 0.05, (20, 2)))
    err, T = landmark_rmse(np.arange(20), est, truth, match="nearest")
    assert err.errors.size == 20 and err.rmse < 0.15
    raw, _ = landmark_rmse(np.arange(20), est, truth, align=False, match="nearest")
    assert raw.rmse > err.rmse
    with pytest.raises(ValueError):
        landmark_rmse([0], [[0, 0]], truth, match="bogus")
