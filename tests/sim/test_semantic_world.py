"""The simulated labelled world and its semantic map: the world's labels, IoU and calibration.

(The scores on small closed-form cases: tests/metrics/test_map.py; the demo that also writes
the map files: tests/pipelines/test_semantic.py.)
"""

from __future__ import annotations

import numpy as np
import pytest

from probmap.grid.semantic import LabelledInverseModel
from probmap.metrics.map import _dilate, reliability, semantic_iou, truth_on_grid
from probmap.sim.semantic import SEMANTIC_CLASSES, map_labelled_world, simulate_labelled_world


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
    right = np.zeros_like(single)
    for k in range(1, len(SEMANTIC_CLASSES)):
        right |= (top == k) & _dilate(truth == k, 1)
    assert single.sum() > 60
    assert abs(right[single].mean() - 0.9) < 0.06
