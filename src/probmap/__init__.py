"""probmap: probabilistic robot mapping and SLAM.

Occupancy grids with known poses (log-odds Bayes filter), particle filters and Monte Carlo
localization, EKF and SEIF landmark SLAM, following Thrun, Burgard and Fox,
*Probabilistic Robotics* (2005).

Heavy dependencies (numba, scipy, matplotlib) are imported lazily so that ``import probmap``
and the command line start fast.
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"

_LAZY = {
    "GridSpec": "probmap.grid.spec",
    "OccupancyGrid": "probmap.grid.occupancy",
    "InverseSensorModel": "probmap.grid.occupancy",
    "logit": "probmap.grid.logodds",
    "prob": "probmap.grid.logodds",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'probmap' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(module), name)
