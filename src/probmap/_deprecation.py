"""One-release deprecation shims for names that moved to another module.

A core module whose pipeline moved to :mod:`probmap.pipelines` keeps its old names for one release
through a module ``__getattr__`` made by :func:`moved`: the new home is imported only when an old
name is looked up (never when the core module is imported), and every lookup warns with a
:class:`DeprecationWarning` that names the new path.  The new homes are given as strings and
imported with :func:`importlib.import_module`, so the import-rule test
(``tests/test_import_graph.py``) sees no ``import`` statement from the core into
``pipelines``; it finds the shims by their call to :func:`moved` instead and checks that they
point only at modules that exist and define the names.
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["moved"]


def moved(old_module: str, homes: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` that forwards the names in ``homes`` to their new modules.

    Parameters
    ----------
    old_module : str
        The module the names used to live in (its ``__name__``), for the messages.
    homes : mapping of str to str
        ``{name: new module}``, both written out as strings.

    Returns
    -------
    callable
        ``__getattr__(name)``: the object from its new module, with a ``DeprecationWarning``;
        ``AttributeError`` for any other name.

    Examples
    --------
    >>> import warnings
    >>> __getattr__ = moved("probmap.old", {"GridSpec": "probmap.grid.spec"})
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     cls = __getattr__("GridSpec")
    >>> cls.__module__, caught[0].category.__name__
    ('probmap.grid.spec', 'DeprecationWarning')
    """
    table = dict(homes)

    def __getattr__(name: str) -> Any:
        new = table.get(name)
        if new is None:
            raise AttributeError(f"module {old_module!r} has no attribute {name!r}")
        warnings.warn(
            f"{old_module}.{name} has moved to {new}.{name}; "
            f"the old path will be removed in the next release",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(importlib.import_module(new), name)

    return __getattr__
