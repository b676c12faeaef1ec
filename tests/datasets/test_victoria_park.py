import warnings

import numpy as np
import pytest

from probmap.datasets.protocol import Dataset, DatasetError
from probmap.datasets.victoria_park import MAT_CLOCK_OFFSET_S, VictoriaPark
from probmap.pipelines.landmark_slam import default_ekf_config, evaluate, run_landmark_slam
from probmap.slam.landmark.ekf import EKFSLAM


def write_vp(d, inputs=None, meas=None, gps=None):
    d.mkdir(exist_ok=True)
    inputs = inputs or ["0.0 1.0 0.0", "0.1 2.0 0.1", "0.2 2.0 0.1", "0.3 0.0 0.0"]
    meas = meas or ["0.15 10.0 1.5707963 0.4", "0.15 12.0 0.0 0.2", "0.2 5.0 3.0 0.0"]
    gps = gps or ["0.0 0.0 0.0", "0.2 0.3 0.0"]
    (d / "inputs.dat").write_text("\n".join(inputs) + "\n")
    (d / "measurements.dat").write_text("\n".join(meas) + "\n")
    (d / "gps.dat").write_text("\n".join(gps) + "\n")
    return d


def test_event_merging_and_conversions(tmp_path):
    vp = VictoriaPark(write_vp(tmp_path / "vp"), range_to_centre=True)
    assert isinstance(vp, Dataset)
    steps = list(vp)
    assert [s.time for s in steps] == [0.0, 0.1, 0.15, 0.2, 0.3]
    assert np.allclose([s.dt for s in steps], [0, 0.1, 0.05, 0.05, 0.1])
    # zero-order hold: the control in force at the start of each interval
    assert np.allclose([s.control[0] for s in steps], [1.0, 1.0, 2.0, 2.0, 2.0])
    s = steps[2]
    assert s.z.shape == (2, 2) and np.all(s.ids == -1)
    assert np.allclose(s.z[0], [10.2, 0.0], atol=1e-6)  # straight ahead, range to trunk centre
    assert np.allclose(s.z[1], [12.1, -np.pi / 2])  # bearing 0 = the vehicle's right
    assert np.allclose(steps[3].z, [[5.0, 3.0 - np.pi / 2]])
    assert vp.gps.shape == (2, 3)


@pytest.mark.parametrize(
    ("which", "lines", "match"),
    [
        ("inputs", ["0.0 1.0"], "expected 3 columns"),
        ("inputs", ["0.0 1.0 x"], "field 'steering'"),
        ("inputs", ["0.0 1.0 0.0", "-1.0 1.0 0.0"], "backwards"),
        ("meas", ["0.1 abc 1.0 0.1"], "field 'range'"),
    ],
)
def test_bad_input_names_file_and_line(tmp_path, which, lines, match):
    kw = {"inputs": lines} if which == "inputs" else {"meas": lines}
    d = write_vp(tmp_path / "vp", **kw)
    with pytest.raises(DatasetError, match=match) as exc:
        VictoriaPark(d)
    assert ".dat" in str(exc.value) and "line" in str(exc.value)


def test_nan_rows_are_counted_and_warned(tmp_path):
    d = write_vp(tmp_path / "vp", meas=["0.15 nan 1.0 0.2", "0.15 12.0 1.0 0.2"])
    with pytest.warns(UserWarning, match="skipped 1 measurement"):
        vp = VictoriaPark(d)
    assert sum(len(s.z) for s in vp) == 1


def test_mat_source_matches_dat(tmp_path):
    from scipy.io import savemat

    d = write_vp(tmp_path / "vp")
    t_ms = np.round((np.array([0.0, 0.1, 0.2, 0.3]) + MAT_CLOCK_OFFSET_S) * 1000)
    savemat(
        d / "aa3_dr.mat",
        {"time": t_ms.astype(np.int32), "speed": [1.0, 2, 2, 0], "steering": [0.0, 0.1, 0.1, 0]},
    )
    g_ms = np.round((np.array([0.0, 0.2]) + MAT_CLOCK_OFFSET_S) * 1000).astype(np.int32)
    savemat(d / "aa3_gpsx.mat", {"timeGps": g_ms, "Lo_m": [0.0, 0.3], "La_m": [0.0, 0.0]})
    a, b = list(VictoriaPark(d)), list(VictoriaPark(d, source="mat"))
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert np.isclose(x.time, y.time) and np.allclose(x.control, y.control)
        assert np.allclose(x.z, y.z)


@pytest.mark.realdata
def test_real_victoria_park_prefix_beats_dead_reckoning(shared_data):
    root = shared_data("victoria-park")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the real files are clean
        vp = VictoriaPark(root, end_time=150.0)
    assert vp.detections == 52974
    ekf = EKFSLAM(
        vp.motion_model,
        vp.measurement_model,
        vp.initial_pose,
        vp.initial_covariance,
        default_ekf_config(vp),
    )
    m = evaluate(run_landmark_slam(ekf, vp), vp)
    assert m["landmarks_mapped"] > 40
    assert m["gps"]["rmse_m"] < 5.0
    assert m["gps"]["rmse_m"] < m["dead_reckoning_gps"]["rmse_m"]
