"""``probmap.geometry._kernels``: the compiled angle wrap against ``se2.wrap_angle``."""

from __future__ import annotations

import math

import numpy as np

from probmap.geometry._kernels import wrap
from probmap.geometry.se2 import wrap_angle


def test_wrap_is_wrap_angle_on_scalars():
    rng = np.random.default_rng(0)
    angles = np.r_[rng.uniform(-100.0, 100.0, 2000), [0.0, -0.0, 1e-300, 7 * math.pi, -7 * math.pi]]
    for a in angles:
        w = wrap(float(a))
        assert -math.pi <= w < math.pi
        # same angle: differs from the input by a whole number of turns
        turns = (float(a) - w) / (2 * math.pi)
        assert abs(turns - round(turns)) < 1e-9
        assert abs(w - float(wrap_angle(a))) < 1e-12


def test_wrap_takes_the_half_open_interval():
    assert wrap(math.pi) == -math.pi
    assert wrap(-math.pi) == -math.pi
    assert wrap(3 * math.pi) == -math.pi
