"""The typed dataset protocol shared by every reader.

A dataset is a sized, iterable, re-iterable sequence of frozen records (laser scans, odometry,
landmark observations, ground truth). Readers stream: iterating a dataset reads its file(s) lazily,
so a large log never has to sit in memory as text.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Protocol, TypeVar, runtime_checkable

R_co = TypeVar("R_co", covariant=True)


class DatasetError(ValueError):
    """Malformed input data. The message names the file and, where known, the line and field."""

    def __init__(
        self,
        message: str,
        *,
        path: object | None = None,
        line: int | None = None,
        field: str | None = None,
    ) -> None:
        where = []
        if path is not None:
            where.append(str(path))
        if line is not None:
            where.append(f"line {line}")
        if field is not None:
            where.append(f"field {field!r}")
        prefix = ", ".join(where)
        super().__init__(f"{prefix}: {message}" if prefix else message)
        self.path = path
        self.line = line
        self.field = field


@runtime_checkable
class Dataset(Protocol[R_co]):
    """A sized, iterable sequence of frozen records, read lazily."""

    name: str

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[R_co]: ...
