import numpy as np
import pytest

from probmap.datasets.landmarks import LandmarkStep
from probmap.datasets.protocol import Dataset
from probmap.datasets.simulation import simulate_landmarks
from probmap.geometry.se2 import wrap_angle


def test_seeded_and_consistent_with_truth():
    a = simulate_landmarks(200, 300, seed=4)
    b = simulate_landmarks(200, 300, seed=4)
    assert isinstance(a, Dataset) and len(a) == 300
    assert all(np.array_equal(x.z, y.z) for x, y in zip(a, b, strict=True))
    sensor = a.measurement_model
    res = []
    for step in a:
        assert isinstance(step, LandmarkStep)
        if len(step.ids):
            z, _, _ = sensor.predict_many(step.gt_pose, a.landmarks_xy[step.ids])
            d = step.z - z
            d[:, 1] = wrap_angle(d[:, 1])
            res.append(d)
            assert np.all(z[:, 0] <= 10.0) and np.all(np.abs(z[:, 1]) <= np.pi / 2)
    res = np.concatenate(res)
    # normalised residuals follow N(0, R): chi-square mean 2 within a loose 5-sigma band
    nis = np.einsum("ij,jk,ik->i", res, np.linalg.inv(sensor.R), res)
    assert abs(nis.mean() - 2.0) < 5 * 2.0 / np.sqrt(len(nis))


def test_visibility_matches_brute_force():
    sim = simulate_landmarks(500, 50, seed=1, max_range=8.0, fov=np.deg2rad(120))
    for step in sim:
        d = sim.landmarks_xy - step.gt_pose[:2]
        r = np.hypot(d[:, 0], d[:, 1])
        b = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - step.gt_pose[2])
        expect = np.flatnonzero((r <= 8.0) & (np.abs(b) <= np.deg2rad(60)))
        assert np.array_equal(np.sort(step.ids), expect)


def test_unknown_correspondences_and_large_world():
    sim = simulate_landmarks(100_000, 20, seed=2, known_correspondences=False)
    assert all(np.all(s.ids == -1) for s in sim)
    assert sum(len(s.z) for s in sim) > 0


def test_bad_arguments():
    with pytest.raises(ValueError):
        simulate_landmarks(0, 10, seed=0)
    with pytest.raises(ValueError):
        simulate_landmarks(10, 10, seed=0, fov=0.0)
