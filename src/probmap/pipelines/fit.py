"""Fitting the beam model to a laser log: read the log, map it, ray-cast it, run EM.

The EM fit itself (Probabilistic Robotics Table 6.2) is :func:`probmap.models.beam.fit_beam_model`,
which takes arrays; this module adds the reading of the log (:func:`probmap.datasets.open_scans`:
a CARMEN log, a ROS 1/2 bag or a registry name) and the map that provides the expected ranges.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from probmap.datasets.scans import open_scans
from probmap.models.beam import BeamModelParams, FitResult, fit_beam_model

if TYPE_CHECKING:
    from probmap.datasets.validate import ReadingReport

__all__ = ["fit_log"]


def fit_log(
    path: str | os.PathLike[str],
    *,
    resolution: float = 0.05,
    every: int = 1,
    max_range: float | None = None,
    poses: str = "corrected",
    skip_bad_lines: bool = False,
    init: BeamModelParams | None = None,
    readings: Callable[[ReadingReport], None] | None = None,
    bag_options: dict[str, Any] | None = None,
) -> FitResult:
    """Fit the beam model to a laser log (CARMEN, ROS 1/2 bag, registry name) with known poses.

    The map is the log-odds map of the log itself (Table 9.1), thresholded at p = 0.5; the
    expected ranges come from exact ray casting in it. Every ``every``-th scan is used.
    Readings are validated as in every command (:mod:`probmap.datasets.validate`: zero and
    invalid readings are dropped); ``readings``, when given, is called with their report.
    ``bag_options``: a bag's topics and frames (guessed when not given).

    Raises
    ------
    DatasetError
        A malformed log, or one without a single usable reading (naming the file).
    """
    from probmap.grid.occupancy import OccupancyGrid
    from probmap.grid.raycast import cast_rays

    if every < 1:
        raise ValueError(f"every must be >= 1, got {every}")
    batch = open_scans(
        path,
        poses=poses,
        max_range=max_range,
        skip_bad_lines=skip_bad_lines,
        bag_options=bag_options,
    )
    mr = float(batch.max_range)
    if readings is not None and batch.readings is not None:
        readings(batch.readings)
    P = np.asarray(batch.laser_poses)
    R = np.asarray(batch.ranges)
    A = np.asarray(batch.angles)
    grid = OccupancyGrid(resolution)
    grid.integrate_scans(P, R, A, max_range=mr)
    occ = grid.classify(0.5, 0.5) == 1
    sel = slice(None, None, every)
    if A.ndim == 1:
        zs = cast_rays(occ, grid.spec, P[sel], A, mr)
    else:
        zs = np.stack(
            [cast_rays(occ, grid.spec, p, a, mr) for p, a in zip(P[sel], A[sel], strict=True)]
        )
    return fit_beam_model(R[sel], zs, mr, init=init)
