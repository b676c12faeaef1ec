"""The semantic mapping demo (``probmap demo --semantic``): simulate a labelled floor plan, map it,
write the map files and score the map against the truth.

The simulator is :mod:`probmap.sim.semantic`, the scores :mod:`probmap.metrics.map`, the map
:class:`~probmap.grid.semantic.SemanticGrid`, the files :mod:`probmap.grid.semantic_io`; this
module only runs them in order and returns plain values for the CLI to print.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from probmap._atomic import atomic_outputs
from probmap.grid.semantic import LabelledInverseModel, SemanticGrid
from probmap.grid.semantic_io import write_semantic_maps
from probmap.metrics.map import reliability, semantic_iou, truth_on_grid
from probmap.sim.semantic import simulate_labelled_world

__all__ = ["SemanticMappingConfig", "run_semantic_demo"]


@dataclass(frozen=True)
class SemanticMappingConfig:
    """Settings of semantic mapping from labelled scans (``probmap semantic``); loadable from
    and dumpable to YAML with :mod:`probmap.config`.

    Attributes
    ----------
    resolution : float
        Cell size of the map, metres (> 0).
    p_hit : float
        ``p(m != free | z)`` at a beam's endpoint, in (0, 1)
        (:class:`~probmap.grid.semantic.LabelledInverseModel`).
    p_miss : float
        ``p(m != free | z)`` for the cells a beam crosses, in (0, 1).
    p_correct : float
        Probability that a hard label is right, in (0, 1] (the confusion model).
    max_clear : float or None
        Free space cleared by a reading at or beyond the maximum range, metres (``None``: the
        scans' maximum range; 0 ignores such readings).
    """

    resolution: float = 0.05
    p_hit: float = 0.7
    p_miss: float = 0.4
    p_correct: float = 0.9
    max_clear: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.resolution) and self.resolution > 0):
            raise ValueError(f"resolution must be a number > 0, got {self.resolution}")
        if self.max_clear is not None and not (self.max_clear >= 0):
            raise ValueError(f"max_clear must be >= 0 or null, got {self.max_clear}")
        self.model()  # the model's own rules on p_hit, p_miss and p_correct

    def model(self) -> LabelledInverseModel:
        """The inverse sensor model these settings describe."""
        return LabelledInverseModel(
            p_hit=self.p_hit,
            p_miss=self.p_miss,
            p_correct=self.p_correct,
            max_clear_range=self.max_clear,
        )


def run_semantic_demo(out_dir: str | os.PathLike[str], *, seed: int = 0) -> dict[str, Any]:
    """Map the simulated labelled floor plan (10 % wrong labels), write the maps, score them.

    Writes into ``out_dir``: ``semantic.npz`` (the lossless semantic map), ``semantic.png``
    (colour map with legend), ``semantic.occupancy.{yaml,pgm,npz,png}`` (the derived occupancy
    grid in the map_server format) and its picture ``semantic.occupancy.plot.png``.

    Returns
    -------
    dict
        Plain values for printing: scans, beams, cell updates, times, per-class IoU (with a
        one-cell tolerance and strict), the calibration error, the files written.
    """
    out = Path(out_dir)
    t0 = time.perf_counter()
    world = simulate_labelled_world(seed=seed, range_noise=0.01, label_noise=0.1, dropout=0.01)
    t1 = time.perf_counter()
    model = LabelledInverseModel(p_correct=0.9)
    grid = SemanticGrid(world.classes, resolution=0.05, model=model)
    stats = grid.integrate_scans(
        world.poses, world.ranges, world.angles, labels=world.labels, max_range=world.max_range
    )
    t2 = time.perf_counter()
    with atomic_outputs():  # all seven files or none; a missing out_dir is created
        files = write_semantic_maps(out / "semantic", grid)
        from probmap.viz.maps import save_map_figure

        files.append(
            save_map_figure(
                out / "semantic.occupancy.plot.png", grid.to_occupancy(), trajectory=world.poses,
                title="probmap demo --semantic: simulated labelled floor plan",
            )
        )  # fmt: skip
    t3 = time.perf_counter()
    truth = truth_on_grid(grid.spec, world.truth, world.spec)
    wrong = world.labels != world.true_labels
    cls = grid.classify()
    iou = semantic_iou(cls, truth, len(world.classes), tolerance=1)
    strict = semantic_iou(cls, truth, len(world.classes), tolerance=0)
    rel = reliability(grid.probabilities(), grid.observed, truth)
    return {
        "scans": stats.scans,
        "beams": stats.beams,
        "hits": stats.hits,
        "cell updates": stats.cell_updates,
        "observed cells": int(grid.observed.sum()),
        "wrong labels": f"{100 * float(wrong[world.true_labels > 0].mean()):.1f} % of hits",
        "iou": {name: float(v) for name, v in zip(world.classes, iou, strict=True)},
        "iou strict": {name: float(v) for name, v in zip(world.classes, strict, strict=True)},
        "calibration error": rel.expected_calibration_error,
        "simulate seconds": t1 - t0,
        "map seconds": t2 - t1,
        "write seconds": t3 - t2,
        "files": [str(f) for f in files],
    }
