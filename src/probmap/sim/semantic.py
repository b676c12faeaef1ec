"""A simulated floor plan with labelled objects and a labelling laser: ground truth for class maps.

The building of :func:`probmap.sim.floorplan.floor_plan` (outer and inner walls, a corridor,
rooms with 1 m doorways) with objects of four classes: walls, open door leaves at every doorway,
furniture (tables, shelves) and pillars, placed off the robot's route. The robot tours the
building along :func:`probmap.sim.floorplan.floor_plan_route`; every beam that returns is
labelled with the class of the cell it hit, and a fraction of the labels are replaced by a wrong
class (uniformly among the other object classes), as a noisy segmentation network would.

Everything is generated from a seed (nothing to download). :func:`map_labelled_world` maps the
labelled scans into a :class:`~probmap.grid.semantic.SemanticGrid`;
:func:`probmap.metrics.map.semantic_iou` and :func:`probmap.metrics.map.reliability` score it
against the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from probmap.grid.raycast import cast_rays
from probmap.grid.semantic import LabelledInverseModel, SemanticGrid
from probmap.grid.spec import GridSpec
from probmap.sim.floorplan import floor_plan_route
from probmap.sim.laser import interpolate_route, noisy_ranges, poses_along

__all__ = [
    "SEMANTIC_CLASSES",
    "SimulatedLabelledWorld",
    "labelled_floor_plan",
    "map_labelled_world",
    "simulate_labelled_world",
]

#: Classes of the simulated world; class 0 is free space.
SEMANTIC_CLASSES: tuple[str, ...] = ("free", "wall", "door", "furniture", "pillar")


@dataclass(frozen=True, eq=False)
class SimulatedLabelledWorld:
    """A true class map and the labelled scans a robot took in it.

    Attributes
    ----------
    truth : ndarray of int8, shape (H, W)
        True class of each cell (0 free, 1.. ``classes[k]``), indexed ``[iy, ix]``.
    spec : GridSpec
        Geometry of ``truth``.
    classes : tuple of str
        Class names, ``classes[0]`` free.
    poses : ndarray, shape (S, 3)
        True sensor poses ``(x, y, theta)`` (metres, radians).
    ranges : ndarray, shape (S, B)
        Measured ranges in metres (``max_range`` for no return, NaN for a dropped reading).
    angles : ndarray, shape (B,)
        Beam angles in the sensor frame, radians.
    max_range : float
        Sensor maximum range, metres.
    labels : ndarray of int64, shape (S, B)
        Reported class of each beam's endpoint (noisy); 0 for beams without a return.
    true_labels : ndarray of int64, shape (S, B)
        True class of the cell each beam hit; 0 for beams without a return.
    probabilities : ndarray, shape (S, B, K) or None
        Per-beam class distributions over classes 1..K (``soft=True`` only).
    """

    truth: NDArray[np.int8]
    spec: GridSpec
    classes: tuple[str, ...]
    poses: NDArray[np.float64]
    ranges: NDArray[np.float64]
    angles: NDArray[np.float64]
    max_range: float
    labels: NDArray[np.int64]
    true_labels: NDArray[np.int64]
    probabilities: NDArray[np.float64] | None


def labelled_floor_plan(
    resolution: float = 0.05, size: tuple[float, float] = (20.0, 12.0)
) -> tuple[NDArray[np.int8], GridSpec]:
    """The building of :func:`~probmap.sim.floorplan.floor_plan` with labelled objects.

    Returns the true class map (H, W) with the classes of :data:`SEMANTIC_CLASSES` and its
    GridSpec (origin (0, 0)). Rooms are 4 m wide; every doorway (1.5-2.5 m into its room) has an
    open door leaf at its hinge; every room has two pieces of furniture and a pillar, all clear
    of the robot's route.
    """
    w_m, h_m = size
    r = resolution
    spec = GridSpec(r, (0.0, 0.0), (round(h_m / r), round(w_m / r)))
    lab = np.zeros(spec.shape, dtype=np.int8)
    t = max(1, round(0.15 / r)) * r  # wall thickness in metres

    def box(cls: int, x0: float, x1: float, y0: float, y1: float) -> None:
        i0, i1 = round(x0 / r), round(x1 / r)
        j0, j1 = round(y0 / r), round(y1 / r)
        lab[max(j0, 0) : max(j1, j0 + 1), max(i0, 0) : max(i1, i0 + 1)] = cls

    wall, door, furniture, pillar = 1, 2, 3, 4
    box(wall, 0, w_m, 0, t)
    box(wall, 0, w_m, h_m - t, h_m)
    box(wall, 0, t, 0, h_m)
    box(wall, w_m - t, w_m, 0, h_m)
    x = 0.0
    while x < w_m - 1e-9:
        for y_wall in (5.0, 7.0):
            box(wall, x, x + 1.5, y_wall, y_wall + t)
            box(wall, x + 2.5, min(x + 4.0, w_m), y_wall, y_wall + t)
        if x > 0:
            box(wall, x, x + t, 0, 5.0)
            box(wall, x, x + t, 7.0, h_m)
        # open door leaves at the hinges, swung into the rooms
        box(door, x + 1.5, x + 1.6, 4.1, 5.0)
        box(door, x + 1.5, x + 1.6, 7.0 + t, 7.9 + t)
        # furniture: a shelf and a table per room; a pillar per room
        box(furniture, x + 2.8, x + 3.6, 3.2, 4.0)
        box(furniture, x + 0.4, x + 1.0, 2.8, 3.6)
        box(furniture, x + 2.8, x + 3.6, 8.0, 8.8)
        box(furniture, x + 0.4, x + 1.0, 8.4, 9.2)
        box(pillar, x + 3.1, x + 3.5, 0.5, 0.9)
        box(pillar, x + 0.5, x + 0.9, 11.0, 11.4)
        x += 4.0
    return lab, spec


# simulate_laser_world's keywords (the same floor plan and tour), then the labels' own: each world
# keeps its own typed, documented signature.
def simulate_labelled_world(
    *,
    seed: int = 0,
    resolution: float = 0.05,
    size: tuple[float, float] = (20.0, 12.0),
    step: float = 0.1,
    n_beams: int = 181,
    fov: float = np.pi,
    max_range: float = 8.0,
    range_noise: float = 0.01,
    label_noise: float = 0.1,
    dropout: float = 0.0,
    soft: bool = False,
) -> SimulatedLabelledWorld:
    """Simulate a labelling laser robot touring :func:`labelled_floor_plan`.

    Parameters
    ----------
    seed : int
        Seed of the random generator; equal seeds give equal worlds.
    resolution, size, n_beams, fov, max_range, range_noise, dropout
        As :func:`probmap.sim.floorplan.simulate_laser_world`.
    step : float
        Distance between scans along the route, metres (0.1: a 10 Hz laser at 1 m/s).
    label_noise : float
        Probability that a beam's label is wrong; a wrong label is uniform over the other
        object classes.
    soft : bool
        Also give per-beam class distributions: the reported label gets a random confidence in
        [0.6, 1) (mean 0.8) and the rest is spread over the other classes with random weights.

    Returns
    -------
    SimulatedLabelledWorld
    """
    if not 0.0 <= label_noise < 1.0:
        raise ValueError(f"label_noise must lie in [0, 1), got {label_noise}")
    rng = np.random.default_rng(seed)
    truth, spec = labelled_floor_plan(resolution, size)
    K = len(SEMANTIC_CLASSES) - 1
    poses = poses_along(interpolate_route(floor_plan_route(size), step), rng, 0.05)
    angles = np.linspace(-fov / 2, fov / 2, n_beams)
    true_r = cast_rays(truth > 0, spec, poses, angles, max_range)
    hit = true_r < max_range
    true_labels = _hit_labels(truth, spec, poses, angles, true_r, hit)
    ranges = noisy_ranges(true_r, max_range, rng, range_noise, dropout)
    wrong = hit & (rng.random(hit.shape) < label_noise)
    # a wrong label: one of the K - 1 other object classes, uniformly
    shift = rng.integers(1, K, hit.shape)
    labels = np.where(wrong, (true_labels - 1 + shift) % K + 1, true_labels)
    labels = np.where(hit, labels, 0).astype(np.int64)
    probs = None
    if soft:
        conf = rng.uniform(0.6, 1.0, hit.shape)
        rest = rng.random((*hit.shape, K))
        onehot = np.eye(K, dtype=bool)[np.clip(labels - 1, 0, K - 1)]
        rest[onehot] = 0.0
        rest *= ((1.0 - conf) / rest.sum(axis=-1))[..., None]
        probs = np.where(onehot, conf[..., None], rest)
    return SimulatedLabelledWorld(
        truth,
        spec,
        SEMANTIC_CLASSES,
        poses,
        ranges,
        angles,
        float(max_range),
        labels,
        true_labels,
        probs,
    )


def _hit_labels(
    truth: NDArray[np.int8],
    spec: GridSpec,
    poses: NDArray[np.float64],
    angles: NDArray[np.float64],
    r: NDArray[np.float64],
    hit: NDArray[np.bool_],
) -> NDArray[np.int64]:
    """True class of the cell where each beam enters its first occupied cell (0 for no hit)."""
    a = poses[:, 2:3] + angles[None, :]
    d = r + 1e-6 * spec.resolution
    pts = np.stack([poses[:, 0:1] + d * np.cos(a), poses[:, 1:2] + d * np.sin(a)], axis=-1)
    cells = spec.world_to_cell(pts.reshape(-1, 2))
    out = np.zeros(len(cells), dtype=np.int64)
    pad = np.pad(truth, 1)
    ix = np.clip(cells[:, 0], -1, spec.width) + 1
    iy = np.clip(cells[:, 1], -1, spec.height) + 1
    out[:] = pad[iy, ix]
    # rounding at a cell boundary: take the nearest occupied neighbour
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)):
        miss = out == 0
        if not miss.any():
            break
        yy = np.clip(iy[miss] + dy, 0, pad.shape[0] - 1)
        xx = np.clip(ix[miss] + dx, 0, pad.shape[1] - 1)
        out[miss] = pad[yy, xx]
    return np.where(hit.ravel(), out, 0).reshape(hit.shape)


# --------------------------------------------------------------------------- mapping
def map_labelled_world(
    world: SimulatedLabelledWorld,
    *,
    resolution: float = 0.05,
    model: LabelledInverseModel | None = None,
    clamp: tuple[float, float] = (0.01, 0.99),
    soft: bool = False,
) -> SemanticGrid:
    """A :class:`SemanticGrid` built from the world's labelled scans (hard labels or ``soft``)."""
    grid = SemanticGrid(world.classes, resolution=resolution, model=model, clamp=clamp)
    if soft:
        if world.probabilities is None:
            raise ValueError("the world has no probability vectors (simulate with soft=True)")
        grid.integrate_scans(
            world.poses,
            world.ranges,
            world.angles,
            probabilities=world.probabilities,
            max_range=world.max_range,
        )
    else:
        grid.integrate_scans(
            world.poses, world.ranges, world.angles, labels=world.labels, max_range=world.max_range
        )
    return grid
