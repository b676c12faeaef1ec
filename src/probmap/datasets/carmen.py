"""Reader for CARMEN laser logs (``.clf``/``.log``; plain, gzip or bzip2).

A CARMEN log holds one message per line, fields separated by whitespace::

    ODOM x y theta tv rv accel  ipc_timestamp ipc_hostname logger_timestamp
    FLASER n r_1 ... r_n  x y theta  odom_x odom_y odom_theta  ipc_timestamp ipc_hostname logger_timestamp
    RLASER (as FLASER, for the rear laser)
    ROBOTLASER1 laser_type start_angle fov angular_res max_range accuracy remission_mode n r_1 ... r_n
                n_remissions [remissions]  laser_x laser_y laser_theta  robot_x robot_y robot_theta
                tv rv forward_safety_dist side_safety_dist turn_axis  ipc_timestamp ipc_hostname logger_timestamp
    PARAM name value [ipc_hostname timestamp]
    # comment

``NEFF``, ``SYNC``, ``TRUEPOS`` and any other message type are recognised and skipped. In
``FLASER``/``RLASER`` the ``x y theta`` fields are the **laser** pose and ``odom_*`` the **robot**
pose, both in the log's world frame (raw odometry in a raw log, SLAM estimates in a corrected log).

Readings are classified as every reader does (:mod:`probmap.datasets.validate`): "no return"
is a reading at or beyond the maximum range (81.83-81.91 m in the SICK logs) or ``+inf``; zero,
negative, ``-inf`` and NaN readings are invalid, dropped and counted by :func:`load_scans`.
Poses beyond :class:`~probmap.datasets.validate.PoseLimits` (a coordinate beyond 100 km, a jump
of more than 10 m + 20 m/s between two messages of one type) make a bad line, as a malformed
field does.

The reader streams: the file is decompressed and parsed line by line, so memory stays at the size
of the records kept by the caller. Compression is detected from the file's magic bytes, not its
name.
"""

from __future__ import annotations

import bz2
import gzip
import io
import math
import os
import warnings
import zlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import IO, TYPE_CHECKING, TypedDict

import numpy as np
from numpy.typing import NDArray

from probmap._checks import require_at_least
from probmap.datasets.records import LaserScan, Odometry, ScanBatch, stack_beams
from probmap.datasets.validate import PoseLimits, PoseTracker, infer_no_return, validate_ranges
from probmap.errors import BadLinesWarning, DatasetError

if TYPE_CHECKING:
    from typing_extensions import Unpack

__all__ = [
    "DEFAULT_MAX_RANGE",
    "BadLinesWarning",
    "CarmenLog",
    "CarmenLogOptions",
    "PoseLimits",
    "default_angle_step",
    "detect_compression",
    "load_scans",
    "open_log",
]

#: Readings at or beyond this many metres are "no return" when the log states no maximum range
#: (the SICK LMS logs report 81.83-81.91 m for no return; real returns stay below 80 m).
DEFAULT_MAX_RANGE = 80.0

LASER_TYPES = ("FLASER", "RLASER", "ROBOTLASER1")
_POSE_FIELDS = ("x", "y", "theta", "odom_x", "odom_y", "odom_theta")
_ODOM_FIELDS = ("x", "y", "theta", "tv", "rv")
_RL1_POSE_FIELDS = ("laser_x", "laser_y", "laser_theta", "robot_x", "robot_y", "robot_theta")
# PARAM values the reader itself uses: checked as numbers when the PARAM line is read.
_NUMERIC_PARAMS = (
    "laser_front_laser_max",
    "robot_front_laser_max",
    "laser_rear_laser_max",
    "robot_rear_laser_max",
    "robot_frontlaser_offset",
    "robot_rearlaser_offset",
)


class _LineError(Exception):
    """A malformed line; turned into a :class:`DatasetError` with the file and line number."""

    def __init__(self, message: str, field: str | None = None, what: str = "malformed") -> None:
        super().__init__(message)
        self.field = field
        self.what = what  # "malformed", or "implausible" for a pose beyond PoseLimits


# ---------------------------------------------------------------------------- files


