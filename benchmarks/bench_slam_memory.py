"""Where the memory of ``probmap slam grid`` goes (issue 36, item 4): the process's resident
size (RSS) and its high-water mark (max RSS) at the boundaries of each phase of
:func:`probmap.pipelines.laser_slam.slam_grid`: reading the log, SLAM up to
``SubmapSlam.finish``, the final map (``SubmapSlam.map``), the check phase (the report), the
map files (``save_map``), the pose graph, and the picture (``save_graph_slam_figure``: the
axes with the map image, ``plot_graph_slam``, then the file, ``save_picture``).

Usage::

    python benchmarks/bench_slam_memory.py LOG OUT_PREFIX

One run per process (a second run in the same process would start from the first one's
high-water mark). Prints one line per point, in MiB.
"""

from __future__ import annotations

import argparse
import functools
import resource
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any


def _rss_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS"):
                return int(line.split()[1]) / 1024
    return float("nan")


def _peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


def _say(what: str) -> None:
    print(f"{what:40s} rss {_rss_mib():6.0f}  peak {_peak_mib():6.0f}", flush=True)


def _traced(owner: Any, name: str) -> None:
    """Print the memory before and after every call of ``owner.name``."""
    inner: Callable[..., Any] = getattr(owner, name)

    @functools.wraps(inner)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        _say(f"  {name} in")
        out = inner(*args, **kwargs)
        _say(f"  {name} out")
        return out

    setattr(owner, name, wrapper)


@contextmanager
def _phase(name: str) -> Iterator[None]:
    _say(f"{name} in")
    yield
    _say(f"{name} out")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log")
    ap.add_argument("prefix")
    args = ap.parse_args()

    import probmap.datasets.g2o as g2o
    import probmap.grid.io as gio
    import probmap.viz.laser_slam as viz
    from probmap.pipelines.laser_slam import slam_grid
    from probmap.slam.laser.submap_slam import SubmapSlam

    _traced(SubmapSlam, "finish")
    _traced(SubmapSlam, "map")
    _traced(gio, "save_map")
    _traced(g2o, "write_pose_graph_g2o")
    _traced(viz, "save_graph_slam_figure")
    _traced(viz, "plot_graph_slam")
    _traced(viz, "save_picture")
    slam_grid(args.log, args.prefix, phase=_phase)
    _say("end")


if __name__ == "__main__":
    main()
