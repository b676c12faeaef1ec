"""YAML <-> frozen dataclasses: load, dump and write probmap's configuration objects.

Every configuration class of the package (``SubmapSlamConfig``, ``RbpfConfig``,
``MCLConfig``, ...) is a frozen dataclass; this module reads one from YAML and writes one back,
generically, from the field types: nested dataclasses (``SubmapSlamConfig.local``), tuples,
``Literal`` choices, ``X | None``, and ``float``/``int``/``bool``/``str``.

A file lists only the fields it changes; the others keep the class's defaults (a nested
dataclass given in part keeps its other fields from the field's default)::

    submaps:
      scans: 30
    local:
      matcher:
        linear_window: 0.3

:func:`dump_config` writes every field, with two more keys that record where the file came
from: ``probmap_version`` (the package version that wrote it) and ``config_class`` (the class
name). :func:`load_config` accepts both and checks that ``config_class``, when present, names the
class it is asked for. Every problem (unknown key, wrong type, a value the class itself refuses)
is one :class:`ValueError` naming the file and the field::

    cfg.yaml: matcher.linear_window: expected a number, got 'x'

A class whose fields moved into nested sections lists its old keys in a class attribute
``MOVED_KEYS`` (``{"old_key": "section.new_key"}``); a file that still uses one gets an error
naming the new key::

    cfg.yaml: closure_min_score: this key is now closures.min_score

Only PyYAML's safe loader and dumper are used. The module imports nothing of probmap but
:mod:`probmap._atomic`, so every layer may use it.
"""

from __future__ import annotations

import dataclasses
import difflib
import numbers
import os
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from probmap._atomic import atomic_write

__all__ = [
    "VERSION_KEY",
    "CLASS_KEY",
    "dump_config",
    "load_config",
    "package_version",
    "write_config",
]

VERSION_KEY = "probmap_version"
CLASS_KEY = "config_class"

T = TypeVar("T")


def package_version() -> str:
    """The installed probmap version (``"unknown"`` when the package metadata is missing)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("probmap")
    except PackageNotFoundError:  # pragma: no cover - running from a bare source tree
        return "unknown"


# ----------------------------------------------------------------------------- dumping
def _plain(value: Any) -> Any:
    """``value`` as YAML-safe builtins: dataclasses as dicts (field order), tuples as lists,
    numpy scalars as Python numbers."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if value is None or isinstance(value, (bool, str)):
        return value
    if type(value).__name__ == "bool_":  # numpy bool, without importing numpy
        return bool(value)
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return float(value)
    raise TypeError(f"cannot write {type(value).__name__} value {value!r} to YAML")


def dump_config(cfg: Any) -> str:
    """The YAML text of the frozen dataclass ``cfg``: ``probmap_version``, ``config_class``,
    then every field in declaration order (nested dataclasses as mappings, tuples as lists).

    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Demo:
    ...     size: int = 3
    ...     window: tuple[float, float] = (0.5, 0.1)
    >>> print(dump_config(Demo()).split("\\n", 2)[2])  # after the two header keys
    size: 3
    window:
    - 0.5
    - 0.1
    <BLANKLINE>
    """
    if not dataclasses.is_dataclass(cfg) or isinstance(cfg, type):
        raise TypeError(f"expected a dataclass instance, got {type(cfg).__name__}")
    doc = {VERSION_KEY: package_version(), CLASS_KEY: type(cfg).__name__, **_plain(cfg)}
    text: str = yaml.safe_dump(doc, sort_keys=False, default_flow_style=False)
    return text


def write_config(path: str | os.PathLike[str], cfg: Any, *, command: str | None = None) -> Path:
    """Write :func:`dump_config` of ``cfg`` to ``path`` atomically; returns the path.

    ``command`` (the command line that made the outputs, on one line) is recorded on a comment
    line at the top, ``# command: ...``, which loading ignores."""
    text = dump_config(cfg)
    if command is not None:
        one_line = command.replace("\r", "\\r").replace("\n", "\\n")
        text = f"# command: {one_line}\n" + text
    with atomic_write(path, "w", encoding="utf-8") as f:
        f.write(text)
    return Path(path)


# ----------------------------------------------------------------------------- loading
class _Bad(Exception):
    """A problem at ``where`` (a dotted field path, possibly empty)."""

    def __init__(self, where: str, message: str) -> None:
        super().__init__(message)
        self.where = where
        self.message = message


def _join(where: str, name: str) -> str:
    return f"{where}.{name}" if where else name


def _show(value: Any) -> str:
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return repr(value)


def _hints(cls: type) -> dict[str, Any]:
    try:
        return typing.get_type_hints(cls)
    except Exception:  # pragma: no cover - an annotation that does not resolve
        return {f.name: f.type for f in dataclasses.fields(cls)}


