"""Fitting the beam model to a laser log: read the log, map it, ray-cast it, run EM.

The EM fit itself (Probabilistic Robotics Table 6.2) is :func:`probmap.models.beam.fit_beam_model`,
which takes arrays; this module adds the reading of the log (:func:`probmap.datasets.open_scans`:
a CARMEN log, a ROS 1/2 bag or a registry name) and the map that provides the expected ranges.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from probmap._checks import require_integer
from probmap.datasets.scans import open_scans
from probmap.models.beam import BeamModelParams, FitResult, fit_beam_model

if TYPE_CHECKING:
    from probmap.datasets.records import ScanBatch
    from probmap.datasets.validate import ReadingReport

__all__ = ["FitConfig", "fit_log", "fit_scans", "read_fit_scans"]


@dataclass(frozen=True)
class FitConfig:
    """Settings of fitting the beam model to a log (``probmap fit-sensor-model``); loadable
    from and dumpable to YAML with :mod:`probmap.config`.

    Attributes
    ----------
    resolution : float
        Cell size (m) of the log's own map, in which the expected ranges are cast (> 0).
    every : int
        Use every ``every``-th scan (>= 1).
    max_range : float or None
        Sensor maximum range, metres (``None``: the log's).
    poses : {"corrected", "odometry"}
        The scans' laser poses, or the odometry.
    max_iterations : int
        Most EM iterations (Table 6.2; >= 1).
    tol : float
        EM stops when the mean log-likelihood gains less than this (>= 0).
    """

    resolution: float = 0.05
    every: int = 1
    max_range: float | None = None
    poses: Literal["corrected", "odometry"] = "corrected"
    max_iterations: int = 200
    tol: float = 1e-7

    def __post_init__(self) -> None:
        if not (math.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f"resolution must be a number > 0, got {self.resolution}")
        require_integer("every", self.every, 1)
        if self.max_range is not None and not (
            math.isfinite(self.max_range) and self.max_range > 0
        ):
            raise ValueError(f"max_range must be a number > 0 or null, got {self.max_range}")
        if self.poses not in ("corrected", "odometry"):
            raise ValueError(f"poses must be 'corrected' or 'odometry', got {self.poses!r}")
        require_integer("max_iterations", self.max_iterations, 1)
        if not (math.isfinite(self.tol) and self.tol >= 0):
            raise ValueError(f"tol must be a number >= 0, got {self.tol}")


def read_fit_scans(
    path: str | os.PathLike[str],
    config: FitConfig,
    *,
    skip_bad_lines: bool = False,
    bag_options: dict[str, Any] | None = None,
) -> ScanBatch:
    """The scans a fit reads: :func:`probmap.datasets.open_scans` of ``path`` (a CARMEN log, a
    ROS 1/2 bag or a registry name) with the poses and maximum range ``config`` names, for
    :func:`fit_scans` (``bag_options``: a bag's topics and frames, guessed when not given).

    Raises
    ------
    DatasetError
        A malformed log, or one without a single usable reading (naming the file).
    """
    return open_scans(
        path,
        poses=config.poses,
        max_range=config.max_range,
        skip_bad_lines=skip_bad_lines,
        bag_options=bag_options,
    )


def fit_scans(
    batch: ScanBatch, config: FitConfig | None = None, *, init: BeamModelParams | None = None
) -> FitResult:
    """Fit the beam model to the scans of ``batch`` (from :func:`probmap.datasets.open_scans`,
    read with the poses and maximum range ``config`` names).

    The map is the log-odds map of the scans themselves (Table 9.1), thresholded at p = 0.5;
    the expected ranges come from exact ray casting in it. Every ``config.every``-th scan is
    used.
    """
    from probmap.grid.occupancy import OccupancyGrid
    from probmap.grid.raycast import cast_rays

    cfg = config if config is not None else FitConfig()
    mr = float(batch.max_range)
    P = np.asarray(batch.laser_poses)
    R = np.asarray(batch.ranges)
    A = np.asarray(batch.angles)
    grid = OccupancyGrid(cfg.resolution)
    grid.integrate_scans(P, R, A, max_range=mr)
    occ = grid.classify(0.5, 0.5) == 1
    sel = slice(None, None, cfg.every)
    if A.ndim == 1:
        zs = cast_rays(occ, grid.spec, P[sel], A, mr)
    else:
        zs = np.stack(
            [cast_rays(occ, grid.spec, p, a, mr) for p, a in zip(P[sel], A[sel], strict=True)]
        )
    return fit_beam_model(R[sel], zs, mr, init=init, max_iterations=cfg.max_iterations, tol=cfg.tol)


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
    config: FitConfig | None = None,
) -> FitResult:
    """Fit the beam model to a laser log (CARMEN, ROS 1/2 bag, registry name) with known poses.

    The map is the log-odds map of the log itself (Table 9.1), thresholded at p = 0.5; the
    expected ranges come from exact ray casting in it. Every ``every``-th scan is used.
    Readings are validated as in every command (:mod:`probmap.datasets.validate`: zero and
    invalid readings are dropped); ``readings``, when given, is called with their report.
    ``bag_options``: a bag's topics and frames (guessed when not given). ``config``, when
    given, holds every setting instead of ``resolution``, ``every``, ``max_range`` and
    ``poses`` (which must then keep their defaults).

    Raises
    ------
    DatasetError
        A malformed log, or one without a single usable reading (naming the file).
    ValueError
        A setting out of range, or ``config`` given with one of the four keywords.
    """
    keywords = FitConfig(resolution=resolution, every=every, max_range=max_range, poses=poses)  # type: ignore[arg-type]  # checked by FitConfig
    if config is not None and keywords != FitConfig():
        raise ValueError("give the settings either in config or as keywords, not both")
    cfg = config if config is not None else keywords
    batch = read_fit_scans(path, cfg, skip_bad_lines=skip_bad_lines, bag_options=bag_options)
    if readings is not None and batch.readings is not None:
        readings(batch.readings)
    return fit_scans(batch, cfg, init=init)
