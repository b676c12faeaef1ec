"""Local SLAM's settings and the lidar-only prior (probmap.slam.laser.local_matching)."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.slam.laser.local_matching import LocalMatchingConfig, prior_step


def test_the_prior_holds_the_direction_the_scan_cannot_see():
    """A corridor along x: the scan pins y and the heading (large J^T J) and says nothing
    along x. One step of the prior keeps the match's y and heading and takes the prediction's
    x; with the weights off it returns the match."""
    h = np.diag([0.0, 1e6, 1e6])
    match = np.array([1.0, 2.0, 0.10])
    predicted = np.array([1.4, 2.3, 0.30])
    got = prior_step(h, 100, (0.5, 1.0), match, predicted)
    np.testing.assert_allclose(got[0], 1.4, atol=1e-9)
    np.testing.assert_allclose(
        got[1:], [2.0 + 0.3 * 25 / (1e6 + 25), 0.10 + 0.2 * 100 / (1e6 + 100)]
    )
    np.testing.assert_array_equal(prior_step(h, 100, (0.0, 0.0), match, predicted), match)


def test_the_prior_step_is_the_minimum_of_the_quadratic():
    """For a full-rank J^T J the step minimizes ``(p - m)' H (p - m) + (p - q)' W (p - q)``:
    its gradient vanishes there; the heading difference is taken the short way round."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 3))
    h = a @ a.T + np.eye(3)
    m = np.array([0.2, -0.1, 3.1])
    q = np.array([0.3, 0.0, -3.1])  # 0.083 rad from m, across +-pi
    p = prior_step(h, 40, (0.5, 1.0), m, q)
    w = 40 * np.diag([0.25, 0.25, 1.0])
    dq = q - p
    dq[2] = np.arctan2(np.sin(dq[2]), np.cos(dq[2]))
    np.testing.assert_allclose(h @ (p - m) - w @ dq, 0.0, atol=1e-9)
    assert abs(p[2] - m[2]) < 0.1  # pulled towards q across pi, not the long way


def test_config_checks_the_prior():
    assert LocalMatchingConfig().lidar_only_prior == (0.5, 1.0)
    with pytest.raises(ValueError, match="lidar_only_prior must be"):
        LocalMatchingConfig(lidar_only_prior=(-1.0, 1.0))