def _convert(tp: Any, value: Any, where: str, default: Any = dataclasses.MISSING) -> Any:
    """``value`` (from YAML) as type ``tp``, or :class:`_Bad`."""
    if tp is Any or tp is object:
        return value
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is typing.Union or (hasattr(types, "UnionType") and origin is types.UnionType):
        if value is None:
            if type(None) in args:
                return None
            raise _Bad(where, "expected a value, got null")
        options = [a for a in args if a is not type(None)]
        errors = []
        for a in options:
            try:
                return _convert(a, value, where, default)
            except _Bad as exc:
                errors.append(exc)
        if len(errors) == 1:
            raise errors[0]
        raise _Bad(where, f"expected {' or '.join(_name(a) for a in options)}, got {_show(value)}")
    if origin is typing.Literal:
        if any(value == a and type(value) is type(a) for a in args):
            return value
        raise _Bad(where, f"expected one of {', '.join(map(repr, args))}, got {_show(value)}")
    if origin is tuple or tp is tuple:
        if not isinstance(value, list):
            raise _Bad(where, f"expected a list, got {_show(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            items = [args[0]] * len(value)
        elif args:
            items = list(args)
            if len(value) != len(items):
                raise _Bad(where, f"expected a list of {len(items)} values, got {len(value)}")
        else:
            items = [Any] * len(value)
        return tuple(
            _convert(a, v, f"{where}[{i}]")
            for i, (a, v) in enumerate(zip(items, value, strict=True))
        )
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise _Bad(where, f"expected a mapping of {tp.__name__} fields, got {_show(value)}")
        base = default if dataclasses.is_dataclass(default) and isinstance(default, tp) else None
        return _build(tp, value, where, base)
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise _Bad(where, f"expected true or false, got {_show(value)}")
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise _Bad(where, f"expected an integer, got {_show(value)}")
    if tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        if isinstance(value, str):  # YAML 1.1 reads 1e-6 (no dot) as a string
            try:
                return float(value)
            except ValueError:
                pass
        raise _Bad(where, f"expected a number, got {_show(value)}")
    if tp is str:
        if isinstance(value, str):
            return value
        raise _Bad(where, f"expected a string, got {_show(value)}")
    if tp is type(None):
        if value is None:
            return None
        raise _Bad(where, f"expected null, got {_show(value)}")
    return value  # a type this module does not know: the class's __post_init__ checks it


def _name(tp: Any) -> str:
    if tp is float:
        return "a number"
    if tp is int:
        return "an integer"
    if tp is bool:
        return "true or false"
    if tp is str:
        return "a string"
    if typing.get_origin(tp) is tuple or tp is tuple:
        return "a list"
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return f"a mapping of {tp.__name__} fields"
    return str(tp)


def _field_default(f: dataclasses.Field[Any]) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def _build(cls: type[T], data: Mapping[Any, Any], where: str, base: Any = None) -> T:
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    hints = _hints(cls)
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if not isinstance(key, str) or key not in fields:
            moved = getattr(cls, "MOVED_KEYS", {}).get(key)
            if moved is not None:  # a key of an earlier, flat layout of this class
                raise _Bad(_join(where, str(key)), f"this key is now {moved}")
            close = difflib.get_close_matches(str(key), list(fields), n=1)
            hint = f" (did you mean {close[0]}?)" if close else ""
            raise _Bad(_join(where, str(key)), f"unknown field of {cls.__name__}{hint}")
        f = fields[key]
        default = getattr(base, key) if base is not None else _field_default(f)
        kwargs[key] = _convert(hints.get(key, Any), value, _join(where, key), default)
    try:
        if base is not None:
            return dataclasses.replace(base, **kwargs)  # type: ignore[no-any-return]
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        raise _Bad(where, str(exc) or type(exc).__name__) from None


def _read(path_or_text: str | os.PathLike[str]) -> tuple[str, str]:
    """(source name, YAML text)."""
    if isinstance(path_or_text, os.PathLike) or (
        "\n" not in path_or_text
        and (path_or_text.endswith((".yaml", ".yml")) or Path(path_or_text).is_file())
    ):
        path = Path(path_or_text)
        try:
            return str(path), path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise FileNotFoundError(2, f"{path}: no such file", str(path)) from None
        except UnicodeDecodeError:
            raise ValueError(f"{path}: not a UTF-8 text file") from None
    return "<config>", path_or_text


def load_config(
    cls: type[T], path_or_text: str | os.PathLike[str], *, source: str | None = None
) -> T:
    """Read a ``cls`` (a frozen dataclass) from a YAML file or YAML text.

    Parameters
    ----------
    cls : type
        The configuration class.
    path_or_text : path-like or str
        A path (a :class:`~pathlib.Path`, or a one-line string ending in ``.yaml``/``.yml`` or
        naming an existing file) or the YAML text itself.
    source : str, optional
        The name errors use for text (default ``<config>``; a file's path otherwise).

    Returns
    -------
    cls
        Fields the YAML leaves out keep their defaults. An empty file gives ``cls()``.

    Raises
    ------
    ValueError
        One line naming the file and the field: invalid YAML, a top level that is not a mapping,
        an unknown field, a value of the wrong type, a ``config_class`` naming another class, or
        a value ``cls`` itself refuses.
    FileNotFoundError
        No such file.

    >>> from probmap.slam.laser.scan_matching import MatcherConfig
    >>> load_config(MatcherConfig, "linear_window: 0.3\\n").linear_window
    0.3
    >>> load_config(MatcherConfig, "linear_window: x\\n", source="cfg.yaml")
    Traceback (most recent call last):
    ...
    ValueError: cfg.yaml: linear_window: expected a number, got 'x'
    """
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise TypeError(f"expected a dataclass type, got {cls!r}")
    name, text = _read(path_or_text)
    name = source or name
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or type(exc).__name__
        at = f"line {mark.line + 1}: " if mark is not None else ""
        raise ValueError(f"{name}: {at}not valid YAML ({problem})") from None
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ValueError(f"{name}: expected a mapping of {cls.__name__} fields, got {_show(data)}")
    data = dict(data)
    version = data.pop(VERSION_KEY, None)
    if version is not None and not isinstance(version, (str, int, float)):
        raise ValueError(f"{name}: {VERSION_KEY}: expected a version string, got {_show(version)}")
    recorded = data.pop(CLASS_KEY, None)
    if recorded is not None and recorded != cls.__name__:
        raise ValueError(
            f"{name}: {CLASS_KEY}: expected {cls.__name__}, got {recorded!r} (a file for another "
            "command?)"
        )
    try:
        return _build(cls, data, "")
    except _Bad as exc:
        at = f"{exc.where}: " if exc.where else ""
        raise ValueError(f"{name}: {at}{exc.message}") from None
