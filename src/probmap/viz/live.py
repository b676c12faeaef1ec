"""Live view of a run in the rerun viewer, or a recording of it (``.rrd``) to open later.

Needs the ``viz`` extra (``pip install 'probmap[viz]'``, which installs ``rerun-sdk``). The
world frame is the map's: x to the right, y up, metres. Entities:

``world/map``
    An occupancy grid as an image (free white, occupied black, unknown grey), placed in metres
    by a transform (origin and resolution of its :class:`~probmap.grid.spec.GridSpec`).
``world/submaps/<i>``
    Graph SLAM: the occupied cells of each finished submap, in its anchor's frame; the
    transforms are logged again after every optimization, so the map moves as loops close.
``world/trajectory``, ``world/scan``, ``world/closures``
    The estimated path, the newest scan's endpoints, accepted loop closures (node to anchor).
``world/particles``, ``world/landmarks``
    Particle filters and landmark SLAM (means and 2-sigma ellipses).
``world/robot``, ``world/measurements``, ``world/reference``
    Landmark SLAM: the robot's pose, the rays of the current measurements, the ground truth
    (or GPS, ``world/gps``) when the dataset has it.

Every logged item carries the timeline ``scan`` (the scan index) so that the viewer can scrub
through the run. :class:`GraphSlamObserver` is the observer that
:func:`probmap.pipelines.laser_slam.run_submap_slam` calls after each scan;
:class:`MappingObserver` and :class:`LandmarkSlamObserver` watch ``probmap map`` and landmark
SLAM.
"""

from __future__ import annotations

import copy
import math
import os
import re
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from probmap._checks import require_at_least
from probmap.viz.maps import sampled_cells

__all__ = [
    "GraphSlamObserver",
    "LandmarkSlamObserver",
    "LiveView",
    "MappingObserver",
    "read_recording",
]

_HINT = "the live view needs rerun: pip install 'probmap[viz]'"


def _rerun() -> Any:
    from probmap.errors import MissingExtraError

    try:
        import rerun
    except ImportError as exc:
        # an ImportError the CLI reports on one line (cli_errors), not a traceback
        raise MissingExtraError(_HINT) from exc
    return rerun


def _ellipse(mean: NDArray, cov: NDArray, k: float = 2.0, n: int = 24) -> NDArray[np.float64]:
    """Closed polygon of the ``k``-sigma ellipse of a 2-D Gaussian, (n + 1, 2)."""
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    lam = np.clip(lam, 0.0, None)
    t = np.linspace(0.0, 2.0 * math.pi, n + 1)
    circle = np.stack([np.cos(t), np.sin(t)])
    return (mean[:, None] + k * (vec * np.sqrt(lam)) @ circle).T


