"""The typed dataset protocol shared by every reader.

A dataset is a sized, iterable, re-iterable sequence of frozen records (laser scans, odometry,
landmark observations, ground truth). Readers stream: iterating a dataset reads its file(s) lazily,
so a large log never has to sit in memory as text.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Protocol, TypeVar, runtime_checkable

from probmap.errors import DatasetError as DatasetError  # re-exported: the old import path

R_co = TypeVar("R_co", covariant=True)


@runtime_checkable
class Dataset(Protocol[R_co]):
    """A sized, iterable sequence of frozen records, read lazily."""

    name: str

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[R_co]: ...
