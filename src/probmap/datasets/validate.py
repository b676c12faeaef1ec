"""One validation step for laser readings and poses, shared by every reader and command.

Readings
--------
Every reading of a laser log falls in exactly one class, whatever the format:

========== ========================================= ==========================================
class      which readings                            what the batch readers make of them
========== ========================================= ==========================================
usable     finite, ``0 < r < max_range``             kept as they are
no return  ``r >= max_range`` or ``+inf``            ``+inf`` becomes ``max_range`` (a finite
                                                     reading at or beyond it is kept)
zero       ``r == 0``                                invalid: NaN (dropped, counted)
invalid    NaN, ``-inf``, ``r < 0``                  NaN (dropped, counted)
========== ========================================= ==========================================

"No return" per format: CARMEN logs store it as a reading at or beyond the maximum range
(81.83-81.91 m for the SICK LMS; the maximum range is the ``ROBOTLASER1`` message's own, else
the PARAM ``laser_front_laser_max``, else the reading :func:`infer_no_return` finds repeated
as a point mass at the top of the data, else 80 m); ROS bags as ``+inf`` or a reading at or above
``range_max`` (readings below ``range_min`` are invalid, as NaN and ``-inf`` are). Every command
(``map``, ``match``, ``fit-sensor-model``, ``localize``, ``slam grid``, ``semantic``) sees the
same cleaned readings, so the same input gets the same verdict everywhere. Padding (the NaN
tail of a short scan in a batch of longer ones) is not a reading and is counted nowhere.

:func:`validate_ranges` cleans and counts; :class:`ReadingReport` is what the commands print
(one line, the same in every command); :func:`require_usable` turns a log without a single
usable reading into a :class:`~probmap.errors.DatasetError` naming the file.

Poses
-----
:class:`PoseLimits` bounds what a pose may do: its coordinates (``max_coordinate``) and its
increment from the previous pose of the same stream, ``max_step + max_speed * |dt|`` metres and
``max_turn_step + max_turn_rate * |dt|`` radians, ``dt`` from the timestamps. The constant
terms keep the check sound on logs whose timestamps repeat or jitter (GMapping-corrected logs
have ``dt = 0`` between messages). The defaults are generous: the real logs we know move at
most 1.6 m and 0.6 rad between two messages and stay within 400 m of their origin.
:class:`PoseTracker` applies them message by message; the readers turn its verdict into a bad
line (an error naming the file, line and field, or a skipped line with ``skip_bad_lines``).
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from probmap._sums import field_sums
from probmap.errors import DatasetError

__all__ = [
    "PoseLimits",
    "PoseTracker",
    "ReadingReport",
    "check_end_time",
    "dataset_directory",
    "NoReturnValue",
    "infer_no_return",
    "no_return_from_tops",
    "number_rows",
    "require_usable",
    "text_lines",
    "top_readings",
    "validate_ranges",
]


# ---------------------------------------------------------------------------- text files


def text_lines(path: str | os.PathLike[str]) -> Iterator[tuple[int, str]]:
    """``(line_number, text)`` of every line of a UTF-8 text file; a byte that is not UTF-8 is a
    :class:`DatasetError` naming the file and the line (not a bare ``UnicodeDecodeError``).

    Raises
    ------
    FileNotFoundError, IsADirectoryError
        As :func:`open` (the message names the file).
    DatasetError
        The file is not UTF-8 text (a binary file, a Latin-1 export, ...).
    """
    p = Path(path)
    with open(p, "rb") as f:
        for lineno, raw in enumerate(f, start=1):
            try:
                line = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                bad = raw[exc.start : exc.start + 1].hex()
                raise DatasetError(
                    f"not a UTF-8 text file: byte 0x{bad} at column {exc.start + 1} "
                    "cannot be decoded",
                    path=p,
                    line=lineno,
                ) from None
            yield lineno, line.replace("\r\n", "\n")


def number_rows(
    path: Path, layout: str, what: str, *, commas: bool = False
) -> Iterator[tuple[int, list[float]]]:
    """``(line_number, values)`` of every line of a table of finite numbers.

    Blank lines and lines starting with ``#`` are skipped; the other lines must hold exactly as
    many whitespace-separated numbers (also comma-separated with ``commas``) as ``layout``
    names fields (``"t1 t2 dx dy dz droll dpitch dyaw"``). Undecodable bytes are replaced.

    Raises
    ------
    DatasetError
        A line with another number of fields, a field that is not a number, or a value that is
        not finite; the message names the file, the line and ``what`` a row is ("TUM pose").
    """
    n = len(layout.split())
    with open(path, encoding="utf-8", errors="replace") as f:
        for number, raw in enumerate(f, 1):
            line = raw.strip()
            if not line or line.startswith("#"):
                continue
            fields = (line.replace(",", " ") if commas else line).split()
            if len(fields) != n:
                raise DatasetError(
                    f"expected {n} fields ({layout}), found {len(fields)}", path=path, line=number
                )
            try:
                values = [float(v) for v in fields]
            except ValueError:
                raise DatasetError(f"non-numeric field in {what}", path=path, line=number) from None
            if not all(math.isfinite(v) for v in values):
                raise DatasetError(f"non-finite value in {what}", path=path, line=number)
            yield number, values


# ---------------------------------------------------------------------------- readings


@dataclass(frozen=True)
class ReadingReport:
    """How the readings of a log were classified (see the module docstring).

    Attributes
    ----------
    scans : int
        Scans counted.
    readings : int
        Real readings (padding excluded): ``usable + no_return + zero + invalid``.
    usable, no_return, zero, invalid : int
        Readings of each class.
    beam_counts : tuple of (int, int)
        ``(beams per scan, scans)`` for every beam count seen, most frequent first.
    skipped_lines : int
        Lines of the log skipped as malformed or physically implausible (``skip_bad_lines``).
    no_return_rule : str
        How the maximum range was chosen when the log did not state it (:func:`infer_no_return`),
        e.g. ``"no return = 50.00 m, inferred: ..."``; empty when the log stated it.
    """

    scans: int = 0
    readings: int = 0
    usable: int = 0
    no_return: int = 0
    zero: int = 0
    invalid: int = 0
    beam_counts: tuple[tuple[int, int], ...] = field(default=())
    skipped_lines: int = 0
    no_return_rule: str = ""

    def __add__(self, other: ReadingReport) -> ReadingReport:
        counts: dict[int, int] = dict(self.beam_counts)
        for b, n in other.beam_counts:
            counts[b] = counts.get(b, 0) + n
        rule = self.no_return_rule or other.no_return_rule
        return field_sums(self, other, beam_counts=_sorted_counts(counts), no_return_rule=rule)

    @property
    def dropped(self) -> int:
        """Readings dropped as invalid (zero included)."""
        return self.zero + self.invalid

    def describe(self) -> str:
        """One line for the commands' summaries, e.g. ``"24,000 in 131 scans: 23,500 usable,
        400 no return, 100 dropped (60 zero, 40 NaN/-inf/negative); 180 beams x 130 scans,
        181 beams x 1 scan"``."""
        text = (
            f"{self.readings:,} in {self.scans:,} scan{'s' if self.scans != 1 else ''}: "
            f"{self.usable:,} usable, {self.no_return:,} no return, {self.dropped:,} dropped "
            f"({self.zero:,} zero, {self.invalid:,} NaN/-inf/negative)"
        )
        if len(self.beam_counts) > 1:
            text += "; " + ", ".join(
                f"{b} beams x {n:,} scan{'s' if n != 1 else ''}" for b, n in self.beam_counts
            )
        if self.no_return_rule:
            text += "; " + self.no_return_rule
        return text


