"""Map metrics on small cases worked out by hand: accuracy, IoU with and without tolerance,
the reliability diagram and its calibration error, the truth resampled onto another grid."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.grid.spec import GridSpec
from probmap.metrics.map import map_accuracy, reliability, semantic_iou, truth_on_grid


def test_map_accuracy_closed_form():
    spec = GridSpec(1.0, (0.0, 0.0), (4, 4))
    truth = np.zeros((4, 4), bool)
    truth[1, 1] = True
    classified = np.full((4, 4), -1, np.int8)  # unknown cells are not counted
    classified[1, 2] = 1  # occupied next to the true wall: right (one cell of tolerance)
    classified[3, 3] = 1  # occupied far from it: wrong
    classified[1, 1] = 0  # free on the wall: wrong
    classified[0, 0] = 0  # free on free: right
    acc, n = map_accuracy(classified, spec, truth, spec)
    assert (acc, n) == (0.5, 4)
    assert np.isnan(map_accuracy(np.full((4, 4), -1, np.int8), spec, truth, spec)[0])


def test_truth_on_a_finer_grid():
    truth = np.array([[0, 1], [2, 0]], np.int8)
    coarse = GridSpec(1.0, (0.0, 0.0), (2, 2))
    fine = GridSpec(0.5, (0.0, 0.0), (4, 5))  # one column beyond the truth: class 0
    on = truth_on_grid(fine, truth, coarse)
    expected = np.zeros((4, 5), np.int16)
    expected[:, :4] = np.kron(truth, np.ones((2, 2), np.int16))  # each true cell: 2 x 2 cells
    np.testing.assert_array_equal(on, expected)


def test_semantic_iou_closed_form():
    truth = np.zeros((6, 6), int)
    truth[2, 1:5] = 1
    pred = np.zeros((6, 6), int)
    pred[2, 1:4] = 1
    pred[2, 4] = 2  # one wrong cell
    pred[5, 5] = 1  # one false wall far away
    pred[0, 0] = -1  # unobserved: ignored
    iou = semantic_iou(pred, truth, 3, tolerance=0)
    # class 1: TP 3, FP 1 (5,5), FN 1 (2,4) -> 3/5 ; class 2: TP 0 FP 1 -> 0
    assert iou[1] == pytest.approx(3 / 5)
    assert iou[2] == 0.0
    # class 0: TP = 36 cells - 1 unobserved - 4 predicted 1 - 1 predicted 2 = 30, FN (5,5) -> 30/31
    assert iou[0] == pytest.approx(30 / 31)
    tol = semantic_iou(pred, truth, 3, tolerance=1)
    # with one cell of tolerance (2,4) is covered by predicted walls next to it; (5,5) is not
    assert tol[1] == pytest.approx(3 / 4)
    empty = semantic_iou(np.zeros((2, 2), int), np.zeros((2, 2), int), 2)
    assert empty[0] == 1.0 and np.isnan(empty[1])


def test_reliability_closed_form():
    p = np.zeros((1, 4, 2))
    p[0, :, 0] = [0.9, 0.9, 0.6, 0.6]
    p[0, :, 1] = 1 - p[0, :, 0]
    truth = np.array([[0, 1, 0, 0]])
    rel = reliability(p, np.ones((1, 4), bool), truth, edges=np.array([0.5, 0.8, 1.0]), tolerance=0)
    np.testing.assert_allclose(rel.confidence, [0.6, 0.9])
    np.testing.assert_allclose(rel.accuracy, [1.0, 0.5])
    assert rel.expected_calibration_error == pytest.approx(0.5 * 0.4 + 0.5 * 0.4)