def detect_compression(path: str | os.PathLike[str]) -> str:
    """``"gzip"``, ``"bz2"`` or ``"plain"``, from the file's first bytes (not its name).

    Raises
    ------
    FileNotFoundError
        If the file does not exist (the message names it).
    """
    p = Path(path)
    try:
        with open(p, "rb") as f:
            head = f.read(3)
    except FileNotFoundError:
        raise FileNotFoundError(2, f"{p}: no such file", str(p)) from None
    if head[:2] == b"\x1f\x8b":
        return "gzip"
    if head == b"BZh":
        return "bz2"
    return "plain"


def open_log(path: str | os.PathLike[str]) -> IO[str]:
    """Open a (possibly compressed) text log for reading, decoding bytes as Latin-1.

    Latin-1 maps every byte to a character, so a stray byte never raises a decoding error; it
    fails as a malformed field instead, with its line number.
    """
    p = Path(path)
    kind = detect_compression(p)
    raw: io.BufferedIOBase
    if kind == "gzip":
        raw = gzip.open(p, "rb")
    elif kind == "bz2":
        raw = bz2.open(p, "rb")
    else:
        raw = open(p, "rb")
    return io.TextIOWrapper(raw, encoding="latin-1", newline=None)


def _numbered_lines(path: Path) -> Iterator[tuple[int, str]]:
    """``(line_number, text)`` of every line, with decompression errors named by file."""
    kind = detect_compression(path)
    with open_log(path) as f:
        lineno = 0
        try:
            for lineno, line in enumerate(f, start=1):  # noqa: B007 - lineno used after the loop
                yield lineno, line
        except (EOFError, OSError, zlib.error) as exc:
            what = "truncated or corrupt" if kind != "plain" else "unreadable"
            raise DatasetError(
                f"{what} {kind} data after line {lineno} ({exc})", path=path
            ) from None


# ---------------------------------------------------------------------------- fields


def default_angle_step(n: int) -> float:
    """Beam spacing in radians of an ``n``-beam laser whose angles the message does not state.

    The CARMEN convention is a 180 degree field of view starting at -90 degrees:

    - an even count (180, 360) covers ``[-90, +90)`` degrees: step ``pi / n`` (1 and 0.5 degrees);
    - an odd count (181, 361) includes both ends ``[-90, +90]``: step ``pi / (n - 1)``.

    >>> round(math.degrees(default_angle_step(180)), 6), round(math.degrees(default_angle_step(361)), 6)
    (1.0, 0.5)
    """
    if n <= 1:
        return math.pi
    return math.pi / (n - 1) if n % 2 else math.pi / n


def _int_field(fields: Sequence[str], i: int, name: str) -> int:
    if i >= len(fields):
        raise _LineError(f"line ends before the {name} field", name)
    try:
        v = int(fields[i])
    except ValueError:
        raise _LineError(f"expected an integer, got {fields[i]!r}", name) from None
    if v < 0:
        raise _LineError(f"must not be negative, got {v}", name)
    return v


def _float_field(fields: Sequence[str], i: int, name: str) -> float:
    try:
        return float(fields[i])
    except ValueError:
        raise _LineError(f"expected a number, got {fields[i]!r}", name) from None


def _float_fields(
    fields: Sequence[str], start: int, stop: int, name_of: Callable[[int], str]
) -> NDArray[np.float64]:
    """Fields ``start:stop`` as float64 (parsed by numpy in C); on failure, name the bad field.

    ``name_of(k)`` names field ``start + k``.
    """
    try:
        return np.array(fields[start:stop], dtype=np.float64)
    except ValueError:
        for k in range(start, stop):
            _float_field(fields, k, name_of(k - start))
        raise  # pragma: no cover - float() and numpy accept the same numbers


def _check_finite(
    values: list[float], fields: Sequence[str], start: int, names: Sequence[str]
) -> None:
    """Raise naming the first non-finite value (poses must be finite; ranges may be NaN)."""
    for k, v in enumerate(values):
        if not math.isfinite(v):
            raise _LineError(f"must be finite, got {fields[start + k]!r}", names[k])


def _names(n: int, tail: Sequence[str]) -> Callable[[int], str]:
    """Names of ``n`` range fields followed by ``tail``."""
    return lambda k: f"range[{k}]" if k < n else tail[k - n]


def _check_count(fields: Sequence[str], expected: int, what: str) -> None:
    if len(fields) != expected:
        raise _LineError(f"{what}: expected {expected} fields, found {len(fields)}")


# ---------------------------------------------------------------------------- reader


