"""The simulated landmark world (probmap.sim.landmarks): what it observes is what its truth
predicts, and the dataset view (probmap.datasets.simulation) carries the same run."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.datasets.simulation import simulate_landmarks
from probmap.geometry.se2 import wrap_angle
from probmap.sim.landmarks import simulate_landmark_world


@pytest.fixture(scope="module")
def world():
    return simulate_landmark_world(300, 400, seed=0, max_range=8.0, fov=np.pi)


def test_observations_are_the_truth_plus_the_model_noise(world):
    off = world.measurement_model.sensor_offset
    assert np.allclose(off, 0.0)  # the default sensor sits at the robot's origin
    resid = []
    for t, (z, ids) in enumerate(zip(world.z, world.ids, strict=True)):
        pose = world.poses[t + 1]
        d = world.landmarks[ids] - pose[:2]
        expected = np.column_stack(
            [np.hypot(*d.T), wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - pose[2])]
        )
        assert (expected[:, 0] <= 8.0).all() and (np.abs(expected[:, 1]) <= np.pi / 2).all()
        r = z - expected
        r[:, 1] = wrap_angle(r[:, 1])
        resid.append(r)
    res = np.concatenate(resid)
    assert len(res) > 1000
    # the residuals have the model's R: its variances, and no correlation (R is diagonal)
    R = world.measurement_model.R
    assert R[0, 1] == 0.0
    cov = np.cov(res.T)
    np.testing.assert_allclose(np.diag(cov), np.diag(R), rtol=5 / np.sqrt(len(res)))
    assert abs(np.corrcoef(res.T)[0, 1]) < 5 / np.sqrt(len(res))


def test_the_robot_drives_the_commanded_loop(world):
    assert (world.controls == world.controls[0]).all()
    v, w = world.controls[0]
    radius = v / w
    dist = np.hypot(*world.poses[:, :2].T)
    assert np.median(np.abs(dist - radius)) < 0.2 * radius  # noisy controls, same circle


def test_dataset_view_is_the_same_run(world):
    data = simulate_landmarks(300, 400, seed=0, max_range=8.0, fov=np.pi)
    np.testing.assert_array_equal(data.true_poses, world.poses)
    np.testing.assert_array_equal(data.landmarks_xy, world.landmarks)
    for t, step in enumerate(data.steps):
        np.testing.assert_array_equal(step.z, world.z[t])
        np.testing.assert_array_equal(step.ids, world.ids[t])
        np.testing.assert_array_equal(step.gt_pose, world.poses[t + 1])
        assert step.time == pytest.approx((t + 1) * world.dt)
    blind = simulate_landmarks(300, 400, seed=0, max_range=8.0, known_correspondences=False)
    assert all((s.ids == -1).all() for s in blind.steps)
    assert sum(s.z.shape[0] for s in blind.steps) == sum(z.shape[0] for z in world.z)


def test_bad_arguments():
    with pytest.raises(ValueError, match=">= 1"):
        simulate_landmark_world(0, 10, seed=0)
    with pytest.raises(ValueError, match="fov"):
        simulate_landmark_world(10, 10, seed=0, fov=0.0)
