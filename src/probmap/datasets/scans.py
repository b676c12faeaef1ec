"""One input path for every command that reads a laser log: :func:`open_scans`.

A CARMEN log (plain, gzip or bzip2), a ROS 1 bag (``.bag``), a ROS 2 bag (its folder, or its
``.db3``/``.mcap`` storage file) or the name of a laser dataset of the registry
(``intel-corrected``, resolved under the data directory) all come out as the same
:class:`~probmap.datasets.records.ScanBatch`, with readings classified by the one rule of
:mod:`probmap.datasets.validate` and counted in ``batch.readings``. ``probmap map``, ``map
--method map``, ``map --workers``, ``localize``, ``match``, ``fit-sensor-model`` and ``slam
grid`` (both methods) read their logs through it, so a bag works wherever a log does.

>>> from probmap.datasets import open_scans
>>> callable(open_scans)
True
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from probmap.datasets.records import ScanBatch
from probmap.datasets.validate import (
    PoseLimits,
    ReadingReport,
    check_end_time,
    require_usable,
    validate_ranges,
)

__all__ = ["BAG_OPTIONS", "in_publication_order", "open_scans", "resolve_log"]

#: The topic and frame options of a ROS bag (``bag_options=`` keys; the CLI's
#: ``--scan-topic``, ``--odom-topic``, ``--fixed-frame``, ``--laser-frame``).
BAG_OPTIONS = ("scan_topic", "odom_topic", "fixed_frame", "laser_frame", "echo")


def resolve_log(
    path: str | os.PathLike[str], data_directory: str | os.PathLike[str] | None = None
) -> Path:
    """The file a laser-log argument names: the path itself when it exists, else the file of
    the registry's laser dataset of that name under the data directory.

    Raises
    ------
    FileNotFoundError
        Neither a file nor a registered name; the one-line message lists the close registry
        names.
    DatasetError
        A registered name that is not a laser dataset, or whose file is absent.
    """
    from probmap.datasets.registry import resolve_input

    return resolve_input(path, data_directory, kind="laser")


def _given(bag_options: dict[str, Any] | None) -> dict[str, Any]:
    """The bag options actually set (None and 0 mean "not given")."""
    opts = dict(bag_options or {})
    unknown = sorted(set(opts) - set(BAG_OPTIONS))
    if unknown:
        raise ValueError(f"unknown bag option(s) {', '.join(unknown)}; known: {BAG_OPTIONS}")
    return {k: v for k, v in opts.items() if v not in (None, 0)}


def open_scans(
    path: str | os.PathLike[str],
    *,
    poses: str = "corrected",
    max_range: float | None = None,
    skip_bad_lines: bool = False,
    bag_options: dict[str, Any] | None = None,
    end_time: float | None = None,
    dtype: type[np.floating] = np.float64,
    pose_limits: PoseLimits | None = None,
    data_directory: str | os.PathLike[str] | None = None,
    require_readings: bool = True,
) -> ScanBatch:
    """Read the laser scans of a CARMEN log, a ROS 1/2 bag or a registered laser dataset.

    Parameters
    ----------
    path : path-like or str
        A CARMEN log (``.clf``/``.log``, plain, gzip or bzip2), a ROS 1 ``.bag``, a ROS 2 bag
        folder (or its ``.db3``/``.mcap`` file), or a registry name of a laser dataset
        (:data:`probmap.datasets.registry.DATASETS`, e.g. ``"intel-corrected"``).
    poses : {"corrected", "odometry"}
        CARMEN: the scans' own laser poses, or the robot's odometry composed with the laser
        offset (:func:`probmap.datasets.carmen.load_scans`). A bag has one pose source (tf and
        odometry), so it reads the same either way.
    max_range : float, optional
        The sensor's maximum range: readings at or beyond it are "no return". Default: the
        log's own (CARMEN: ``ROBOTLASER1``, PARAM, 80 m; bags: ``range_max``).
    skip_bad_lines : bool
        Skip and count malformed or implausible lines (bags: scans) instead of failing.
    bag_options : dict, optional
        ``scan_topic``, ``odom_topic``, ``fixed_frame``, ``laser_frame``, ``echo``, as for
        :class:`probmap.datasets.ros.scans.RosBag`; by default topics and frames are guessed.
        Given for a CARMEN log, they are an error.
    end_time : float, optional
        Keep the scans of the first ``end_time`` seconds only (``t <= t0 + end_time``).
    dtype : numpy floating type
        dtype of ``ranges``.
    pose_limits : PoseLimits, optional
        Bounds on plausible poses (default :class:`~probmap.datasets.validate.PoseLimits`).
    data_directory : path-like, optional
        Where registry names are found (default: ``$PROBMAP_DATA``, else ``../shared/data``).
    require_readings : bool
        Refuse a log without a single usable reading (the rule of every command).

    Returns
    -------
    ScanBatch
        With ``readings``, the classification of the readings kept (against ``max_range``).

    Raises
    ------
    FileNotFoundError
        Neither a file nor a registered name (the message lists close names).
    DatasetError
        Malformed input (naming the file and line or message), no scans, or no usable reading.
    MissingExtraError
        A bag without the ``ros`` extra (``pip install 'probmap[ros]'``).
    ValueError
        A bad option, or bag options for a CARMEN log.
    """
    from probmap.datasets.ros.scans import is_bag

    if poses not in ("corrected", "odometry"):
        raise ValueError(f"poses must be 'corrected' or 'odometry', got {poses!r}")
    if max_range is not None and not max_range > 0:
        raise ValueError(f"max_range must be > 0 m, got {max_range}")
    check_end_time(end_time)
    given = _given(bag_options)
    p = resolve_log(path, data_directory)
    shown = path if p == Path(path) else p  # errors name the path as given, or the file
    if is_bag(p):
        from probmap.datasets.ros.scans import load_bag_scans

        batch = load_bag_scans(
            p, dtype=dtype, pose_limits=pose_limits, skip_bad_lines=skip_bad_lines, **given
        )
        if max_range is not None and float(max_range) != float(batch.max_range):
            batch = _with_max_range(batch, float(max_range))
    else:
        if given:
            raise ValueError(f"{shown}: topic/frame options apply to ROS bags only")
        from probmap.datasets.carmen import load_scans

        batch = load_scans(
            p,
            poses=poses,
            max_range=max_range,
            skip_bad_lines=skip_bad_lines,
            dtype=dtype,
            pose_limits=pose_limits,
        )
    if end_time is not None:
        batch = _first_seconds(batch, float(end_time))
    if require_readings:
        report = batch.readings
        if report is None:  # pragma: no cover - every reader fills it
            _, report = validate_ranges(
                np.asarray(batch.ranges), batch.max_range, beams=batch.beams
            )
        require_usable(report, shown, float(batch.max_range))
    return batch


def _with_max_range(batch: ScanBatch, max_range: float) -> ScanBatch:
    """A bag's batch classified against another maximum range. The bag reader already turned
    zero readings into NaN; they stay counted as zero, not as NaN."""
    ranges, report = validate_ranges(batch.ranges, max_range, beams=batch.beams)
    old = batch.readings or ReadingReport()
    report = replace(
        report,
        zero=old.zero,
        invalid=report.invalid - old.zero,
        skipped_lines=int(batch.skipped_lines),
    )
    return replace(batch, ranges=ranges, max_range=max_range, readings=report)


def _first_seconds(batch: ScanBatch, end_time: float) -> ScanBatch:
    """The scans stamped within ``end_time`` seconds of the first (timestamps need not be
    sorted: Intel's jitter), with their readings counted again."""
    t = np.asarray(batch.times)
    if t.size == 0:
        return batch
    keep = t <= t[0] + end_time
    if keep.all():
        return batch
    part = batch.rows(keep)
    _, report = validate_ranges(part.ranges, float(batch.max_range), beams=part.beams)
    report = replace(report, skipped_lines=int(batch.skipped_lines))
    return replace(part, readings=report)


def in_publication_order(batch: ScanBatch) -> tuple[ScanBatch, int]:
    """The batch's scans in the order their driver published them
    (:attr:`~probmap.datasets.records.ScanBatch.published`), and how many scans the file
    holds after one published later than them; the batch itself when it records no such
    order or is in it already.

    Lidar-only SLAM predicts each scan from the one before, so it needs the order the scans
    were taken in. A bag written in stamp order, whose stamps jitter, holds another: the
    Intel bag's scans stamped up to 0.9 s late put 998 of its 13,630 after a scan published
    later. With odometry, each scan is placed from the odometry at
    its stamp, and stamp order serves (the Intel bag maps to 0.0206 m in stamp order,
    0.0225 m in publication order).
    """
    if batch.published is None:
        return batch, 0
    keys = np.asarray(batch.published)
    # the scans the file holds after one published later than them
    late = int(np.count_nonzero(keys[1:] < np.maximum.accumulate(keys)[:-1]))
    if late == 0:
        return batch, 0
    return batch.rows(np.argsort(keys, kind="stable")), late
