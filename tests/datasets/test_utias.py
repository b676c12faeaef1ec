import warnings

import numpy as np
import pytest

from probmap.datasets.protocol import DatasetError
from probmap.datasets.utias import MRCLAM
from probmap.pipelines.landmark_slam import default_ekf_config, evaluate, run_landmark_slam
from probmap.slam.landmark.ekf import EKFSLAM

HEAD = "# h\n# h\n# h\n# h\n"


def write_mrclam(d, meas=None, odo=None):
    d.mkdir(exist_ok=True)
    (d / "Barcodes.dat").write_text(HEAD + "1 5\n2 14\n3 41\n4 32\n5 23\n6 63\n7 81\n")
    (d / "Landmark_Groundtruth.dat").write_text(HEAD + "6 1.0 2.0 0.0 0.0\n7 3.0 -1.0 0 0\n")
    odo = odo or ["10.0 0.5 0.0", "10.5 0.5 0.1", "11.0 0.0 0.0"]
    (d / "Robot1_Odometry.dat").write_text(HEAD + "\n".join(odo) + "\n")
    meas = meas or ["10.2 63 2.0 0.1", "10.2 14 1.5 0.0", "10.7 81 3.0 -0.2", "10.7 99 1.0 0.0"]
    (d / "Robot1_Measurement.dat").write_text(HEAD + "\n".join(meas) + "\n")
    (d / "Robot1_Groundtruth.dat").write_text(HEAD + "9.9 0 0 0\n11.1 0.55 0 0.05\n")
    return d


def test_barcodes_robots_and_unknown(tmp_path):
    d = write_mrclam(tmp_path / "M")
    with pytest.warns(UserWarning, match="skipped 1 measurements of barcodes"):
        ds = MRCLAM(d, 1)
    assert ds.unknown_barcodes == 1
    # the robot-to-robot observation (barcode 14 = robot 2) is kept apart
    assert ds.robot_observations.tolist() == [[10.2, 2.0, 1.5, 0.0]]
    steps = list(ds)
    assert [s.time for s in steps] == [10.0, 10.2, 10.5, 10.7, 11.0]
    assert np.allclose([s.control[0] for s in steps], [0.5, 0.5, 0.5, 0.5, 0.5])  # dt = 0 first
    assert np.allclose([s.control[1] for s in steps], [0.0, 0.0, 0.0, 0.1, 0.1])
    obs = [(s.time, s.ids.tolist(), s.z.tolist()) for s in steps if len(s.ids)]
    assert obs == [(10.2, [6], [[2.0, 0.1]]), (10.7, [7], [[3.0, -0.2]])]
    assert set(ds.landmark_truth) == {6, 7}
    assert np.allclose(ds.initial_pose, [0.0458333, 0, 0.0041667], atol=1e-6)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert all(np.all(s.ids == -1) for s in MRCLAM(d, 1, known=False))


def test_bad_input(tmp_path):
    d = write_mrclam(tmp_path / "M", odo=["10.0 0.5 0.0", "9.0 0.5 0.1"])
    with pytest.raises(DatasetError, match=r"Robot1_Odometry.dat, line 6.*backwards"):
        MRCLAM(d, 1)
    d = write_mrclam(tmp_path / "N", meas=["10.2 63 two 0.1"])
    with pytest.raises(DatasetError, match="field 'range'"):
        MRCLAM(d, 1)
    with pytest.raises(ValueError, match="robot"):
        MRCLAM(d, 7)
    with pytest.raises(DatasetError, match="not a directory"):
        MRCLAM(tmp_path / "missing", 1)


@pytest.mark.realdata
@pytest.mark.parametrize("robot", [1, 2, 3])
def test_real_mrclam7_known_correspondences(shared_data, robot):
    root = shared_data("utias-mrclam/MRCLAM_Dataset7")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # robot 3 has 9 unknown barcodes
        ds = MRCLAM(root, robot)
    ekf = EKFSLAM(
        ds.motion_model,
        ds.measurement_model,
        ds.initial_pose,
        ds.initial_covariance,
        default_ekf_config(ds),
    )
    m = evaluate(run_landmark_slam(ekf, ds), ds)
    # SE(2)-aligned figures (the map's frame drifts while no landmark is in view; see README)
    assert m["ate_aligned"]["translation_m"]["rmse"] <= 0.30
    assert m["landmarks_aligned"]["error_m"]["rmse"] <= 0.30
    assert m["landmarks_mapped"] == 15
    # far better than dead reckoning
    dr = m["dead_reckoning_ate"]["translation_m"]["rmse"]
    assert m["ate"]["translation_m"]["rmse"] < 0.6 * dr