class LiveView:
    """A rerun recording of one run: shown live (``spawn``), saved (``save``), or both.

    Parameters
    ----------
    name : str
        Application name shown by the viewer (``"probmap slam grid"``).
    save : path-like, optional
        Record everything into this ``.rrd`` file (open it with ``rerun FILE.rrd``). The
        recording is written as the run goes into a temporary file beside it, renamed to
        ``save`` by :meth:`close` (or removed by ``close(keep=False)``: a failed run leaves
        no file). A missing folder is created.
    spawn : bool
        Start a rerun viewer and stream to it.

    Raises
    ------
    ImportError
        rerun is not installed (one line naming the extra).
    ValueError
        Neither ``save`` nor ``spawn``, or ``save`` does not end in ``.rrd``.
    """

    def __init__(
        self, name: str, *, save: str | os.PathLike[str] | None = None, spawn: bool = False
    ) -> None:
        rr = _rerun()
        if save is None and not spawn:
            raise ValueError("a live view needs save=FILE.rrd, spawn=True or both")
        self._rr = rr
        self.file = None if save is None else Path(save)
        if self.file is not None and self.file.suffix != ".rrd":
            raise ValueError(f"{self.file}: a recording is saved as FILE.rrd")
        # rerun's application ids take letters, digits, spaces, "-" and "_" (else it warns)
        self._rec: Any = rr.RecordingStream(re.sub(r"[^A-Za-z0-9 _-]+", "-", name))
        sinks = []
        self._part: Path | None = None
        if self.file is not None:
            self.file.parent.mkdir(parents=True, exist_ok=True)
            self._part = self.file.with_name(f".{self.file.name}.{os.getpid()}.part.rrd")
            sinks.append(rr.FileSink(str(self._part)))
        if spawn:
            self._rec.spawn(connect=False)
            sinks.append(rr.GrpcSink())
        self._rec.set_sinks(*sinks)
        # one 2-D view of the map frame and one plot of the run's numbers; without this
        # layout the viewer guesses, and a view-coordinates hint on "world" made it add an
        # empty 3-D view. The map frame is y-up, a 2-D view is y-down: "world" is mirrored
        # in y under the view's root, so the map reads as in the pictures.
        import rerun.blueprint as rrb

        self._rec.send_blueprint(
            rrb.Blueprint(
                rrb.Horizontal(
                    rrb.Spatial2DView(origin="/", contents="/world/**", name="map"),
                    rrb.TimeSeriesView(origin="/stats", name="stats"),
                    column_shares=[3, 1],
                ),
                collapse_panels=True,
            )
        )
        self._rec.log("world", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)

    # ----------------------------------------------------------------- primitives
    def step(self, scan: int) -> None:
        """Set the ``scan`` timeline for what is logged next."""
        self._rec.set_time("scan", sequence=int(scan))

    def grid(self, grid: Any, entity: str = "world/map", *, max_pixels: int = 2000) -> None:
        """An :class:`~probmap.grid.occupancy.OccupancyGrid` as an image placed in metres
        (every ``step``-th cell so that the longer side has at most ``max_pixels``)."""
        rr = self._rr
        lo, seen, step = sampled_cells(grid, max_pixels)
        free = 1.0 / (1.0 + np.exp(lo.astype(np.float64)))  # 1 - p: free white
        img = np.where(seen, free * 255.0, 160.0).astype(np.uint8)[::-1]  # row 0 on top
        r = grid.spec.resolution * step
        ox, oy = grid.spec.origin
        top = oy + img.shape[0] * r
        self._rec.log(entity, rr.Transform3D(translation=[ox, top, 0.0], scale=[r, -r, 1.0]))
        self._rec.log(entity, rr.Image(img, color_model="L"))

    def points(
        self, entity: str, xy: ArrayLike, *, color: tuple[int, int, int] = (220, 40, 40),
        radius: float = 0.04,
    ) -> None:  # fmt: skip
        """Points (N, 2) in metres."""
        p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        self._rec.log(entity, self._rr.Points2D(p, colors=color, radii=radius))

    def path(
        self, entity: str, xy: ArrayLike, *, color: tuple[int, int, int] = (30, 100, 220)
    ) -> None:
        """A polyline (N, 2) in metres."""
        p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        self._rec.log(entity, self._rr.LineStrips2D([p], colors=color, radii=0.03))

    def segments(
        self, entity: str, a: ArrayLike, b: ArrayLike, *, color: tuple[int, int, int] = (0, 160, 60)
    ) -> None:
        """Segments from ``a`` (N, 2) to ``b`` (N, 2), metres."""
        pa = np.asarray(a, dtype=np.float64).reshape(-1, 2)
        pb = np.asarray(b, dtype=np.float64).reshape(-1, 2)
        strips = np.stack([pa, pb], axis=1)
        self._rec.log(entity, self._rr.LineStrips2D(list(strips), colors=color, radii=0.02))

    def frame(self, entity: str, pose: ArrayLike) -> None:
        """Place ``entity`` at ``pose (x, y, theta)``: what is logged under it is in that frame."""
        x, y, th = (float(v) for v in np.asarray(pose, dtype=np.float64).reshape(3))
        c, s = math.cos(th), math.sin(th)
        mat = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
        self._rec.log(entity, self._rr.Transform3D(translation=[x, y, 0.0], mat3x3=mat))

    def ellipses(self, entity: str, means: ArrayLike, covs: ArrayLike) -> None:
        """2-sigma ellipses of 2-D Gaussians: means (N, 2), covariances (N, 2, 2)."""
        m = np.asarray(means, dtype=np.float64).reshape(-1, 2)
        c = np.asarray(covs, dtype=np.float64).reshape(-1, 2, 2)
        strips = [_ellipse(mi, ci) for mi, ci in zip(m, c, strict=True)]
        self._rec.log(entity, self._rr.LineStrips2D(strips, colors=(240, 140, 0), radii=0.02))

    def scalar(self, entity: str, value: float) -> None:
        """A number over the run (a plot in the viewer)."""
        self._rec.log(entity, self._rr.Scalars(float(value)))

    def close(self, *, keep: bool = True) -> None:
        """Flush and close the recording: the ``.rrd`` file is complete and in place
        afterwards (``keep=False``: the recording is deleted). Closing twice does nothing."""
        if self._rec is None:
            return
        self._rec.flush()
        self._rec.disconnect()
        self._rec = None
        if self._part is not None and self.file is not None:
            if keep:
                os.replace(self._part, self.file)
            else:
                self._part.unlink(missing_ok=True)

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        self.close(keep=exc_type is None)


