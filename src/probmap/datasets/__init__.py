"""probmap.datasets: readers of laser logs, ROS bags, landmark datasets and pose graphs.

:func:`open_scans` is the one input path of every command that reads a laser log: a CARMEN
log, a ROS 1 or ROS 2 bag, or a registered dataset name, as one
:class:`~probmap.datasets.records.ScanBatch`. It is imported on first use, so that importing
this package (the registry, the CLI's help) loads no numpy.
"""

from __future__ import annotations

from typing import Any

__all__ = ["open_scans"]


def __getattr__(name: str) -> Any:
    if name == "open_scans":
        from probmap.datasets.scans import open_scans

        return open_scans
    raise AttributeError(f"module 'probmap.datasets' has no attribute {name!r}")
