"""The field-by-field sum of two count records, one copy for every record that adds.

A record of counts (:class:`~probmap.grid.occupancy.ScanStats`,
:class:`~probmap.datasets.validate.ReadingReport`) describes part of a run; two parts add up to
the record of both. Summing every field here, rather than in a hand-written ``__add__`` per
record, means a field added to a record later is summed too instead of being left out.

This module imports only the standard library, so that any layer may import it.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:  # pragma: no cover
    from _typeshed import DataclassInstance

    R = TypeVar("R", bound=DataclassInstance)
else:
    R = TypeVar("R")

__all__ = ["field_sums"]


def field_sums(a: R, b: R, **merged: Any) -> R:
    """The record of ``a`` and ``b`` together: each field ``a.f + b.f``.

    Parameters
    ----------
    a, b : dataclass instances of one type
        The two records (counts of two parts of a run).
    **merged
        Values for the fields that do not add with ``+`` (a histogram merged by key ...),
        computed by the caller.

    Returns
    -------
    A record of ``a``'s type.

    Raises
    ------
    TypeError
        ``merged`` names a field the record does not have.

    Examples
    --------
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Counts:
    ...     hits: int
    ...     misses: int
    ...     label: str = ""
    >>> field_sums(Counts(1, 2, "a"), Counts(10, 20, "b"), label="a+b")
    Counts(hits=11, misses=22, label='a+b')
    """
    names = [f.name for f in dataclasses.fields(a)]
    unknown = set(merged) - set(names)
    if unknown:
        raise TypeError(f"{type(a).__name__} has no field {sorted(unknown)[0]!r}")
    values = {n: merged[n] if n in merged else getattr(a, n) + getattr(b, n) for n in names}
    return type(a)(**values)
