"""probmap.pipelines.optimize: the settings of ``probmap optimize`` and the run."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

from probmap.pipelines.optimize import PoseGraphConfig
from probmap.slam.posegraph.optimize import OptimizerConfig


def test_config_is_the_optimizers_fields_then_its_own():
    own = [f.name for f in fields(PoseGraphConfig)]
    base = [f.name for f in fields(OptimizerConfig)]
    assert own == [*base, "robust_edges", "init"]
    # the same defaults as the optimizer's, but the robust scale left unresolved
    cfg = PoseGraphConfig()
    for name in base:
        expected = OptimizerConfig.__dataclass_fields__[name].default
        assert getattr(cfg, name) == expected, name


@pytest.mark.parametrize(
    ("robust", "scale"), [("none", 1.0), ("huber", 1.345), ("cauchy", 2.3849), ("dcs", 1.0)]
)
def test_robust_scale_resolves_per_kernel_when_the_optimizer_is_built(robust, scale):
    cfg = PoseGraphConfig(robust=robust)
    assert cfg.robust_scale is None
    assert cfg.optimizer().robust_scale == scale
    assert cfg.scale == scale
    assert PoseGraphConfig(robust=robust, robust_scale=0.5).scale == 0.5


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"max_iterations": -1}, "max_iterations must be >= 0, got -1"),
        ({"robust_scale": 0.0}, "robust_scale must be a positive number, got 0.0"),
        ({"robust_edges": "odometry"}, "robust_edges must be 'all' or 'closures', got 'odometry'"),
        ({"init": "zero"}, "init must be auto, given or lago, got 'zero'"),
    ],
)
def test_config_refuses_bad_values_with_the_optimizers_messages(kwargs, message):
    with pytest.raises(ValueError) as info:
        PoseGraphConfig(**kwargs)
    assert str(info.value) == message


def test_the_config_serves_as_an_optimizer_config():
    # a square of four odometry edges whose start is off: the config drives the optimizer
    from probmap.slam.posegraph.optimize import optimize_pose_graph

    truth = np.array(
        [[0.0, 0.0, 0.0], [1.0, 0.0, np.pi / 2], [1.0, 1.0, -np.pi], [0.0, 1.0, -np.pi / 2]]
    )
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])
    z = np.tile([1.0, 0.0, np.pi / 2], (4, 1))
    info = np.tile(np.eye(3), (4, 1, 1))
    start = truth + [[0, 0, 0], [0.1, -0.1, 0.05], [-0.1, 0.1, 0.1], [0.05, 0.05, -0.05]]
    cfg = PoseGraphConfig(robust="huber")
    a = optimize_pose_graph(start, edges, z, info, cfg)
    b = optimize_pose_graph(start, edges, z, info, cfg.optimizer())
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_allclose(a.poses, truth, atol=1e-9)