@dataclass
class _PassState:
    params: dict[str, str]
    skipped: int = 0
    first_error: str = ""
    scans: int = 0
    odometry: int = 0
    messages: int = 0
    neff: int = 0  # GMapping's NEFF lines: the log is its corrected output


class CarmenLogOptions(TypedDict, total=False):
    """The keywords of :class:`CarmenLog` (their defaults and meaning are documented there),
    which :func:`load_scans` and :func:`load_share` hand on to it."""

    start_angle: float
    angle_step: float | None
    max_range: float | None
    skip_bad_lines: bool
    pose_limits: PoseLimits | None


class CarmenLog:
    """A CARMEN laser log as a :class:`~probmap.datasets.protocol.Dataset` of laser scans.

    Parameters
    ----------
    path : path-like
        The log: plain text, gzip or bzip2 (detected from the magic bytes).
    start_angle : float
        Bearing in radians (laser frame) of the first beam of ``FLASER``/``RLASER`` messages,
        which do not state it. Default ``-pi/2`` (the robot's right). ``ROBOTLASER1`` messages
        state their own angles, which are always used.
    angle_step : float or None
        Beam spacing in radians for ``FLASER``/``RLASER``; None applies
        :func:`default_angle_step` (``pi/n`` for 180 and 360 beams, ``pi/(n-1)`` for 181 and 361).
    max_range : float or None
        Maximum range in metres: readings at or beyond it are "no return". None takes, per scan,
        the ``ROBOTLASER1`` message's own value, else the PARAM ``laser_front_laser_max`` or
        ``robot_front_laser_max`` (``..._rear_...`` for ``RLASER``) read so far, else
        :data:`DEFAULT_MAX_RANGE` (80 m).
    skip_bad_lines : bool
        Skip malformed lines, count them in :attr:`skipped_lines` and warn once per pass
        (:class:`BadLinesWarning`), instead of raising :class:`DatasetError`.
    pose_limits : PoseLimits or None
        Physical limits on the logged poses (coordinates, and the increment from the previous
        pose of the same message type and pose field); a pose beyond them makes a bad line
        (see :mod:`probmap.datasets.validate`). None: the generous defaults of
        :class:`PoseLimits`.

    Notes
    -----
    Iterating yields :class:`~probmap.datasets.records.LaserScan` records in file order;
    :meth:`odometry` yields ``ODOM`` records and :meth:`records` both, interleaved as logged.
    PARAM lines apply to the scans after them (CARMEN writes them at the top of a log).

    Raises
    ------
    FileNotFoundError
        When the file does not exist.
    DatasetError
        (While reading) a malformed line, naming the file, line and field; an empty log; a
        truncated or corrupt compressed file; a log without laser scans.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        start_angle: float = -math.pi / 2,
        angle_step: float | None = None,
        max_range: float | None = None,
        skip_bad_lines: bool = False,
        pose_limits: PoseLimits | None = None,
    ) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            if self.path.exists():
                raise IsADirectoryError(21, f"{self.path}: not a file", str(self.path))
            raise FileNotFoundError(2, f"{self.path}: no such file", str(self.path))
        if not math.isfinite(start_angle):
            raise ValueError(f"start_angle must be finite, got {start_angle}")
        if angle_step is not None and not (math.isfinite(angle_step) and angle_step != 0.0):
            raise ValueError(f"angle_step must be a finite non-zero number, got {angle_step}")
        if max_range is not None and not (math.isfinite(max_range) and max_range > 0.0):
            raise ValueError(f"max_range must be a positive number of metres, got {max_range}")
        self.start_angle = float(start_angle)
        self.angle_step = None if angle_step is None else float(angle_step)
        self.max_range = None if max_range is None else float(max_range)
        self.skip_bad_lines = bool(skip_bad_lines)
        if pose_limits is not None and not isinstance(pose_limits, PoseLimits):
            raise TypeError(f"pose_limits must be a PoseLimits, got {type(pose_limits).__name__}")
        self.pose_limits = pose_limits if pose_limits is not None else PoseLimits()
        self.name = _dataset_name(self.path)
        self._angles: dict[tuple[int, float, float], NDArray[np.float64]] = {}
        self._done: _PassState | None = None
        # a share of the log's lines already read (see _text_share): text, first line number,
        # PARAMs logged before it
        self._share: tuple[str, int, dict[str, str]] | None = None
        # set when a scan fell back on DEFAULT_MAX_RANGE: the log states no maximum range
        self.max_range_defaulted = False

    # ------------------------------------------------------------------ protocol
    def __len__(self) -> int:
        """Number of laser scans (one counting pass over the file, then cached)."""
        if self._done is None:
            for _ in self._read(scans=True, odometry=False):
                pass
        assert self._done is not None
        if self._done.scans == 0:
            raise DatasetError(
                "no laser scans (FLASER, RLASER or ROBOTLASER1 lines) in the log", path=self.path
            )
        return self._done.scans

    def __iter__(self) -> Iterator[LaserScan]:
        for rec in self._read(scans=True, odometry=False):
            assert isinstance(rec, LaserScan)
            yield rec

    def __repr__(self) -> str:
        return f"CarmenLog({str(self.path)!r})"

    def odometry(self) -> Iterator[Odometry]:
        """``ODOM`` messages in file order."""
        for rec in self._read(scans=False, odometry=True):
            assert isinstance(rec, Odometry)
            yield rec

    def records(self) -> Iterator[LaserScan | Odometry]:
        """Laser scans and odometry interleaved in file order."""
        return self._read(scans=True, odometry=True)

    @property
    def params(self) -> dict[str, str]:
        """``PARAM name value`` pairs of the whole log (values as logged, strings)."""
        if self._done is None:
            for _ in self._read(scans=False, odometry=False):
                pass
        assert self._done is not None
        return dict(self._done.params)

    @property
    def skipped_lines(self) -> int:
        """Malformed lines skipped during the last complete pass (0 before any pass)."""
        return 0 if self._done is None else self._done.skipped

    # ------------------------------------------------------------------ parsing
    def _lines(self) -> Iterator[tuple[int, str]]:
        if self._share is None:
            return _numbered_lines(self.path)
        text, first, _ = self._share
        # the text was read through the same newline translation: "\n" ends every line
        return enumerate(text.split("\n"), start=first)

    def _read(self, *, scans: bool, odometry: bool) -> Iterator[LaserScan | Odometry]:
        state = _PassState(params={} if self._share is None else dict(self._share[2]))
        tracker = PoseTracker(self.pose_limits)
        for lineno, line in self._lines():
            fields = line.split()
            if not fields:
                continue
            state.messages += 1
            kind = fields[0]
            if kind[0] == "#":
                continue
            try:
                if kind == "FLASER" or kind == "RLASER":
                    scan = self._parse_flaser(fields, lineno, state.params)
                    _check_poses(tracker, kind, scan.time, scan, _POSE_FIELDS)
                    state.scans += 1
                    if scans:
                        yield scan
                elif kind == "ODOM":
                    # validated in every pass, built only when asked for
                    odo = self._parse_odom(fields, lineno, odometry, tracker)
                    state.odometry += 1
                    if odo is not None:
                        yield odo
                elif kind == "ROBOTLASER1":
                    scan = self._parse_robotlaser(fields, lineno)
                    _check_poses(tracker, kind, scan.time, scan, _RL1_POSE_FIELDS)
                    state.scans += 1
                    if scans:
                        yield scan
                elif kind == "PARAM":
                    self._parse_param(fields, state.params)
                elif kind == "NEFF":
                    state.neff += 1
            except _LineError as exc:
                if not self.skip_bad_lines:
                    raise DatasetError(
                        f"{exc.what} {kind} line: {exc}",
                        path=self.path,
                        line=lineno,
                        field=exc.field,
                    ) from None
                state.skipped += 1
                if not state.first_error:
                    state.first_error = f"line {lineno}: {exc.what} {kind} line: {exc}"
        if state.messages == 0 and self._share is None:
            raise DatasetError("empty log (no messages)", path=self.path)
        if state.skipped:
            warnings.warn(
                f"{self.path}: skipped {state.skipped} bad (malformed or implausible) "
                f"line(s); first at {state.first_error}",
                BadLinesWarning,
                stacklevel=3,
            )
        self._done = state
        if scans and state.scans == 0 and self._share is None:
            raise DatasetError(
                "no laser scans (FLASER, RLASER or ROBOTLASER1 lines) in the log", path=self.path
            )

    def _beam_angles(self, n: int, start: float, step: float) -> NDArray[np.float64]:
        key = (n, start, step)
        a = self._angles.get(key)
        if a is None:
            if len(self._angles) >= 64:  # a log whose every message has its own geometry
                self._angles.clear()
            a = start + step * np.arange(n, dtype=np.float64)
            a.flags.writeable = False
            self._angles[key] = a
        return a

    def _resolve_max_range(self, kind: str, params: dict[str, str]) -> float:
        if self.max_range is not None:
            return self.max_range
        side = "rear" if kind == "RLASER" else "front"
        for name in (f"laser_{side}_laser_max", f"robot_{side}_laser_max"):
            v = params.get(name)
            if v is not None:
                return float(v)
        self.max_range_defaulted = True
        return DEFAULT_MAX_RANGE

    def _parse_flaser(self, f: list[str], lineno: int, params: dict[str, str]) -> LaserScan:
        n = _int_field(f, 1, "num_readings")
        _check_count(f, n + 11, f"{f[0]} with {n} readings")
        values = _float_fields(f, 2, n + 8, _names(n, _POSE_FIELDS))
        ranges = values[:n]
        poses = values[n:]
        _check_finite(poses.tolist(), f, n + 2, _POSE_FIELDS)
        ipc = _float_field(f, n + 8, "ipc_timestamp")
        logger = _float_field(f, n + 10, "logger_timestamp")
        step = self.angle_step if self.angle_step is not None else default_angle_step(n)
        return LaserScan(
            time=ipc,
            ranges=ranges,
            angles=self._beam_angles(n, self.start_angle, step),
            laser_pose=poses[:3],
            robot_pose=poses[3:],
            max_range=self._resolve_max_range(f[0], params),
            logger_time=logger,
            source=f[0],
            line=lineno,
        )

    def _parse_robotlaser(self, f: list[str], lineno: int) -> LaserScan:
        n = _int_field(f, 8, "num_readings")
        n_rem = _int_field(f, 9 + n, "num_remissions")
        _check_count(f, n + n_rem + 24, f"ROBOTLASER1 with {n} readings and {n_rem} remissions")
        start = _float_field(f, 2, "start_angle")
        res = _float_field(f, 4, "angular_resolution")
        if not (math.isfinite(start) and math.isfinite(res)):
            raise _LineError("start_angle and angular_resolution must be finite", "start_angle")
        if res == 0.0 and n > 1:
            raise _LineError(
                f"must not be 0 with {n} readings (every beam would lie on one ray)",
                "angular_resolution",
            )
        msg_max = _float_field(f, 5, "maximum_range")
        ranges = _float_fields(f, 9, 9 + n, _names(n, ()))
        k = 10 + n + n_rem
        poses = _float_fields(f, k, k + 6, _names(0, _RL1_POSE_FIELDS))
        _check_finite(poses.tolist(), f, k, _RL1_POSE_FIELDS)
        ipc = _float_field(f, k + 11, "ipc_timestamp")
        logger = _float_field(f, k + 13, "logger_timestamp")
        if self.max_range is not None:
            max_range = self.max_range
        elif math.isfinite(msg_max) and msg_max > 0.0:
            max_range = msg_max
        else:
            max_range = DEFAULT_MAX_RANGE
            self.max_range_defaulted = True
        return LaserScan(
            time=ipc,
            ranges=ranges,
            angles=self._beam_angles(n, start, res),
            laser_pose=poses[:3],
            robot_pose=poses[3:],
            max_range=max_range,
            logger_time=logger,
            source="ROBOTLASER1",
            line=lineno,
        )

    @staticmethod
    def _parse_odom(
        f: list[str], lineno: int, build: bool, tracker: PoseTracker | None = None
    ) -> Odometry | None:
        if len(f) != 10:
            _check_count(f, 10, "ODOM")
        try:
            x, y, th = float(f[1]), float(f[2]), float(f[3])
            tv, rv, _ = float(f[4]), float(f[5]), float(f[6])
            ipc, logger = float(f[7]), float(f[9])
        except ValueError:
            names = (*_ODOM_FIELDS, "accel", "ipc_timestamp")
            for k, name in enumerate(names):
                _float_field(f, k + 1, name)
            _float_field(f, 9, "logger_timestamp")
            raise  # pragma: no cover
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(th)):
            _check_finite([x, y, th], f, 1, _ODOM_FIELDS)
        if tracker is not None:
            bad = tracker.check("ODOM pose", ipc, x, y, th)
            if bad is not None:
                raise _LineError(bad[1], _ODOM_FIELDS[bad[0]], "implausible")
            tracker.accept("ODOM pose", ipc, x, y, th)
        if not build:
            return None
        return Odometry(ipc, np.array((x, y, th)), tv, rv, logger, lineno)

    @staticmethod
    def _parse_param(f: list[str], params: dict[str, str]) -> None:
        if len(f) < 3:
            raise _LineError("expected PARAM name value", "value")
        name = f[1]
        if name in _NUMERIC_PARAMS:
            x = _float_field(f, 2, name)
            if not math.isfinite(x) or (name.endswith("_max") and x <= 0.0):
                raise _LineError(f"expected a positive finite number, got {f[2]!r}", name)
        params[name] = f[2]


def _check_poses(
    tracker: PoseTracker, kind: str, time: float, scan: LaserScan, names: Sequence[str]
) -> None:
    """Both poses of a laser line against :class:`PoseLimits` (a bad line if either fails);
    the tracker records them only when both pass."""
    lp, rp = scan.laser_pose, scan.robot_pose
    laser = (float(lp[0]), float(lp[1]), float(lp[2]))
    robot = (float(rp[0]), float(rp[1]), float(rp[2]))
    for k, pose in ((0, laser), (3, robot)):
        bad = tracker.check(f"{kind} {'laser' if k == 0 else 'robot'} pose", time, *pose)
        if bad is not None:
            raise _LineError(bad[1], names[k + bad[0]], "implausible")
    tracker.accept(f"{kind} laser pose", time, *laser)
    tracker.accept(f"{kind} robot pose", time, *robot)


def _dataset_name(path: Path) -> str:
    name = path.name
    for suffix in (".gz", ".bz2", ".clf", ".log", ".carmen"):
        if name.lower().endswith(suffix) and len(name) > len(suffix):
            name = name[: -len(suffix)]
    return name


# ---------------------------------------------------------------------------- batch


def load_scans(
    path: str | os.PathLike[str],
    *,
    poses: str = "corrected",
    sources: Sequence[str] = ("FLASER", "ROBOTLASER1"),
    dtype: type[np.floating] = np.float64,
    **log_options: Unpack[CarmenLogOptions],
) -> ScanBatch:
    """Read every front-laser scan of a CARMEN log into stacked arrays (for batch mapping).

    Parameters
    ----------
    path : path-like
        The log (plain, gzip or bzip2).
    poses : {"corrected", "odometry"}
        ``"corrected"``: each scan's own laser-pose fields (``x y theta``; GMapping's estimate in
        a corrected log). ``"odometry"``: the robot pose fields (``odom_*``) composed with the
        laser mounting offset, ``laser = robot (+) (d, 0, 0)`` where ``d`` is PARAM
        ``robot_frontlaser_offset`` in metres along the robot's x axis (0 when absent).
    **log_options
        ``start_angle``, ``angle_step``, ``max_range``, ``skip_bad_lines``, ``pose_limits``:
        as for :class:`CarmenLog`.
    sources : sequence of str
        Message types to keep. Default: the front laser (``FLASER``, ``ROBOTLASER1``).
    dtype : numpy floating type
        dtype of ``ranges`` (float64 by default; float32 halves the memory).

    Returns
    -------
    ScanBatch
        ``ranges`` (S, B), validated (:func:`probmap.datasets.validate.validate_ranges`: NaN for
        zero and invalid readings, the maximum range for ``+inf``) and counted in ``readings``;
        ``angles`` (B,) when all scans share one beam geometry, else (S, B).
        ``max_range`` is the smallest of the scans' maximum ranges.

    Raises
    ------
    DatasetError
        As :class:`CarmenLog`, and when the log holds no scan of the chosen ``sources``.
    """
    _check_load_args(poses, sources)
    log = CarmenLog(path, **log_options)
    batch = _stack(log, poses, sources, dtype, None)
    if batch is None:
        raise DatasetError(f"no {'/'.join(sources)} scans in the log", path=log.path)
    if not batch.max_range_stated:
        batch = with_inferred_no_return(batch)
    return batch


def with_inferred_no_return(batch: ScanBatch) -> ScanBatch:
    """``batch`` of a log that states no maximum range, its readings classified against the
    no-return value found in them (:func:`~probmap.datasets.validate.infer_no_return`), with
    the rule in ``readings.no_return_rule``; unchanged when no value stands out."""
    found = infer_no_return(np.asarray(batch.ranges), float(batch.max_range))
    if found is None:
        return batch
    ranges, report = validate_ranges(batch.ranges, found.value, beams=batch.beams)
    report = replace(report, skipped_lines=batch.skipped_lines, no_return_rule=found.describe())
    return replace(batch, ranges=ranges, max_range=found.value, readings=report)


def _check_load_args(poses: str, sources: Sequence[str]) -> None:
    if poses not in ("corrected", "odometry"):
        raise ValueError(f"poses must be 'corrected' or 'odometry', got {poses!r}")
    unknown = set(sources) - set(LASER_TYPES)
    if unknown or not sources:
        raise ValueError(f"sources must be among {LASER_TYPES}, got {tuple(sources)!r}")
    if poses == "odometry" and "RLASER" in sources:
        # the rear laser's mounting (offset and heading) is not described by the front PARAMs
        raise ValueError("poses='odometry' supports the front laser only; use poses='corrected'")


def _stack(
    log: CarmenLog,
    poses: str,
    sources: Sequence[str],
    dtype: type[np.floating],
    offset_params: dict[str, str] | None,
) -> ScanBatch | None:
    """One pass over ``log``: its scans of ``sources`` stacked (None when it has none).
    ``offset_params``: the PARAMs that give the laser offset (default: the log's own)."""
    keep = frozenset(sources)
    times: list[float] = []
    rows: list[NDArray[np.float64]] = []
    angle_rows: list[NDArray[np.float64]] = []
    laser: list[NDArray[np.float64]] = []
    robot: list[NDArray[np.float64]] = []
    max_ranges: list[float] = []
    odom: NDArray[np.float64] | None = None
    drift = [0.0, 0.0]  # largest distance (m), turn (rad) of a laser pose from the odometry
    for scan in log.records():
        if isinstance(scan, Odometry):
            odom = scan.pose
            continue
        if scan.source not in keep:
            continue
        if odom is not None:
            gap = scan.laser_pose - odom  # a mounting offset (< 1 m) counts as none
            drift[0] = max(drift[0], math.hypot(gap[0], gap[1]))
            drift[1] = max(drift[1], abs(math.remainder(gap[2], math.tau)))
        times.append(scan.time)
        rows.append(scan.ranges)
        angle_rows.append(scan.angles)
        laser.append(scan.laser_pose)
        robot.append(scan.robot_pose)
        max_ranges.append(scan.max_range)
    if not rows:
        return None
    ranges, angles, beams = stack_beams(rows, angle_rows, dtype)
    robot_poses = np.array(robot, dtype=np.float64).reshape(-1, 3)
    if poses == "corrected":
        laser_poses = np.array(laser, dtype=np.float64).reshape(-1, 3)
    else:
        params = log.params if offset_params is None else offset_params
        d = float(params.get("robot_frontlaser_offset", 0.0))
        th = robot_poses[:, 2]
        laser_poses = np.column_stack(
            (robot_poses[:, 0] + d * np.cos(th), robot_poses[:, 1] + d * np.sin(th), th)
        )
    max_range = float(min(max_ranges))
    ranges, report = validate_ranges(ranges, max_range, beams=beams)
    report = replace(report, skipped_lines=log.skipped_lines)
    return ScanBatch(
        times=np.array(times, dtype=np.float64),
        ranges=ranges,
        angles=angles,
        laser_poses=laser_poses,
        robot_poses=robot_poses,
        max_range=max_range,
        beams=beams,
        skipped_lines=log.skipped_lines,
        readings=report,
        max_range_stated=not log.max_range_defaulted,
        pose_source=_pose_source(
            poses,
            odom is not None,
            drift,
            gmapping=log._done is not None and log._done.neff > 0,
            rigid=_rigid(np.array(laser, dtype=np.float64).reshape(-1, 3), robot_poses),
        ),  # fmt: skip
    )


# A scan pose this far from the last ODOM message (metres, radians) was corrected: between
# two odometry messages a robot moves centimetres; a SLAM correction grows to metres.
CORRECTED_DRIFT = (1.0, 0.2)


def _rigid(laser: NDArray[np.float64], robot: NDArray[np.float64]) -> bool:
    """Whether every laser pose is the robot pose of its scan moved by one fixed offset
    along the heading (how a raw log states both; a SLAM system corrects the laser's only)."""
    if len(laser) == 0:
        return False
    turn = np.abs(np.remainder(laser[:, 2] - robot[:, 2] + np.pi, 2 * np.pi) - np.pi)
    d = laser[:, :2] - robot[:, :2]
    ahead = d[:, 0] * np.cos(robot[:, 2]) + d[:, 1] * np.sin(robot[:, 2])
    side = -d[:, 0] * np.sin(robot[:, 2]) + d[:, 1] * np.cos(robot[:, 2])
    return bool(turn.max() < 1e-3 and np.ptp(ahead) < 1e-3 and np.abs(side).max() < 1e-3)


def _pose_source(
    poses: str,
    has_odometry: bool,
    drift: Sequence[float],
    *,
    gmapping: bool = False,
    rigid: bool = False,
) -> str:
    """``"odometry"`` when the scans are placed by raw odometry (``poses="odometry"``, or laser
    poses that never leave the log's ``ODOM`` messages), ``"corrected"`` when they do or the
    log is GMapping's output (``gmapping``: it has ``NEFF`` lines; GMapping rewrites the
    ``ODOM`` lines too). Without ``ODOM`` messages: ``"odometry"`` when the laser poses are
    the scans' own odometry fields moved by a fixed offset (``rigid``), else ``""``."""
    if poses == "odometry":
        return "odometry"
    if gmapping:
        return "corrected"
    if not has_odometry:  # the scans' own odometry fields: a rigid offset from the laser's
        return "odometry" if rigid else ""
    far = drift[0] > CORRECTED_DRIFT[0] or drift[1] > CORRECTED_DRIFT[1]
    return "corrected" if far else "odometry"


# ---------------------------------------------------------------------------- shares of a log


@dataclass(frozen=True)
class LogShare:
    """A contiguous run of a log's lines, read once and parsed elsewhere (another process).

    ``params_before`` holds the PARAMs logged before ``first_line`` and ``params_all`` those of
    the whole log, so that a share parses exactly as the same lines do in a whole-log pass.
    """

    path: Path
    text: str
    first_line: int
    params_before: dict[str, str]
    params_all: dict[str, str]


def split_log(path: str | os.PathLike[str], n_shares: int) -> list[LogShare]:
    """Read (and decompress) a log once and cut its lines into ``n_shares`` contiguous shares
    holding nearly equal numbers of laser lines (for parsing them in parallel).

    Raises
    ------
    FileNotFoundError, DatasetError
        A missing file; an empty, truncated or corrupt one (named, as :class:`CarmenLog`).
    """
    require_at_least("n_shares", n_shares, 1)
    p = Path(path)
    CarmenLog(p)  # the same checks on the path as a whole-log read
    lines: list[str] = []
    laser: list[int] = []  # indices of laser lines
    params_at: list[tuple[int, list[str]]] = []
    for _, line in _numbered_lines(p):
        head = line[:12]
        if head.startswith(("FLASER", "RLASER", "ROBOTLASER1")):
            laser.append(len(lines))
        elif head.startswith("PARAM"):
            params_at.append((len(lines), line.split()))
        lines.append(line)
    if not any(line.strip() for line in lines):
        raise DatasetError("empty log (no messages)", path=p)
    # cut before the laser lines that start each share (the first share starts at line 1)
    n = max(1, min(n_shares, len(laser)))
    cuts = [0] + [laser[(k * len(laser)) // n] for k in range(1, n)] + [len(lines)]
    everything: dict[str, str] = {}
    for _, f in params_at:
        try:
            CarmenLog._parse_param(f, everything)
        except _LineError:
            pass  # reported by the share holding the line
    shares = []
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        before: dict[str, str] = {}
        for i, f in params_at:
            if i >= a:
                break
            try:
                CarmenLog._parse_param(f, before)
            except _LineError:
                pass
        shares.append(LogShare(p, "".join(lines[a:b]), a + 1, before, everything))
    return shares


def load_share(
    share: LogShare,
    *,
    poses: str = "corrected",
    sources: Sequence[str] = ("FLASER", "ROBOTLASER1"),
    dtype: type[np.floating] = np.float64,
    **log_options: Unpack[CarmenLogOptions],
) -> ScanBatch | None:
    """The scans of one share of a log, as :func:`load_scans` reads them from the whole log
    (same keywords, records, line numbers in errors, PARAM context); None when the share has
    none."""
    _check_load_args(poses, sources)
    log = CarmenLog(share.path, **log_options)
    log._share = (share.text, share.first_line, share.params_before)
    return _stack(log, poses, sources, dtype, share.params_all)
