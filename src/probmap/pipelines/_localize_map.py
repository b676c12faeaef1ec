"""The map a log is localized in: a map_server map or a graph-SLAM session, read by
:func:`load_localization_map` (re-exported by :mod:`probmap.pipelines.localize`)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from probmap.pipelines._localize_track import match_times

__all__ = ["LocalizationMap", "load_localization_map"]


@dataclass(frozen=True, eq=False)
class LocalizationMap:
    """The map a log is localized in, read by :func:`load_localization_map`.

    It has what the map pictures and the live view take of an occupancy grid (``spec``,
    ``log_odds``, ``observed``), so it can be drawn like one.

    Attributes
    ----------
    spec : GridSpec
        Geometry (resolution in m, origin of the lower-left corner in m, shape (H, W)).
    probability : (H, W) ndarray
        Occupancy probability per cell, rows from the smallest y, NaN where unknown.
    source : Path
        The file it was read from.
    kind : str
        ``"map"`` (a map_server YAML map) or ``"session"`` (a graph-SLAM session).
    times : (S,) ndarray or None
        A session's scan timestamps (s); None for a map.
    poses : (S, 3) ndarray or None
        A session's optimized sensor poses at those scans (m, rad), in the map frame: the
        run's own trajectory, which a localization in its map can be compared with.
    odometry : (S, 3) ndarray or None
        A session's sensor odometry at those scans (m, rad): the robot's odometry composed
        with the mounting offset the session was built with (see :func:`laser_offset_of`).
    """

    spec: Any
    probability: NDArray[np.float64]
    source: Path
    kind: str
    times: NDArray[np.float64] | None = None
    poses: NDArray[np.float64] | None = None
    odometry: NDArray[np.float64] | None = None

    @property
    def observed(self) -> NDArray[np.bool_]:
        """(H, W) bool: cells with a known occupancy."""
        return np.isfinite(self.probability)

    @property
    def log_odds(self) -> NDArray[np.float64]:
        """(H, W) log odds ``log(p / (1 - p))`` (0 where unknown; +-inf at p = 1, 0)."""
        p = np.nan_to_num(self.probability, nan=0.5)
        with np.errstate(divide="ignore"):
            return np.log(p) - np.log1p(-p)

    def pose_at(self, time_s: float, max_dt: float = 0.02) -> NDArray[np.float64] | None:
        """A session's pose (3,) at the scan nearest ``time_s`` when one lies within
        ``max_dt`` seconds; None otherwise (and always for a map)."""
        if self.times is None or self.poses is None:
            return None
        i, j = match_times(self.times, [time_s], max_dt)
        return self.poses[i[0]].copy() if j.size else None


def load_localization_map(path: str | os.PathLike[str]) -> LocalizationMap:
    """A map to localize in: a map_server YAML map, or a graph-SLAM session saved by
    ``probmap slam grid --save-session`` (:func:`~probmap.pipelines.sessions.save_session`).

    A session's run is finished as ``slam grid`` finishes it (the final optimization), and
    its occupancy grid is rendered with every scan at its optimized pose
    (:meth:`SubmapSlam.map <probmap.slam.laser.submap_slam.SubmapSlam.map>`): the map ``slam grid``
    wrote beside the session. Its frame is the session's, the sensor odometry frame of its
    first scan. A session is data (arrays and a JSON header, docs/sessions.md): reading one
    runs no code from it, whoever wrote it.

    Parameters
    ----------
    path : path-like
        ``*.yaml`` / ``*.yml``: a map_server map; a folder: its ``slam.session`` (the file
        ``slam grid --save-session FOLDER`` writes; named in ``source``); anything else: a
        session.

    Returns
    -------
    LocalizationMap

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        A file that is neither (one line naming the file), a malformed map (a
        :class:`~probmap.errors.MapFileError` naming the field), or a session of another
        format version or malformed (an old pickled one among them: it is never unpickled).
    """
    p = Path(path)
    if p.is_dir():  # a folder given to slam grid --save-session holds slam.session
        from probmap.pipelines.laser_slam import SESSION_NAME

        p = p / SESSION_NAME
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such map or session file")
    if p.suffix.lower() in (".yaml", ".yml"):
        from probmap.grid.io import read_map_server

        m = read_map_server(p)
        return LocalizationMap(m.spec, np.asarray(m.probability, dtype=np.float64), p, "map")
    neither = (
        f"{p}: neither a map_server YAML map (*.yaml) nor a probmap graph-SLAM session "
        "(probmap slam grid --save-session)"
    )
    from probmap.pipelines.sessions import NotASessionError, load_session

    try:
        slam = load_session(p)
    except NotASessionError:
        raise ValueError(neither) from None
    if slam.nodes == 0:
        raise ValueError(f"{p}: the session holds no scans")
    slam.finish()  # the final optimization, as slam grid ran it before writing its map
    grid = slam.map()
    prob = np.where(grid.observed, grid.probability(), np.nan)
    times, poses = slam.trajectory()
    odometry = np.asarray(slam.scan_odometry, dtype=np.float64).reshape(-1, 3)
    return LocalizationMap(
        grid.spec, prob, p, "session", np.asarray(times, dtype=np.float64), poses, odometry
    )