def _scan_points(pose: NDArray, ranges: NDArray, angles: NDArray, max_range: float) -> NDArray:
    ok = np.isfinite(ranges) & (ranges > 0) & (ranges < max_range)
    r, a = ranges[ok], angles[ok] + pose[2]
    return np.column_stack([pose[0] + r * np.cos(a), pose[1] + r * np.sin(a)])


class _Throttled:
    """The observers' one rate limit: what grows with the run (the trajectory, the map ...) is
    logged at most once per ``interval`` seconds of wall time, so that watching costs about the
    same share of a long run as of a short one."""

    interval: float
    _last: float

    def _start_throttle(self, interval: float) -> None:
        require_at_least("interval", interval, 0, "s")
        self.interval = float(interval)
        self._last = -math.inf  # wall time of the last update of the growing items

    def _due(self) -> bool:
        """True (and the clock restarted) when ``interval`` has passed since the last time."""
        now = time.perf_counter()
        if now - self._last < self.interval:
            return False
        self._last = now
        return True


class GraphSlamObserver(_Throttled):
    """Streams a :class:`~probmap.slam.laser.submap_slam.SubmapSlam` run to a :class:`LiveView`.

    Called after every scan (``observer(index, slam, ranges, angles)``); it logs the newest
    node's scan every ``every`` nodes and each finished submap once. What grows with the run
    (the trajectory, the closures, the transforms of all submaps after an optimization) is
    logged at most once per ``interval`` seconds of wall time, so that watching costs about the
    same share of a long run as of a short one; :meth:`finish` logs the final state.

    Parameters
    ----------
    view : LiveView
    every : int
        Nodes between updates of the scan.
    interval : float
        Least wall time (seconds) between updates of the trajectory, closures and submap
        transforms (0: at every ``every``-th node and every optimization).
    """

    def __init__(self, view: LiveView, *, every: int = 5, interval: float = 1.0) -> None:
        require_at_least("every", every, 1)
        self._start_throttle(interval)
        self.view = view
        self.every = int(every)
        self._nodes = 0
        self._submaps = 0  # finished submaps logged
        self._optimizations = -1
        self._closures = 0

    def __call__(self, index: int, slam: Any, ranges: NDArray, angles: NDArray) -> None:
        v = self.view
        n = slam.nodes
        new_node = n > self._nodes
        self._nodes = n
        v.step(index)
        poses = slam.graph.poses
        self._new_submaps(slam, poses)
        if not (new_node and (n - 1) % self.every == 0):
            return
        v.points("world/scan", _scan_points(poses[n - 1], ranges, angles, slam.max_range))
        v.scalar("stats/closures", len(slam.closures))
        if not self._due():
            return
        v.path("world/trajectory", poses[:n, :2])
        if slam.optimizations != self._optimizations:
            # every pose moved: the submaps follow their anchors, the closures their ends
            self._optimizations = slam.optimizations
            for sm in slam.submaps[: self._submaps]:
                v.frame(f"world/submaps/{sm.index}", poses[sm.anchor])
            if len(slam.closures) > self._closures:
                edges = slam.closure_edges()
                v.segments("world/closures", poses[edges[:, 0], :2], poses[edges[:, 1], :2])
                self._closures = len(edges)

    def _new_submaps(self, slam: Any, poses: NDArray) -> None:
        """Log the submaps finished since the last call (in order), each in its anchor's
        frame."""
        v = self.view
        while self._submaps < len(slam.submaps) and slam.submaps[self._submaps].finished:
            sm = slam.submaps[self._submaps]
            v.points(
                f"world/submaps/{sm.index}",
                sm.occupied_points(),
                color=(215, 215, 215),
                radius=0.03,
            )
            v.frame(f"world/submaps/{sm.index}", poses[sm.anchor])
            self._submaps += 1

    def finish(self, run: Any) -> None:
        """The final map, trajectory, submaps and closures of the run (``SubmapSlamRun``)."""
        v = self.view
        v.step(len(run.times))
        self._new_submaps(run.slam, run.slam.graph.poses)
        for sm in run.slam.submaps[: self._submaps]:
            v.frame(f"world/submaps/{sm.index}", run.slam.graph.poses[sm.anchor])
        v.grid(run.grid)
        v.path("world/trajectory", run.sensor_poses[:, :2])
        if len(run.closures):
            p = run.node_poses  # closures are (node, anchor) pairs
            v.segments("world/closures", p[run.closures[:, 0], :2], p[run.closures[:, 1], :2])


