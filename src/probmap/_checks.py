"""The argument checks that configs and constructors of every layer share, one copy each.

Each check raises :class:`ValueError` with the one-line message the package has always given
for that kind of bad value (``"beam_skip must be >= 1, got 0"``), naming the argument or field.
A NaN fails every check: no comparison with NaN is true, and each check asks for the good case
(``not value >= low``), so a NaN never slips through as "not too small".

This module imports only the standard library, so that any layer may import it.
"""

from __future__ import annotations

import math
import numbers

__all__ = [
    "is_finite_number",
    "require_at_least",
    "require_integer",
    "require_nonnegative_finite",
    "require_positive_finite",
]


def is_finite_number(value: object) -> bool:
    """Whether ``value`` is a real, finite number: anything ``float()`` takes (a numpy scalar, a
    0-d array) but a bool, NaN, an infinity or what ``float()`` refuses.

    Examples
    --------
    >>> [is_finite_number(v) for v in (2, 0.5, float("nan"), True, "x", None)]
    [True, True, False, False, False, False]
    """
    try:
        return not isinstance(value, bool) and math.isfinite(float(value))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False


def require_positive_finite(name: str, value: float) -> None:
    """Raise unless ``value`` is a finite number > 0.

    Parameters
    ----------
    name : str
        The argument or field, for the message.
    value : float
        The value to check (a length in metres, a standard deviation, a step ...).

    Raises
    ------
    ValueError
        ``"{name} must be a positive number, got {value}"``.

    Examples
    --------
    >>> require_positive_finite("sigma", 0.05)
    >>> require_positive_finite("sigma", float("inf"))
    Traceback (most recent call last):
    ...
    ValueError: sigma must be a positive number, got inf
    """
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number, got {value}")


def require_nonnegative_finite(name: str, value: float) -> None:
    """Raise ``ValueError("{name} must be >= 0, got {value}")`` unless ``value`` is a finite
    number >= 0 (a window, a tolerance); the arguments are those of
    :func:`require_positive_finite`."""
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be >= 0, got {value}")


def require_at_least(name: str, value: float, low: float, unit: str = "") -> None:
    """Raise unless ``value >= low`` (infinity passes; NaN does not).

    Parameters
    ----------
    name : str
        The argument or field, for the message.
    value : float
        The value to check: a count (``low`` 1), a number of retries (``low`` 0), a time ...
    low : float
        The smallest value allowed; write it as the message should show it (``1``, not ``1.0``).
    unit : str, optional
        Appended to ``low`` in the message with a space (``"s"``: ``">= 0 s"``).

    Raises
    ------
    ValueError
        ``"{name} must be >= {low}, got {value}"`` (``">= {low} {unit}"`` with a unit).

    Examples
    --------
    >>> require_at_least("workers", 4, 1)
    >>> require_at_least("interval", -1.0, 0, "s")
    Traceback (most recent call last):
    ...
    ValueError: interval must be >= 0 s, got -1.0
    """
    if not value >= low:
        bound = f"{low} {unit}" if unit else f"{low}"
        raise ValueError(f"{name} must be >= {bound}, got {value}")


def require_integer(name: str, value: object, low: int) -> None:
    """Raise unless ``value`` is an integer (Python or numpy, not a bool) ``>= low``.

    Parameters
    ----------
    name : str
        The argument or field, for the message.
    value : object
        The value to check: a count of iterations, rounds, observations, pixels ...
    low : int
        The smallest value allowed.

    Raises
    ------
    ValueError
        ``"{name} must be an integer >= {low}, got {value!r}"`` (a float such as ``3.0``, a
        bool or a string is refused too: a count is not a length).

    Examples
    --------
    >>> require_integer("max_misses", 3, 0)
    >>> require_integer("min_observations", 2.0, 1)
    Traceback (most recent call last):
    ...
    ValueError: min_observations must be an integer >= 1, got 2.0
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or int(value) < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