#: A no-return value must repeat at least this many times, and this many times more often than
#: the next smaller reading, to be inferred (:func:`infer_no_return`).
NO_RETURN_MIN_COUNT = 20
NO_RETURN_RATIO = 10


@dataclass(frozen=True)
class NoReturnValue:
    """A no-return reading found in the data by :func:`infer_no_return`.

    Attributes
    ----------
    value : float
        The reading (m): readings at or beyond it are "no return".
    count : int
        How often it occurs exactly.
    next_value : float
        The largest reading below it (m; NaN when there is none).
    next_count : int
        How often that one occurs.
    """

    value: float
    count: int
    next_value: float
    next_count: int

    def describe(self) -> str:
        """Which value was used and why, for the commands' summaries."""
        nxt = (
            f"the next largest, {self.next_value:.2f} m, {self.next_count:,} times"
            if math.isfinite(self.next_value)
            else "no other reading"
        )
        return (
            f"no return = {self.value:.2f} m, inferred (the log states no maximum range): the "
            f"largest reading occurs exactly {self.count:,} times, {nxt}"
        )


def infer_no_return(ranges: NDArray[np.floating], below: float) -> NoReturnValue | None:
    """The no-return reading of a log that does not state its maximum range.

    Lasers write "no return" as one fixed reading, usually their maximum range (50.00 m,
    81.83 m, ...). It shows in the data as the largest reading repeated exactly, many times,
    where genuine far readings are spread out and rare. It is inferred when the largest finite
    reading below ``below`` occurs at least :data:`NO_RETURN_MIN_COUNT` times and at least
    :data:`NO_RETURN_RATIO` times as often as the next smaller reading; a log whose every
    reading is one value (a synthetic wall at a fixed distance) has none.

    Parameters
    ----------
    ranges : ndarray, shape (S, B) or (B,)
        Readings (m); NaN, zero and negative ones are ignored.
    below : float
        Readings at or beyond it are no return already (the default maximum range, 80 m).

    Returns
    -------
    NoReturnValue or None
        None when no reading stands out so.

    Examples
    --------
    >>> import numpy as np
    >>> r = np.r_[np.linspace(0.5, 40.0, 500), np.full(30, 50.0)]
    >>> infer_no_return(r, 80.0).value
    50.0
    >>> infer_no_return(np.linspace(0.5, 40.0, 500), 80.0) is None
    True
    """
    return no_return_from_tops([top_readings(ranges, below)])


