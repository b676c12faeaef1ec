"""Log-odds helpers for the binary Bayes filter (Probabilistic Robotics, Table 4.2, eq. 4.8-4.9)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


def logit(p: ArrayLike) -> NDArray[np.float64] | float:
    """Log odds ``l = log(p / (1 - p))`` of a probability.

    Parameters
    ----------
    p : float or array_like
        Probabilities in the open interval (0, 1).

    Returns
    -------
    float or ndarray
        The log odds, same shape as ``p``.

    Raises
    ------
    ValueError
        If any probability lies outside (0, 1).

    Examples
    --------
    >>> round(logit(0.5), 6)
    0.0
    >>> round(float(logit(0.7)), 4)
    0.8473
    """
    arr = np.asarray(p, dtype=np.float64)
    if not np.all((arr > 0.0) & (arr < 1.0)):
        raise ValueError(f"probabilities must lie in (0, 1), got {p!r}")
    out = np.log(arr) - np.log1p(-arr)
    return float(out) if out.ndim == 0 else out


def prob(l: ArrayLike) -> NDArray[np.float64] | float:
    """Probability from log odds, ``p = 1 - 1 / (1 + exp(l))`` (Table 4.2, line 7 of the book's text).

    Evaluated in the algebraically equal form ``1 / (1 + exp(-l))`` for ``l >= 0`` and
    ``exp(l) / (1 + exp(l))`` for ``l < 0`` so that no ``exp`` overflows for large ``|l|``.

    Examples
    --------
    >>> prob(0.0)
    0.5
    >>> round(prob(logit(0.97)), 12)
    0.97
    >>> float(prob(1000.0)), float(prob(-1000.0))
    (1.0, 0.0)
    """
    arr = np.asarray(l, dtype=np.float64)
    e = np.exp(-np.abs(arr))
    out = np.where(arr >= 0.0, 1.0 / (1.0 + e), e / (1.0 + e))
    return float(out) if out.ndim == 0 else out