class MappingObserver(_Throttled):
    """Streams ``probmap map`` (:func:`probmap.pipelines.map_log`) to a :class:`LiveView`.

    Called as ``observer(done, grid, trajectory, ranges, angles, max_range)`` after every few
    scans: it logs the newest scan's endpoints (``world/scan``) at every call and, at most once
    per ``interval`` seconds of wall time, the growing map (``world/map``) and the trajectory
    (``world/trajectory``); :meth:`finish` logs the final map and trajectory.

    Parameters
    ----------
    view : LiveView
    interval : float
        Least wall time (seconds) between updates of the map and trajectory (0: at every
        call). The map is an image of the whole grid, so it is the costly item.
    """

    def __init__(self, view: LiveView, *, interval: float = 1.0) -> None:
        self._start_throttle(interval)
        self.view = view

    def __call__(
        self, done: int, grid: Any, trajectory: NDArray, ranges: NDArray, angles: NDArray,
        max_range: float,
    ) -> None:  # fmt: skip
        v = self.view
        v.step(done)
        pose = np.asarray(trajectory[-1], dtype=np.float64)
        r = np.asarray(ranges, dtype=np.float64)
        v.points("world/scan", _scan_points(pose, r, np.asarray(angles, np.float64), max_range))
        if not self._due():
            return
        v.grid(grid)
        v.path("world/trajectory", np.asarray(trajectory)[:, :2])

    def finish(self, result: Any) -> None:
        """The final map and trajectory of a :class:`~probmap.pipelines.MappingResult`."""
        v = self.view
        v.step(int(result.stats.scans))
        v.grid(result.grid)
        if result.trajectory is not None and len(result.trajectory):
            v.path("world/trajectory", np.asarray(result.trajectory)[:, :2])


