"""The landmark-SLAM pipeline (probmap.pipelines.landmark_slam): run and evaluate an EKF."""

import numpy as np

from probmap.datasets.simulation import simulate_landmarks
from probmap.pipelines.landmark_slam import dead_reckoning, evaluate, run_landmark_slam
from probmap.slam.landmark.ekf import EKFSLAM


def test_pipeline_runs_and_evaluates_simulation():
    sim = simulate_landmarks(60, 600, seed=11, density=0.05)
    ekf = EKFSLAM(sim.motion_model, sim.measurement_model, sim.initial_pose, sim.initial_covariance)
    calls = []
    res = run_landmark_slam(ekf, sim, progress=lambda i, n: calls.append((i, n)))
    assert res.trajectory.shape == (600, 4) and calls[-1] == (600, 600)
    m = evaluate(res, sim)
    # SLAM beats dead reckoning, and the map is accurate
    assert (
        m["ate"]["translation_m"]["rmse"] < 0.5 * m["dead_reckoning_ate"]["translation_m"]["rmse"]
    )
    assert m["landmarks"]["error_m"]["rmse"] < 0.3
    assert 0.5 < m["nis"]["mean_per_dof"] < 1.5
    dr = dead_reckoning(sim)
    assert np.allclose(dr[:, 0], res.trajectory[:, 0])


def test_unknown_correspondences_evaluated_by_nearest_landmark():
    sim = simulate_landmarks(40, 400, seed=12, density=0.05, known_correspondences=False)
    ekf = EKFSLAM(sim.motion_model, sim.measurement_model, sim.initial_pose, sim.initial_covariance)
    res = run_landmark_slam(ekf, sim)
    assert not res.known_correspondences
    m = evaluate(res, sim)
    assert m["landmarks"]["matched_by"] == "nearest"
    assert m["landmarks"]["error_m"]["rmse"] < 0.3
