"""The exceptions and warnings that probmap raises, in one place.

Every class keeps its old import path too (``probmap.datasets.protocol.DatasetError``,
``probmap.grid.io.MapFileError`` ...): those modules re-export the names from here.  This module
imports nothing from the package, so any layer may import it.

Exceptions that belong to one layer stay there: :class:`probmap.cli.common.CliError` (the CLI's
one-line errors) and
:class:`probmap.pipelines.distributed.DistributedMappingError` (it carries that
pipeline's partial result).
"""

from __future__ import annotations

__all__ = [
    "BadLinesWarning",
    "BagError",
    "DatasetError",
    "GridBoundsError",
    "MapFileError",
    "MissingExtraError",
    "ParticleFilterWarning",
    "SemanticFileError",
    "SingularInformationError",
    "error_message",
]


def error_message(exc: BaseException) -> str:
    """An error's message on one line as probmap reports it: ``str(exc)`` (the class name when
    that is empty), with the file name of an :class:`OSError` in front unless the message
    names it already. The CLI's one-line errors and the distributed pipeline's failed inputs
    both read so.

    Examples
    --------
    >>> error_message(FileNotFoundError(2, "No such file", "a.log"))
    "[Errno 2] No such file: 'a.log'"
    >>> error_message(KeyError())
    'KeyError'
    """
    msg = str(exc) or exc.__class__.__name__
    if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in msg:
        msg = f"{exc.filename}: {msg}"
    return msg


# --------------------------------------------------------------------------------- input data
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


class BagError(DatasetError):
    """A bag that cannot be read or used: names the file and the topic, frame or time.

    The message stays on one line: topic and frame names come from the bag, and a line break
    or other control character among them is written as its escape (``\\n``).

    >>> str(BagError("no frame a\\nb", path="x.bag"))
    'x.bag: no frame a\\\\nb'
    """

    def __init__(
        self,
        message: str,
        *,
        path: object | None = None,
        line: int | None = None,
        field: str | None = None,
    ) -> None:
        message = "".join(c if c.isprintable() else repr(c)[1:-1] for c in message)
        super().__init__(message, path=path, line=line, field=field)


class NoPoseSourceError(BagError):
    """A bag with neither tf links nor odometry into the laser frame ``laser_frame``: its scans
    can only be read in the laser's own frame (every pose the same), as lidar-only SLAM does."""

    def __init__(self, message: str, *, path: object = None, laser_frame: str = "") -> None:
        super().__init__(message, path=path)
        self.laser_frame = laser_frame


class MapFileError(DatasetError):
    """A malformed or inconsistent map file; the message names the file and field."""


class SemanticFileError(DatasetError):
    """A malformed semantic map or labelled scan file; the message names the file and key."""


class MissingExtraError(ImportError):
    """An optional dependency is not installed; the message names the extra to install
    (``pip install 'probmap[ros]'``). The CLI reports it on one line."""


class BadLinesWarning(UserWarning):
    """Malformed lines were skipped (``skip_bad_lines=True``)."""


# --------------------------------------------------------------------------------- estimators
class GridBoundsError(ValueError):
    """A scan or pose falls outside a fixed-bounds grid, or a grid would grow past its limit."""


class SingularInformationError(ValueError):
    """An information block is singular or indefinite; the update was rejected, state unchanged."""


class ParticleFilterWarning(UserWarning):
    """The filter hit a degenerate case (e.g. every particle impossible) and recovered."""
