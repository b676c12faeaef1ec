"""Ray casting and scan bounds kernels against pure-Python references."""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.grid import _kernels
from probmap.grid.raycast import cast_rays
from probmap.grid.spec import GridSpec


def reference_range(occ, spec, pose, angle, max_range):
    """Clip the beam segment against every cell (Liang-Barsky); the nearest occupied entry wins."""
    x, y, th = pose
    res = spec.resolution
    ox, oy = spec.origin
    gx0, gy0 = (x - ox) / res, (y - oy) / res
    gx1 = gx0 + max_range / res * math.cos(th + angle)
    gy1 = gy0 + max_range / res * math.sin(th + angle)
    best = max_range
    h, w = occ.shape
    for iy, ix in zip(*np.nonzero(occ), strict=True):
        t0, t1, ok = 0.0, 1.0, True
        for p, q in (
            (-(gx1 - gx0), gx0 - ix),
            (gx1 - gx0, ix + 1 - gx0),
            (-(gy1 - gy0), gy0 - iy),
            (gy1 - gy0, iy + 1 - gy0),
        ):
            if p == 0:
                ok = ok and q >= 0
                continue
            r = q / p
            t0, t1 = (max(t0, r), t1) if p < 0 else (t0, min(t1, r))
        if ok and t0 <= t1:
            best = min(best, t0 * max_range)
    # the kernel stops where the beam leaves the grid; so does the reference
    return best


@pytest.mark.parametrize("seed", range(4))
def test_cast_rays_matches_reference(seed):
    rng = np.random.default_rng(seed)
    spec = GridSpec(0.25, (-3.0, -2.0), (24, 28))
    occ = rng.random(spec.shape) < 0.06
    poses = np.column_stack(
        [rng.uniform(-2.5, 3.5, 6), rng.uniform(-1.5, 3.5, 6), rng.uniform(-np.pi, np.pi, 6)]
    )
    angles = rng.uniform(-np.pi, np.pi, 25)
    got = cast_rays(occ, spec, poses, angles, 4.0)
    for p in range(len(poses)):
        for b in range(len(angles)):
            want = reference_range(occ, spec, poses[p], angles[b], 4.0)
            assert got[p, b] == pytest.approx(want, abs=1e-9), (p, b)


def test_cast_rays_validates():
    spec = GridSpec(1.0, (0.0, 0.0), (3, 3))
    with pytest.raises(ValueError, match="shape"):
        cast_rays(np.zeros((2, 2), bool), spec, [0, 0, 0], [0.0], 5.0)
    with pytest.raises(ValueError, match="finite"):
        cast_rays(np.zeros((3, 3), bool), spec, [np.nan, 0, 0], [0.0], 5.0)


def test_scan_bounds_matches_numpy():
    rng = np.random.default_rng(3)
    poses = rng.uniform(-5, 5, (7, 3))
    ranges = rng.uniform(0.1, 6.0, (7, 30))
    ranges[0, 0] = np.nan
    ranges[1, 1] = 9.0  # max-range: counted at the clear range
    angles = rng.uniform(-np.pi, np.pi, 30)
    out = np.empty(4)
    _kernels.scan_bounds(poses, ranges, angles[None, :], True, 8.0, 2.0, 0.3, out)
    r = np.where(ranges >= 8.0, 2.0, ranges + 0.3)
    a = poses[:, 2:3] + angles[None, :]
    ok = np.isfinite(ranges)
    xs = np.concatenate([(poses[:, 0:1] + r * np.cos(a))[ok], poses[:, 0]])
    ys = np.concatenate([(poses[:, 1:2] + r * np.sin(a))[ok], poses[:, 1]])
    np.testing.assert_allclose(out, [xs.min(), xs.max(), ys.min(), ys.max()], rtol=1e-12)