def _landmark_estimate(estimator: Any, copy_first: bool = True) -> tuple[NDArray, NDArray]:
    """Means (n, 2) and covariances (n, 2, 2) of the mapped landmarks, read from a copy
    (``copy_first``): ``landmarks()`` may change an estimator (SEIF stores the mean it
    recovers), and watching must not change the run."""
    source = copy.deepcopy(estimator) if copy_first else estimator
    _, xy, cov = source.landmarks()
    return np.asarray(xy, np.float64).reshape(-1, 2), np.asarray(cov, np.float64).reshape(-1, 2, 2)


class LandmarkSlamObserver(_Throttled):
    """Streams landmark SLAM (:func:`probmap.pipelines.landmark_slam.run_landmark_slam`) to a
    :class:`LiveView`.

    Called as ``observer(index, step, estimator)`` after every step. At most once per
    ``every`` steps (at the first step with measurements once ``every`` steps have passed, or
    after ``2 * every`` steps without any) it logs the robot (``world/robot``, its pose as a point and a heading segment
    ``world/robot/heading``) and the step's measurements as rays from the robot to where they
    put their landmarks (``world/measurements``; none logged for a step without any); at most
    once per ``interval`` seconds of wall time also the trajectory (``world/trajectory``), the
    reference so far (``world/reference``: ground truth of the records, when they carry it) and
    the map: landmark means (``world/landmarks``) and their 2-sigma ellipses
    (``world/landmarks/ellipses``; EKF and SEIF marginals, FastSLAM's heaviest particle).
    The map is read from a deep copy of the estimator, so that watching cannot change the run
    (SEIF's ``landmarks()`` stores the mean it recovers); an estimator that cannot be copied is
    asked directly (EKF and FastSLAM read without changing anything). A batch smoother
    (GraphSLAM, which has ``smooth()``) has no estimate before its solve: it shows only
    through :meth:`finish`, which logs the final solve like every estimator's final state.

    Parameters
    ----------
    view : LiveView
    measurement_model : object
        The dataset's range-bearing model (``inverse(pose, z) -> (landmark, ...)``).
    every : int
        Least steps between updates of the robot and measurements.
    interval : float
        Least wall time (seconds) between updates of the trajectory and map (0: at every
        update of the robot).
    reference : array_like, shape (K, 4), optional
        Ground truth as ``time, x, y, theta`` rows (a dataset's ``gt_trajectory``), drawn up
        to the current step's time when the steps carry no ``gt_pose`` of their own.
    """

    def __init__(
        self,
        view: LiveView,
        measurement_model: Any,
        *,
        every: int = 5,
        interval: float = 1.0,
        reference: ArrayLike | None = None,
    ) -> None:
        require_at_least("every", every, 1)
        self._start_throttle(interval)
        self.view = view
        self.model = measurement_model
        self.every = int(every)
        self._poses: list[NDArray] = []
        self._truth: list[NDArray] = []
        self._copyable = True  # False once a copy failed (state holding a module, a lock)
        self._shown: float = -math.inf  # the step last shown
        self.reference = None if reference is None else np.asarray(reference, np.float64)

    def _robot(self, pose: NDArray) -> None:
        v = self.view
        v.points("world/robot", pose[:2], color=(30, 100, 220), radius=0.15)
        tip = pose[:2] + 0.5 * np.array([math.cos(pose[2]), math.sin(pose[2])])
        v.segments("world/robot/heading", pose[:2], tip, color=(30, 100, 220))

    def __call__(self, index: int, step: Any, estimator: Any) -> None:
        if callable(getattr(estimator, "smooth", None)):
            return  # a batch smoother: nothing to show before the solve (see finish)
        pose = np.asarray(estimator.pose, dtype=np.float64).copy()
        self._poses.append(pose)
        if step.gt_pose is not None:
            self._truth.append(np.asarray(step.gt_pose, dtype=np.float64)[:2])
        z = np.asarray(step.z, dtype=np.float64).reshape(-1, 2)
        # at most one update per `every` steps: the first step with measurements once `every`
        # steps have passed, else the robot alone after `every` steps without any
        due = index - self._shown >= self.every
        if not (due and (z.shape[0] or index - self._shown >= 2 * self.every)):
            return
        self._shown = index
        v = self.view
        v.step(index)
        self._robot(pose)
        if z.shape[0]:
            ends = np.array([self.model.inverse(pose, zi)[0] for zi in z])
            v.segments("world/measurements", np.repeat(pose[None, :2], len(ends), 0), ends)
        if not self._due():
            return
        v.path("world/trajectory", np.asarray(self._poses)[:, :2])
        if self._truth:
            v.path("world/reference", np.asarray(self._truth), color=(120, 120, 120))
        elif self.reference is not None:
            ref = self.reference[self.reference[:, 0] <= step.time, 1:3]
            if len(ref) >= 2:
                v.path("world/reference", ref, color=(120, 120, 120))
        try:
            xy, cov = _landmark_estimate(estimator, self._copyable)
        except (TypeError, copy.Error):
            # no copy: ask the estimator itself (EKF and FastSLAM read without changing)
            self._copyable = False
            xy, cov = _landmark_estimate(estimator, False)
        if len(xy):
            v.points("world/landmarks", xy, color=(240, 140, 0), radius=0.08)
            v.ellipses("world/landmarks/ellipses", xy, cov)

    def finish(self, result: Any, dataset: Any = None, metrics: dict | None = None) -> None:
        """The final state of a run (a :class:`~probmap.pipelines.landmark_slam.SlamResult`):
        the trajectory (smoothed for GraphSLAM), the robot, the landmarks with their ellipses
        and the reference: the ground-truth path, the true landmarks
        (``world/landmark_truth``) and GPS fixes (``world/gps``, mapped into the estimate's
        frame by the inverse of the alignment in ``metrics["gps"]``) when there are any."""
        v = self.view
        traj = np.asarray(result.trajectory, dtype=np.float64)
        v.step(len(traj))
        if len(traj):
            v.path("world/trajectory", traj[:, 1:3])
            self._robot(traj[-1, 1:4])
        if len(result.landmark_xy):
            v.points("world/landmarks", result.landmark_xy, color=(240, 140, 0), radius=0.08)
            v.ellipses("world/landmarks/ellipses", result.landmark_xy, result.landmark_cov)
        ref = result.gt_poses
        if ref is None and dataset is not None and len(traj):
            gt = getattr(dataset, "gt_trajectory", None)
            if gt is not None and len(gt) >= 2:
                inside = (gt[:, 0] >= traj[0, 0]) & (gt[:, 0] <= traj[-1, 0])
                ref = np.asarray(gt)[inside, 1:3]
        if ref is not None:
            ok = np.all(np.isfinite(ref), axis=1)
            if ok.sum() >= 2:
                v.path("world/reference", np.asarray(ref)[ok, :2], color=(120, 120, 120))
        truth = getattr(dataset, "landmark_truth", None)
        if truth:
            v.points("world/landmark_truth", np.array(list(truth.values())), color=(0, 0, 0))
        gps = getattr(dataset, "gps", None)
        align = ((metrics or {}).get("gps") or {}).get("alignment")
        if gps is not None and align is not None and len(traj):
            g = np.asarray(gps, dtype=np.float64)
            g = g[(g[:, 0] >= traj[0, 0]) & (g[:, 0] <= traj[-1, 0]), 1:3]
            tx, ty, phi = (float(x) for x in np.asarray(align, dtype=np.float64).reshape(3))
            c, s = math.cos(phi), math.sin(phi)
            # estimate -> GPS: g = rot x + t, so x = rot^T (g - t)
            rot = np.array([[c, -s], [s, c]])
            v.points("world/gps", (g - [tx, ty]) @ rot, color=(120, 120, 120), radius=0.3)


