"""The semantic mapping demo (``probmap demo --semantic``): simulate a labelled floor plan, map it,
write the map files and score the map against the truth.

The simulator is :mod:`probmap.sim.semantic`, the scores :mod:`probmap.metrics.map`, the map
:class:`~probmap.grid.semantic.SemanticGrid`, the files :mod:`probmap.grid.semantic_io`; this
module only runs them in order and returns plain values for the CLI to print.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from probmap._atomic import atomic_outputs
from probmap.grid.semantic import LabelledInverseModel, SemanticGrid
from probmap.grid.semantic_io import write_semantic_maps
from probmap.metrics.map import reliability, semantic_iou, truth_on_grid
from probmap.sim.semantic import simulate_labelled_world

__all__ = ["run_semantic_demo"]


def run_semantic_demo(out_dir: str | os.PathLike[str], *, seed: int = 0) -> dict[str, Any]:
    """Map the simulated labelled floor plan (10 % wrong labels), write the maps, score them.

    Writes into ``out_dir``: ``semantic.npz`` (the lossless semantic map), ``semantic.png``
    (colour map with legend) and ``occupancy.{yaml,pgm,npz,png}`` (the derived occupancy grid in
    the map_server format).

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
    with atomic_outputs():  # all six files or none; a missing out_dir is created
        files = write_semantic_maps(out / "semantic", grid)
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