def top_readings(
    ranges: NDArray[np.floating], below: float
) -> tuple[float, int, float, int] | None:
    """The largest finite reading below ``below`` and how often it occurs, then the next
    smaller one and its count (NaN, 0 when none): what :func:`infer_no_return` looks at, in a
    form that parts of a log can compute apart (:func:`no_return_from_tops` joins them).
    None when there is no such reading."""
    r = np.asarray(ranges).reshape(-1)
    with np.errstate(invalid="ignore"):
        r = r[np.isfinite(r) & (r > 0) & (r < below)]
    if r.size == 0:
        return None
    top = r.max()
    rest = r[r < top]
    if rest.size == 0:
        return float(top), int(r.size), math.nan, 0
    nxt = rest.max()
    return (
        float(top),
        int(np.count_nonzero(r == top)),
        float(nxt),
        int(np.count_nonzero(rest == nxt)),
    )


def no_return_from_tops(
    tops: Sequence[tuple[float, int, float, int] | None],
) -> NoReturnValue | None:
    """:func:`infer_no_return` over the parts of a log whose :func:`top_readings` are
    ``tops``: the whole log's two largest readings and counts are exact from the parts'."""
    values: dict[float, int] = {}
    for t in tops:
        if t is None:
            continue
        values[t[0]] = values.get(t[0], 0) + t[1]
        if t[3]:
            values[t[2]] = values.get(t[2], 0) + t[3]
    if not values:
        return None
    top = max(values)
    below = [v for v in values if v < top]
    if not below:  # one value throughout: nothing shows it to be a cap, not a wall
        return None
    nxt = max(below)
    # a part whose top is the whole log's next value counts it in full; one whose top is
    # larger holds it as its second value, counted in full too: the sums are exact
    next_count = values[nxt] if below else 0
    count = values[top]
    if count < NO_RETURN_MIN_COUNT or count < NO_RETURN_RATIO * next_count:
        return None
    return NoReturnValue(top, count, nxt, next_count)


