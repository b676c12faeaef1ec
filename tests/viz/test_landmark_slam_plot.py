"""Landmark-SLAM plots draw the estimate after the metrics' SE(2) alignment, and say so."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from probmap.viz.landmark_slam import alignment_from_metrics, plot_slam


def test_estimate_is_drawn_in_the_reference_frame():
    from matplotlib.figure import Figure

    rng = np.random.default_rng(0)
    truth = np.column_stack([np.linspace(0, 10, 50), np.sin(np.linspace(0, 3, 50)), np.zeros(50)])
    T = np.array([3.0, -2.0, 0.7])  # estimate frame -> reference frame
    c, s = math.cos(T[2]), math.sin(T[2])
    R = np.array([[c, -s], [s, c]])
    est_xy = (truth[:, :2] - T[:2]) @ R  # the truth seen from the estimate's frame
    est = np.column_stack([np.arange(50.0), est_xy, truth[:, 2] - T[2]])
    lm_true = rng.uniform(0, 10, (4, 2))
    cov = np.diag([0.04, 0.01])
    result = SimpleNamespace(
        trajectory=est, landmark_xy=(lm_true - T[:2]) @ R, landmark_cov=np.repeat(cov[None], 4, 0)
    )
    metrics = {"ate_aligned": {"alignment": T.tolist()}, "gps": {"alignment": [0, 0, 0]}}
    A, name = alignment_from_metrics(metrics)
    assert name == "ground truth" and np.allclose(A, T)
    ax = Figure().add_subplot()
    plot_slam(ax, result, alignment=A, aligned_to=name)
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    drawn = lines["estimate (SE(2)-aligned to ground truth)"].get_xydata()
    np.testing.assert_allclose(drawn, truth[:, :2], atol=1e-12)
    np.testing.assert_allclose(lines["landmarks (2-sigma)"].get_xydata(), lm_true, atol=1e-12)
    # the ellipses are rotated with the landmarks: the first one's long axis is along R [1, 0]
    ellipse = ax.get_lines()[1].get_xydata() - lm_true[0]
    far = ellipse[np.argmax(np.linalg.norm(ellipse, axis=1))]
    assert abs(abs(far @ (R @ [1.0, 0.0])) / np.linalg.norm(far) - 1.0) < 1e-3
    assert alignment_from_metrics({}) == (None, "")
    assert alignment_from_metrics({"gps": {"alignment": [1, 2, 3]}})[1] == "GPS"
    raw = Figure().add_subplot()
    plot_slam(raw, result)
    assert "estimate" in [ln.get_label() for ln in raw.get_lines()]


def test_the_picture_names_the_dataset_robot_and_figures(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    from probmap.viz.landmark_slam import metrics_caption, save_slam_figure

    drawn = []
    real = Figure.savefig
    monkeypatch.setattr(
        Figure, "savefig", lambda self, *a, **k: (drawn.append(self), real(self, *a, **k))[1]
    )
    est = np.column_stack([np.arange(5.0), np.arange(5.0), np.zeros(5), np.zeros(5)])
    result = SimpleNamespace(
        trajectory=est, landmark_xy=np.zeros((1, 2)), landmark_cov=np.eye(2)[None] * 0.01
    )
    metrics = {
        "dataset": "mrclam-MRCLAM_Dataset7-robot3", "steps": 5, "landmarks_mapped": 1,
        "ate": {"translation_m": {"rmse": 1.5}}, "landmarks": {"error_m": {"rmse": 0.25}},
    }  # fmt: skip
    save_slam_figure(tmp_path / "slam.png", result, title="EKF SLAM", metrics=metrics)
    (ax,) = drawn[0].axes
    assert ax.get_title(loc="left") == "EKF SLAM on mrclam-MRCLAM_Dataset7-robot3"
    assert "5 steps, 1 landmarks; ATE 1.500 m, landmarks 0.250 m" in [
        t.get_text() for t in ax.texts
    ]
    # Victoria Park: no truth, GPS
    gps = {"gps": {"rmse_m": 4.123}, "dead_reckoning_gps": {"rmse_m": 40.0}, "steps": 7}
    assert metrics_caption(gps) == "7 steps; GPS RMSE 4.12 m; dead reckoning 40.00 m"
    assert metrics_caption(None) == ""
