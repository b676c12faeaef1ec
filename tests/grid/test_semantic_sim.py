"""Semantic mapping of the simulated labelled world: IoU, calibration, and the scoring functions.

(The demo that also writes the map files: tests/pipelines/test_semantic.py.)
"""

from __future__ import annotations

import numpy as np
import pytest

from probmap.grid.semantic import LabelledInverseModel
from probmap.grid.semantic_sim import (
    SEMANTIC_CLASSES,
    map_labelled_world,
    reliability,
    semantic_iou,
    simulate_labelled_world,
    truth_on_grid,
)


@pytest.fixture(scope="module")
def world():
    return simulate_labelled_world(seed=0, label_noise=0.1, dropout=0.01, soft=True)


@pytest.fixture(scope="module")
def mapped(world):
    grid = map_labelled_world(world, model=LabelledInverseModel(p_correct=0.9))
    return grid, truth_on_grid(grid.spec, world.truth, world.spec)


def test_world_is_consistent(world):
    # the route never enters an object
    cells = world.spec.world_to_cell(world.poses[:, :2])
    assert (world.truth[cells[:, 1], cells[:, 0]] == 0).all()
    # every class is present, every hit is labelled with an object class
    assert set(np.unique(world.truth)) == set(range(len(SEMANTIC_CLASSES)))
    hit = world.true_labels > 0
    assert hit.mean() > 0.9
    valid = np.isfinite(world.ranges)
    assert ((world.true_labels[valid] == 0) == (world.ranges[valid] >= world.max_range)).all()
    # 10 % wrong labels, always another object class
    wrong = world.labels[hit] != world.true_labels[hit]
    assert abs(wrong.mean() - 0.1) < 0.005
    assert (world.labels[hit] >= 1).all()
    # the hit label is the class of the true cell a little beyond the hit point
    s, b = np.nonzero(hit & valid)
    pick = np.random.default_rng(0).choice(len(s), 500, replace=False)
    for i in pick:
        x, y, th = world.poses[s[i]]
        a = th + world.angles[b[i]]
        r = world.ranges[s[i], b[i]] + 0.03  # past range noise, inside the 0.05 m+ objects
        ix, iy = world.spec.world_to_cell([x + r * np.cos(a), y + r * np.sin(a)])
        near = world.truth[max(iy - 1, 0) : iy + 2, max(ix - 1, 0) : ix + 2]
        assert world.true_labels[s[i], b[i]] in near
    # soft vectors are distributions whose top class is the reported label
    p = world.probabilities[hit]
    np.testing.assert_allclose(p.sum(axis=-1), 1.0)
    assert (p.argmax(axis=-1) + 1 == world.labels[hit]).all()


def test_iou_with_ten_percent_wrong_labels(mapped):
    grid, truth = mapped
    iou = semantic_iou(grid.classify(), truth, len(SEMANTIC_CLASSES), tolerance=1)
    assert (iou >= 0.95).all(), dict(zip(SEMANTIC_CLASSES, iou.round(4), strict=True))
    # strict (cell-exact) IoU: walls' faces fall on either side of the boundary
    strict = semantic_iou(grid.classify(), truth, len(SEMANTIC_CLASSES), tolerance=0)
    assert strict[0] > 0.97 and (strict[1:] > 0.6).all()


def test_iou_with_probability_vectors(world):
    grid = map_labelled_world(world, soft=True)
    truth = truth_on_grid(grid.spec, world.truth, world.spec)
    iou = semantic_iou(grid.classify(), truth, len(SEMANTIC_CLASSES))
    assert (iou >= 0.93).all(), iou


def test_calibration(mapped):
    """Cells predicted at about 0.9 are right about 90 % of the time."""
    grid, truth = mapped
    rel = reliability(
        grid.probabilities(),
        grid.observed,
        truth,
        edges=np.array([0, 0.85, 0.95, 1.0]),
        tolerance=0,
    )
    assert rel.count[1] > 1000
    assert abs(rel.accuracy[1] - rel.confidence[1]) < 0.05, (rel.confidence, rel.accuracy)
    # the object class given "occupied" follows the confusion model exactly: a cell whose label
    # evidence is one observation has confidence p_correct = 0.9 and must be right ~90 %
    P = grid.probabilities()
    occ = grid.observed & (grid.argmax() > 0)
    pc = P[..., 1:] / P[..., 1:].sum(axis=-1, keepdims=True)
    conf = pc.max(axis=-1)
    single = occ & (np.abs(conf - 0.9) < 0.02)
    top = pc.argmax(axis=-1) + 1
    from probmap.grid.semantic_sim import _dilate

    right = np.zeros_like(single)
    for k in range(1, len(SEMANTIC_CLASSES)):
        right |= (top == k) & _dilate(truth == k, 1)
    assert single.sum() > 60
    assert abs(right[single].mean() - 0.9) < 0.06


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
