"""Nearest-time lookup and pose interpolation (probmap.geometry.timesync)."""

from __future__ import annotations

import numpy as np

from probmap.geometry import timesync
from probmap.geometry.timesync import interpolate_poses, nearest_time_index
from probmap.metrics import trajectory


def test_old_import_path():
    assert trajectory.interpolate_poses is timesync.interpolate_poses


def test_interpolate_across_the_angle_wrap():
    tr = np.array([[0.0, 0, 0, 3.0], [1.0, 2, 0, -3.0]])
    p = interpolate_poses(tr, [0.0, 0.5, 1.0])
    assert np.allclose(p[:, :2], [[0, 0], [1, 0], [2, 0]])
    # shortest arc: 3 -> -3 rad passes through pi, not through 0
    assert np.isclose(abs(p[1, 2]), np.pi, atol=1e-9)
    assert np.isclose(p[0, 2], 3.0) and np.isclose(p[2, 2], -3.0)


def test_nearest_time_index_against_brute_force():
    rng = np.random.default_rng(4)
    times = rng.uniform(0, 10, 40)  # unsorted
    t = rng.uniform(-1, 11, 200)
    tol = 0.1
    got = nearest_time_index(times, t, tol)
    for q, g in zip(t, got, strict=True):
        gap = np.abs(times - q)
        if gap.min() > tol:
            assert g == -1
        else:
            assert gap[g] == gap.min()


def test_nearest_time_index_ties_take_the_earlier_time():
    assert list(nearest_time_index(np.array([2.0, 1.0]), np.array([1.5]), 1.0)) == [1]
    assert list(nearest_time_index(np.array([5.0]), np.array([5.2, 7.0]), 0.5)) == [0, -1]