def read_recording(path: str | os.PathLike[str]) -> dict[str, int]:
    """Entities of a ``.rrd`` recording and how many rows each has (for tests and checks).

    Returns
    -------
    dict
        ``{entity path: rows logged}``, for example ``{"/world/trajectory": 12, ...}``.
    """
    _rerun()
    from rerun.chunk import RrdReader

    counts: dict[str, int] = {}
    for chunk in RrdReader(Path(path)).store().stream():
        if chunk.is_static:
            continue
        counts[chunk.entity_path] = counts.get(chunk.entity_path, 0) + chunk.num_rows
    return counts


class LocalizationObserver(_Throttled):
    """Streams a Monte Carlo localization run
    (:func:`probmap.pipelines.localize.localize_scans`) to a :class:`LiveView`.

    On the first call it logs the map (``world/map``) and the reference trajectory
    (``world/reference``, when given). Called after every filter update (``observer(index,
    estimate, particles, ranges, angles)``), it logs every ``every`` updates the estimate
    (``world/estimate``), the scan's endpoints at the estimate (``world/scan``), at most
    ``max_particles`` particles (``world/particles``, an even subsample) and the spread
    (``stats/spread``, m); the estimated trajectory (``world/trajectory``) is logged at most
    once per ``interval`` seconds of wall time; :meth:`finish` logs it whole.

    Parameters
    ----------
    view : LiveView
    grid : OccupancyGrid or LocalizationMap
        The map: anything with ``spec``, ``log_odds`` and ``observed``.
    max_range : float
        Readings at or beyond it (m) are no return and not drawn.
    reference : (M, 2) or (M, 3) array_like, optional
        A reference path in the map frame (m), already clipped to the localized span.
    every : int
        Updates between logs of the particles, estimate and scan.
    max_particles : int
        Most particles logged per update (the viewer slows down with hundreds of thousands
        of points over a run).
    interval : float
        Least wall time (s) between logs of the growing trajectory (0: every ``every``-th
        update).
    """

    def __init__(
        self,
        view: LiveView,
        grid: Any,
        max_range: float,
        *,
        reference: ArrayLike | None = None,
        every: int = 1,
        max_particles: int = 500,
        interval: float = 1.0,
    ) -> None:
        require_at_least("every", every, 1)
        require_at_least("max_particles", max_particles, 1)
        self._start_throttle(interval)
        self.view = view
        self.grid = grid
        self.max_range = float(max_range)
        self.reference = (
            None if reference is None else np.asarray(reference, dtype=np.float64)[:, :2]
        )
        self.every = int(every)
        self.max_particles = int(max_particles)
        self.updates = 0
        self._path: list[NDArray[np.float64]] = []

    def __call__(
        self, index: int, estimate: Any, particles: NDArray, ranges: NDArray, angles: NDArray
    ) -> None:
        v = self.view
        v.step(index)
        if self.updates == 0:
            v.grid(self.grid)
            if self.reference is not None and len(self.reference):
                v.path("world/reference", self.reference, color=(40, 160, 60))
        self.updates += 1
        pose = np.asarray(estimate.best_cluster, dtype=np.float64)
        self._path.append(pose[:2].copy())
        if (self.updates - 1) % self.every:
            return
        n = len(particles)
        q = particles[:: max(1, -(-n // self.max_particles)), :2]
        # radii in UI points (negative): visible at any zoom, from a room to a campus
        v.points("world/particles", q, color=(240, 140, 0), radius=-1.5)
        v.points("world/estimate", pose[:2], color=(220, 40, 40), radius=-5.0)
        v.points("world/scan", _scan_points(pose, ranges, angles, self.max_range), radius=-1.5)
        v.scalar("stats/spread", estimate.spread)
        if self._due():
            v.path("world/trajectory", np.asarray(self._path), color=(220, 40, 40))

    def finish(self, run: Any) -> None:
        """The whole estimated trajectory of the run (``LocalizationRun``)."""
        if len(run.times) == 0:
            return
        self.view.step(int(run.scan_index[-1]))
        self.view.path("world/trajectory", run.poses[:, :2], color=(220, 40, 40))


__all__ += ["LocalizationObserver"]
