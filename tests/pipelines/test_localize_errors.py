"""A reference is compared at its own times, the run interpolated between its updates
(closed forms)."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.pipelines.localize import LocalizationRun, interpolate_run, trajectory_errors


def _run(times, poses, offset=(0.0, 0.0, 0.0)):
    t = np.asarray(times, dtype=float)
    return LocalizationRun(
        t, np.asarray(poses, dtype=float), np.zeros(t.size), np.arange(t.size),
        laser_offset=np.asarray(offset, dtype=float),
    )  # fmt: skip


def test_errors_at_reference_times_between_updates():
    run = _run([0.0, 2.0], [[0.0, 0.0, 0.0], [2.0, 0.0, 0.4]])
    # the run at t = 1 is (1, 0, 0.2); the reference there is 0.3 m off sideways, 0.1 rad
    err, head = trajectory_errors(run, [1.0, 5.0], [[1.0, 0.3, 0.3], [9.0, 9.0, 0.0]])
    assert err.shape == (1,)  # t = 5 lies outside the run: not compared
    assert err[0] == pytest.approx(0.3) and head[0] == pytest.approx(0.1)


def test_laser_poses_and_jittered_times():
    # update times that go back (a log's clock jitter) are taken in time order
    run = _run([0.0, 2.0, 1.0], [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.0, 0.0]], (0.5, 0, 0))
    p = interpolate_run(run, [0.5, 1.5], laser=True)
    np.testing.assert_allclose(p, [[1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    one = _run([3.0], [[1.0, 2.0, 0.0]])
    q = interpolate_run(one, [3.0, 4.0])
    np.testing.assert_allclose(q[0], [1.0, 2.0, 0.0])
    assert np.all(np.isnan(q[1]))
    with pytest.raises(ValueError, match="reference"):
        trajectory_errors(run, [], np.zeros((0, 3)))
