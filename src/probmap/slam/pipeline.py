"""Deprecated path of the landmark-SLAM pipeline, now :mod:`probmap.pipelines.landmark_slam`.

Running an estimator over a dataset, evaluating and writing outputs is a pipeline, not SLAM core.
This path works for one release: importing it imports nothing of the pipeline, and each old name
is forwarded, with a ``DeprecationWarning``, when it is looked up.
"""

from __future__ import annotations

from probmap._deprecation import moved

__getattr__ = moved(
    __name__,
    dict.fromkeys(
        [
            "GPS_MAX_SPEED",
            "SlamResult",
            "dead_reckoning",
            "default_ekf_config",
            "evaluate",
            "run_landmark_slam",
            "write_slam_outputs",
        ],
        "probmap.pipelines.landmark_slam",
    ),
)
