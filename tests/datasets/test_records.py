"""Stacking scans into a ScanBatch's arrays (shared by the CARMEN and ROS bag readers)."""

import numpy as np

from probmap.datasets.records import stack_beams


def test_stack_beams_shared_geometry_keeps_one_angle_row():
    a = np.array([-0.5, 0.0, 0.5])
    ranges, angles, beams = stack_beams([np.ones(3), np.full(3, 2.0)], [a, a.copy()], np.float32)
    assert ranges.dtype == np.float32 and ranges.tolist() == [[1, 1, 1], [2, 2, 2]]
    assert angles.shape == (3,) and angles.tolist() == a.tolist()
    assert beams.tolist() == [3, 3]


def test_stack_beams_pads_ragged_scans():
    a2, a3 = np.array([0.1, 0.2]), np.array([0.0, 0.3, 0.6])
    ranges, angles, beams = stack_beams([np.array([4.0, 5.0]), np.ones(3)], [a2, a3], np.float64)
    assert np.array_equal(ranges, [[4.0, 5.0, np.nan], [1, 1, 1]], equal_nan=True)
    assert angles.tolist() == [[0.1, 0.2, 0.0], [0.0, 0.3, 0.6]]
    assert beams.tolist() == [2, 3]
    # equal counts but other angles: one row per scan
    _, angles, _ = stack_beams([np.ones(2), np.ones(2)], [a2, a2 + 1], np.float64)
    assert angles.shape == (2, 2)
