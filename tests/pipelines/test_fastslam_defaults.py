"""Dataset defaults of FastSLAM are resolved in one place for ``slam fastslam`` and ``slam
compare`` (the pipelines module), as the EKF's are."""

from __future__ import annotations

import math

from probmap.pipelines.landmark_slam import default_ekf_config, default_fastslam_config
from probmap.slam.landmark.fastslam import FastSLAMConfig


class VictoriaPark:  # the dataset class is recognised by name, as default_ekf_config does
    pass


def test_victoria_park_gets_the_ekfs_perceptual_range_and_keeps_the_rest():
    ekf = default_ekf_config(VictoriaPark())
    base = FastSLAMConfig(n_particles=7, version=1)
    cfg = default_fastslam_config(VictoriaPark(), base)
    assert cfg.visibility_range == ekf.visibility_range == 25.0
    assert math.isclose(cfg.visibility_fov, ekf.visibility_fov)
    assert (cfg.n_particles, cfg.version) == (7, 1)


def test_other_datasets_keep_the_given_configuration():
    base = FastSLAMConfig(seed=3)
    assert default_fastslam_config(object(), base) is base
    assert default_fastslam_config(object()) == FastSLAMConfig()


def test_graphslam_on_victoria_park_uses_the_ekfs_landmark_rule():
    from probmap.pipelines.landmark_slam import default_graphslam_config

    ekf = default_ekf_config(VictoriaPark())
    cfg = default_graphslam_config(VictoriaPark())
    assert cfg.visibility_range == ekf.visibility_range
    assert math.isclose(cfg.visibility_fov, ekf.visibility_fov)
    assert cfg.max_misses == ekf.max_misses
    assert default_graphslam_config(object()).visibility_range is None