def _sorted_counts(counts: dict[int, int]) -> tuple[tuple[int, int], ...]:
    return tuple(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def validate_ranges(
    ranges: NDArray[np.floating],
    max_range: float,
    *,
    beams: NDArray[np.integer] | Sequence[int] | None = None,
) -> tuple[NDArray[np.floating], ReadingReport]:
    """Classify, count and clean the readings of a scan batch.

    Parameters
    ----------
    ranges : ndarray, shape (S, B) or (B,)
        Readings in metres (float32 or float64). Not modified.
    max_range : float
        The sensor's maximum range (m), > 0: readings at or beyond it are "no return".
    beams : array of int, shape (S,), optional
        Real beams per row; the rest of a row is padding, counted nowhere and left NaN.

    Returns
    -------
    cleaned : ndarray
        ``ranges`` itself when nothing needs cleaning, else a copy of the same dtype with NaN for
        zero and invalid readings (NaN, -inf, negative) and ``max_range`` for ``+inf``.
    report : ReadingReport
    """
    if not max_range > 0:  # NaN too
        raise ValueError(f"max_range must be > 0 m, got {max_range}")
    r = np.asarray(ranges)
    if not np.issubdtype(r.dtype, np.floating):
        r = r.astype(np.float64)
    rows = r.reshape(1, -1) if r.ndim == 1 else r
    if rows.ndim != 2:
        raise ValueError(f"ranges must have shape (S, B), got {r.shape}")
    s, b = rows.shape
    real: NDArray[np.bool_] | None = None
    if beams is None:
        counts = {b: s} if s else {}
    else:
        nb = np.asarray(beams, dtype=np.int64).reshape(-1)
        if nb.shape != (s,):
            raise ValueError(f"beams must have shape ({s},), got {nb.shape}")
        values, freq = np.unique(nb, return_counts=True)
        counts = {int(v): int(c) for v, c in zip(values, freq, strict=True)}
        if np.any(nb != b):
            real = np.arange(b)[None, :] < nb[:, None]
    with np.errstate(invalid="ignore"):
        nan = np.isnan(rows)
        posinf = np.isposinf(rows)
        negative = rows < 0  # -inf included
        zero = rows == 0
        beyond = rows >= max_range  # +inf included
    if real is not None:
        nan &= real
        posinf &= real
        negative &= real
        zero &= real
        beyond &= real
        n_real = int(np.count_nonzero(real))
    else:
        n_real = int(rows.size)
    n_nan, n_neg = int(np.count_nonzero(nan)), int(np.count_nonzero(negative))
    n_zero, n_beyond = int(np.count_nonzero(zero)), int(np.count_nonzero(beyond))
    n_posinf = int(np.count_nonzero(posinf))
    report = ReadingReport(
        scans=s,
        readings=n_real,
        usable=n_real - n_nan - n_neg - n_zero - n_beyond,
        no_return=n_beyond,
        zero=n_zero,
        invalid=n_nan + n_neg,
        beam_counts=_sorted_counts(counts),
    )
    if not (n_neg or n_zero or (n_posinf and math.isfinite(max_range))):
        return ranges if r is ranges else r, report
    out = rows.copy()
    out[negative | zero] = np.nan
    if n_posinf and math.isfinite(max_range):
        out[posinf] = _at_least(max_range, out.dtype)
    return out.reshape(r.shape), report


def check_end_time(end_time: float | None) -> None:
    """Raise :class:`ValueError` unless ``end_time`` (seconds after a log's start, the readers'
    "first seconds only" option) is None or a positive finite number."""
    if end_time is not None and not (math.isfinite(end_time) and end_time > 0):
        raise ValueError(f"end_time must be a positive number of seconds, got {end_time}")


def dataset_directory(directory: str | os.PathLike[str]) -> Path:
    """``directory`` as a :class:`~pathlib.Path`; a :class:`DatasetError` naming it unless it is
    an existing folder (the readers of datasets stored as a folder of files)."""
    d = Path(directory)
    if not d.is_dir():
        raise DatasetError("not a directory", path=d)
    return d


def _at_least(value: float, dtype: np.dtype) -> float:
    """``value`` as stored in ``dtype``, rounded up so that it still compares ``>= value``."""
    v = np.asarray(value, dtype=dtype)
    if float(v) < value:
        v = np.nextafter(v, np.asarray(np.inf, dtype=dtype))
    return float(v)


def require_usable(report: ReadingReport, path: object, max_range: float | None = None) -> None:
    """Raise :class:`DatasetError` naming ``path`` when ``report`` holds no usable reading: a
    command would otherwise write an empty map (or a degenerate model) and exit as if it worked.
    """
    if report.usable > 0:
        return
    at = f" {max_range:g} m" if max_range is not None else ""
    raise DatasetError(
        f"no usable laser reading in {report.scans:,} scan{'s' if report.scans != 1 else ''} "
        f"({report.no_return:,} no return at or beyond the maximum range{at}, "
        f"{report.zero:,} zero, {report.invalid:,} NaN/-inf/negative)",
        path=path,
    )


# ---------------------------------------------------------------------------- poses


@dataclass(frozen=True)
class PoseLimits:
    """Physical limits on logged poses; a pose outside them is a bad line.

    Parameters
    ----------
    max_coordinate : float
        Largest ``|x|`` or ``|y|`` in metres (default 100 km).
    max_speed : float
        m/s allowed between two poses of one stream, on top of ``max_step`` (default 20).
    max_step : float
        Metres allowed between two consecutive poses whatever their timestamps (default 10).
    max_turn_rate : float
        rad/s allowed on top of ``max_turn_step`` (default 5).
    max_turn_step : float
        Radians allowed between two consecutive poses whatever their timestamps (default 2).

    Notes
    -----
    Any limit may be ``math.inf`` (no limit); none may be NaN, zero or negative.
    """

    max_coordinate: float = 1.0e5
    max_speed: float = 20.0
    max_step: float = 10.0
    max_turn_rate: float = 5.0
    max_turn_step: float = 2.0

    def __post_init__(self) -> None:
        for name in ("max_coordinate", "max_speed", "max_step", "max_turn_rate", "max_turn_step"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
                raise ValueError(f"PoseLimits.{name} must be a number > 0 (or inf), got {v!r}")


class PoseTracker:
    """Checks each pose of a log against :class:`PoseLimits` and the previous good pose of the
    same stream (``"FLASER"``, ``"ODOM"``, ...).

    :meth:`check` returns None for a plausible pose, else ``(index, message)``: the index
    (0, 1 or 2 for x, y, theta) of the field to name and what is wrong. :meth:`accept` records
    the poses of a line once all of them passed (a skipped line moves nothing).
    """

    def __init__(self, limits: PoseLimits | None = None) -> None:
        self.limits = limits if limits is not None else PoseLimits()
        self._last: dict[str, tuple[float, float, float, float]] = {}

    def check(
        self, stream: str, time: float, x: float, y: float, theta: float
    ) -> tuple[int, str] | None:
        lim = self.limits
        for k, v in ((0, x), (1, y)):
            if abs(v) > lim.max_coordinate:
                return k, (
                    f"{v:g} m is beyond the plausible extent "
                    f"(|coordinate| <= {lim.max_coordinate:g} m)"
                )
        last = self._last.get(stream)
        if last is None:
            return None
        t0, x0, y0, th0 = last
        dt = abs(time - t0) if math.isfinite(time) and math.isfinite(t0) else 0.0
        dx, dy = x - x0, y - y0
        d = math.hypot(dx, dy)
        allowed = lim.max_step + lim.max_speed * dt
        if d > allowed:
            return (0 if abs(dx) >= abs(dy) else 1), (
                f"the pose jumps {d:g} m in {dt:g} s from the previous {stream} pose "
                f"(plausible: <= {lim.max_step:g} m + {lim.max_speed:g} m/s)"
            )
        turn = abs((theta - th0 + math.pi) % (2.0 * math.pi) - math.pi)
        allowed = lim.max_turn_step + lim.max_turn_rate * dt
        if turn > allowed:
            return 2, (
                f"the heading turns {turn:g} rad in {dt:g} s from the previous {stream} pose "
                f"(plausible: <= {lim.max_turn_step:g} rad + {lim.max_turn_rate:g} rad/s)"
            )
        return None

    def accept(self, stream: str, time: float, x: float, y: float, theta: float) -> None:
        self._last[stream] = (time, x, y, theta)
