"""The shared argument checks (``probmap._checks``) against a plain reference predicate.

Each check must let through exactly the values its reference accepts and refuse the others with
the package's message, so that a config that moved to the helper still accepts and refuses the
same values with the same words.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from probmap._checks import (
    is_finite_number,
    require_at_least,
    require_integer,
    require_nonnegative_finite,
    require_positive_finite,
)
from probmap.filters.mcl import MCLConfig
from probmap.pipelines.fit import FitConfig
from probmap.slam.landmark.graphslam import GraphSLAMConfig
from probmap.slam.landmark.seif import SeifConfig
from probmap.slam.laser.scan_matching import MatcherConfig

VALUES = [-math.inf, -2.5, -1, -1e-12, 0, 0.0, 1e-300, 0.5, 1, 2, 7.25, 1e300, math.inf, math.nan]


def _raises(check, *args) -> str | None:
    try:
        check(*args)
    except ValueError as exc:
        return str(exc)
    return None


@pytest.mark.parametrize("value", VALUES)
def test_positive_finite_matches_reference(value):
    ok = math.isfinite(value) and value > 0
    msg = _raises(require_positive_finite, "sigma", value)
    assert (msg is None) == ok
    if not ok:
        assert msg == f"sigma must be a positive number, got {value}"


@pytest.mark.parametrize("value", VALUES)
def test_nonnegative_finite_matches_reference(value):
    ok = math.isfinite(value) and value >= 0
    msg = _raises(require_nonnegative_finite, "linear_window", value)
    assert (msg is None) == ok
    if not ok:
        assert msg == f"linear_window must be >= 0, got {value}"


@pytest.mark.parametrize("low", [0, 1, 2])
@pytest.mark.parametrize("value", VALUES)
def test_at_least_matches_reference(value, low):
    ok = not math.isnan(value) and value >= low  # inf passes, NaN never does
    msg = _raises(require_at_least, "workers", value, low)
    assert (msg is None) == ok
    if not ok:
        assert msg == f"workers must be >= {low}, got {value}"


def test_at_least_names_the_unit():
    assert (
        _raises(require_at_least, "interval", -0.5, 0, "s") == "interval must be >= 0 s, got -0.5"
    )
    assert _raises(require_at_least, "interval", 0.0, 0, "s") is None


def test_matcher_config_refuses_through_the_helpers():
    """A config that calls the helpers names its field, as before (a NaN count is refused too)."""
    with pytest.raises(ValueError, match=re.escape("sigma must be a positive number, got 0.0")):
        MatcherConfig(sigma=0.0)
    with pytest.raises(ValueError, match=re.escape("angular_window must be >= 0, got nan")):
        MatcherConfig(angular_window=math.nan)
    with pytest.raises(ValueError, match=re.escape("beam_skip must be >= 1, got 0")):
        MatcherConfig(beam_skip=0)
    with pytest.raises(ValueError, match=re.escape("iterations must be >= 0, got -1")):
        MatcherConfig(iterations=-1)
    assert MatcherConfig(iterations=0, linear_window=0.0).iterations == 0
    # a config the helpers do not serve keeps its own words
    with pytest.raises(ValueError, match="n_particles must be positive"):
        MCLConfig(n_particles=0)


INTEGERS = [
    *VALUES,
    -3,
    3,
    10**20,
    True,
    False,
    np.int64(2),
    np.int32(-1),
    np.uint8(1),
    np.float64(2.0),
    "2",
    None,
]


@pytest.mark.parametrize("low", [0, 1])
@pytest.mark.parametrize("value", INTEGERS, ids=repr)
def test_integer_matches_reference(value, low):
    # a count: Python or numpy integers, not bools, not floats that happen to be whole
    ok = type(value) in (int, np.int64, np.int32, np.uint8) and value >= low
    msg = _raises(require_integer, "max_misses", value, low)
    assert (msg is None) == ok
    if not ok:
        assert msg == f"max_misses must be an integer >= {low}, got {value!r}"


@pytest.mark.parametrize(
    "build,field,low",
    [
        (GraphSLAMConfig, "max_iterations", 0),
        (GraphSLAMConfig, "outlier_rounds", 0),
        (GraphSLAMConfig, "min_observations", 1),
        (GraphSLAMConfig, "max_misses", 0),
        (SeifConfig, "context_hops", 0),
        (FitConfig, "every", 1),
        (FitConfig, "max_iterations", 1),
    ],
)
def test_configs_refuse_counts_through_the_integer_helper(build, field, low):
    for bad in (low - 1, float(low), True):
        with pytest.raises(ValueError) as err:
            build(**{field: bad})
        assert str(err.value) == f"{field} must be an integer >= {low}, got {bad!r}"
    assert getattr(build(**{field: np.int64(low)}), field) == low


@pytest.mark.parametrize(
    "value,ok",
    [
        (0, True),
        (-3, True),
        (10**20, True),
        (2.5, True),
        (-1e300, True),
        (np.float32(1.5), True),
        (np.int64(-2), True),
        (np.array(2.0), True),
        (math.inf, False),
        (-math.inf, False),
        (math.nan, False),
        (np.float64("nan"), False),
        (True, False),
        (False, False),
        ("2", True),  # float("2") is 2.0: YAML and CLI text are numbers to this check
        ("x", False),
        (None, False),
        (1j, False),
        ((1.0, 2.0), False),
    ],
    ids=repr,
)
def test_is_finite_number(value, ok):
    assert is_finite_number(value) is ok
