"""A raw-odometry log of the Freiburg campus, rebuilt from its GMapping-corrected log, and
relations from the corrected poses: the one outdoor log in ``../shared/data``, with a scan
about every metre and odometry whose turns are off, for ``bench_graph_slam.py --worker campus``
and ``tests/pipelines/test_campus_rebuilt.py``.

The corrected log (``freiburg-campus/freiburg-campus-corrected.log.gz``, 2,008 FLASER lines,
17,691 ODOM lines, every timestamp 0) writes each scan at its corrected pose. After each scan
its ODOM lines restart from that pose and add the wheel odometry's increments until the next
scan. So ``between(corrected pose of scan k, last ODOM before scan k + 1)`` is the odometry's
own motion between the two scans, and chaining these motions gives the odometry trajectory
(the wheels' drift, not GMapping's corrections). Taking the ODOM line before the last, or the
last one extrapolated by its own step, agrees worse with the corrected motions (1.7 and 2.4
against 1.4 degrees of mean turn error per scan), so the last one is taken.

The times are synthetic: 0.14 s per ODOM line, 2,465 s in all, a mean speed of 0.71 m/s (the
log's ``robot_max_t_vel`` is 0.70 m/s). The reference is GMapping's estimate, not ground
truth: errors of a few centimetres against it say nothing; metres (a fold, a corridor drawn
twice) do.
"""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np

from probmap.geometry.se2 import between, compose
from probmap.metrics.relations import Relations

CORRECTED = "freiburg-campus/freiburg-campus-corrected.log.gz"
ODOM_PERIOD_S = 0.14  # synthetic time per ODOM line
LASER_OFFSET_M = -0.04  # PARAM robot_frontlaser_offset
LOOP_GAP_S = 60.0  # loop relations: scans further apart in time than this ...
LOOP_RADIUS_M = 4.0  # ... and closer than this in the corrected map
LOOP_RELATIONS = 3000  # at most this many, drawn with seed 0


def rebuild(corrected: Path, out: Path) -> tuple[np.ndarray, np.ndarray]:
    """Write ``out``, a raw CARMEN log (the corrected log's PARAM lines, then one FLASER line
    per scan with the odometry pose), and return the scan times (S,) and the corrected robot
    poses (S, 3)."""
    params: list[str] = []
    scans: list[list[str]] = []
    poses: list[list[float]] = []
    last_odom: list[list[float]] = []
    odom_count: list[int] = []
    last: list[float] | None = None
    count = 0
    with gzip.open(corrected, "rt") as f:
        for line in f:
            fields = line.split()
            if not fields:
                continue
            if fields[0] == "PARAM":
                params.append(line)
            elif fields[0] == "ODOM":
                last = [float(v) for v in fields[1:4]]
                count += 1
            elif fields[0] == "FLASER":
                n = int(fields[1])
                if scans:
                    assert last is not None
                    last_odom.append(last)
                scans.append(fields[2 : 2 + n])
                poses.append([float(v) for v in fields[2 + n : 5 + n]])
                odom_count.append(count)
    ref = np.asarray(poses)
    steps = between(ref[:-1], np.asarray(last_odom))
    odo = [ref[0]]
    for u in steps:
        odo.append(compose(odo[-1], u))
    odometry = np.asarray(odo)
    laser = compose(odometry, np.array([LASER_OFFSET_M, 0.0, 0.0]))
    times = 1000.0 + np.asarray(odom_count, dtype=np.float64) * ODOM_PERIOD_S
    with open(out, "w") as f:
        f.writelines(params)
        for k, ranges in enumerate(scans):
            pose = " ".join(f"{v:.6f}" for v in (*laser[k], *odometry[k]))
            f.write(f"FLASER {len(ranges)} {' '.join(ranges)} {pose} {times[k]:.6f} campus "
                    f"{times[k]:.6f}\n")  # fmt: skip
    return times, ref


def relations(times: np.ndarray, ref: np.ndarray) -> tuple[Relations, Relations]:
    """Relations from the corrected poses: local (each scan to the next three) and loop (pairs
    more than ``LOOP_GAP_S`` apart in time and within ``LOOP_RADIUS_M``, at most
    ``LOOP_RELATIONS`` of them drawn with seed 0)."""
    n = len(times)
    i1 = np.concatenate([np.arange(n - k) for k in (1, 2, 3)])
    i2 = np.concatenate([np.arange(k, n) for k in (1, 2, 3)])
    d = np.hypot(ref[:, None, 0] - ref[None, :, 0], ref[:, None, 1] - ref[None, :, 1])
    gap = np.abs(times[:, None] - times[None, :])
    a, b = np.nonzero(np.triu((d < LOOP_RADIUS_M) & (gap > LOOP_GAP_S)))
    pick = np.random.default_rng(0).choice(len(a), size=min(LOOP_RELATIONS, len(a)), replace=False)
    a, b = a[pick], b[pick]

    def rel(p: np.ndarray, q: np.ndarray) -> Relations:
        return Relations(times[p], times[q], between(ref[p], ref[q]))

    return rel(i1, i2), rel(a, b)
