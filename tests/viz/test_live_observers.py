"""The live view of ``probmap map`` and of landmark SLAM: recordings read back and checked
against the run they show (what was logged, how often, and the final values), and watching
does not change the run."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rerun")

from probmap.datasets.simulation import simulate_landmarks  # noqa: E402
from probmap.pipelines import MappingConfig, map_log  # noqa: E402
from probmap.pipelines.landmark_slam import run_landmark_slam  # noqa: E402
from probmap.viz.live import (  # noqa: E402
    LandmarkSlamObserver,
    LiveView,
    MappingObserver,
    read_recording,
)


def rows_of(path: Path, entity: str, component: str) -> list[tuple[int, object]]:
    """Every ``(scan, value)`` row of ``component`` (e.g. ``"Points2D:positions"``) logged to
    ``entity`` on the ``scan`` timeline, in timeline order."""
    from rerun.chunk import RrdReader

    out = []
    for chunk in RrdReader(path).store().stream():
        if chunk.entity_path != entity or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        if component not in batch.schema.names:
            continue
        values = batch.column(component)
        for k, t in enumerate(batch.column("scan").to_pylist()):
            if values[k].is_valid:
                out.append((t, values[k].as_py()))
    return sorted(out, key=lambda r: r[0])


# ----------------------------------------------------------------------------- mapping
def test_map_recording_shows_the_map_growing(tmp_path, sim_log):
    log = sim_log(tmp_path / "tour.log")
    cfg = MappingConfig(resolution=0.1)
    rrd = tmp_path / "map.rrd"
    with LiveView("probmap test", save=rrd) as view:
        observer = MappingObserver(view, interval=0.0)  # every call: exact counts
        watched = map_log(log, cfg, observer=observer, observe_every=7)
        observer.finish(watched)
    plain = map_log(log, cfg)  # one chunk of 1,000 scans: the same map
    np.testing.assert_array_equal(watched.grid.log_odds, plain.grid.log_odds)
    assert watched.grid.spec.shape == plain.grid.spec.shape
    # the grid grew in other steps: the same origin up to rounding, so a ray that ends on a
    # cell border may walk one cell more or less (the counts, not the map)
    np.testing.assert_allclose(watched.grid.spec.origin, plain.grid.spec.origin, atol=1e-9)
    assert watched.stats.beams == plain.stats.beams and watched.stats.hits == plain.stats.hits
    assert abs(watched.stats.cell_updates - plain.stats.cell_updates) <= 1e-4 * plain.stats.beams
    n = plain.stats.scans
    calls = math.ceil(n / 7)
    counts = read_recording(rrd)
    # the map: a transform and an image per call and at the end
    assert counts == {
        "/world/scan": calls,
        "/world/map": 2 * (calls + 1),
        "/world/trajectory": calls + 1,
    }
    scans = rows_of(rrd, "/world/scan", "Points2D:positions")
    assert [t for t, _ in scans] == [min(7 * (k + 1), n) for k in range(calls)]
    # the newest scan's endpoints: the last scan's valid ranges from its pose
    from probmap.datasets.carmen import load_scans

    batch = load_scans(log)
    pose, r = batch.laser_poses[-1], batch.ranges[-1]
    ok = np.isfinite(r) & (r > 0) & (r < batch.max_range)
    a = batch.angles[ok] + pose[2]
    expect = np.column_stack([pose[0] + r[ok] * np.cos(a), pose[1] + r[ok] * np.sin(a)])
    np.testing.assert_allclose(np.asarray(scans[-1][1]), expect, atol=1e-4)
    (strip,) = rows_of(rrd, "/world/trajectory", "LineStrips2D:strips")[-1][1]
    np.testing.assert_allclose(strip, plain.trajectory[:, :2], atol=1e-5)


def test_map_log_stops_when_asked(tmp_path, sim_log):
    """stop() before the k-th chunk: the map of the first (k - 1) chunks, flagged."""
    log = sim_log(tmp_path / "tour.log")
    asked = [0]

    def stop() -> bool:
        asked[0] += 1
        return asked[0] > 3

    cut = map_log(log, MappingConfig(resolution=0.1, chunk=25), stop=stop)
    assert cut.interrupted and cut.stats.scans == 75 and cut.trajectory.shape == (75, 3)
    full = map_log(log, MappingConfig(resolution=0.1))
    assert cut.scans_total == full.stats.scans and not full.interrupted
    lines = log.read_text().splitlines()
    first = tmp_path / "first.log"
    first.write_text("\n".join(lines[:76]) + "\n")  # PARAM line and 75 scans
    ref = map_log(first, MappingConfig(resolution=0.1, chunk=25))  # the same chunks
    np.testing.assert_array_equal(cut.grid.log_odds, ref.grid.log_odds)
    assert cut.stats == ref.stats
    with pytest.raises(ValueError, match="observe_every"):
        map_log(log, observe_every=0)


# ----------------------------------------------------------------------- landmark SLAM
def shown_steps(steps, every: int) -> list[int]:
    """The steps the observer shows: at most one per ``every``, the first with measurements
    once ``every`` have passed, or one after ``2 * every`` without any."""
    out: list[int] = []
    last = -math.inf
    for i, step in enumerate(steps):
        if i - last >= every and (len(step.z) or i - last >= 2 * every):
            out.append(i)
            last = i
    return out


def _ekf(ds):
    from probmap.slam.landmark.ekf import EKFSLAM

    return EKFSLAM(ds.motion_model, ds.measurement_model, ds.initial_pose, ds.initial_covariance)


def _ellipse_distances(strip, mean, cov) -> np.ndarray:
    d = np.asarray(strip) - mean
    return np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)


def test_ekf_recording_shows_robot_measurements_landmarks_and_truth(tmp_path):
    ds = simulate_landmarks(15, 80, seed=3, max_range=4.0)  # 20 steps with measurements
    rrd = tmp_path / "ekf.rrd"
    with LiveView("probmap test", save=rrd) as view:
        observer = LandmarkSlamObserver(view, ds.measurement_model, every=5, interval=0.0)
        result = run_landmark_slam(_ekf(ds), ds, observer=observer)
        observer.finish(result, ds)
    plain = run_landmark_slam(_ekf(ds), ds)
    np.testing.assert_array_equal(result.trajectory, plain.trajectory)  # watching changes nothing
    steps = list(ds)
    shown = shown_steps(steps, 5)
    with_z = [i for i in shown if len(steps[i].z)]
    # the reference of the observer: the filter stepped by hand, its map at the shown steps
    ekf, maps = _ekf(ds), {}
    for i, step in enumerate(steps):
        ekf.predict(step.control, step.dt)
        ekf.update(step.z, step.ids)
        if i in shown and len(ekf.landmarks()[0]):
            maps[i] = ekf.landmarks()
    assert len(maps) > len(shown) // 2  # the filter maps what it sees
    counts = read_recording(rrd)
    assert counts == {
        "/world/robot": len(shown) + 1,
        "/world/robot/heading": len(shown) + 1,
        "/world/measurements": len(with_z),
        "/world/trajectory": len(shown) + 1,
        "/world/reference": len(shown) + 1,
        "/world/landmarks": len(maps) + 1,
        "/world/landmarks/ellipses": len(maps) + 1,
        "/world/landmark_truth": 1,
    }
    assert 0 < len(with_z) < len(shown)  # both kinds of update
    assert all(b - a >= 5 for a, b in zip(shown, shown[1:], strict=False))
    # the rays of a step end where the inverse model puts its measurements
    k = with_z[len(with_z) // 2]
    rays = dict(rows_of(rrd, "/world/measurements", "LineStrips2D:strips"))[k]
    pose = result.trajectory[k, 1:]
    ends = [ds.measurement_model.inverse(pose, z)[0] for z in steps[k].z]
    np.testing.assert_allclose(np.asarray(rays)[:, 1], ends, atol=1e-4)
    np.testing.assert_allclose(np.asarray(rays)[:, 0], np.tile(pose[:2], (len(ends), 1)), atol=1e-4)
    # the final trajectory, reference and landmarks are the run's
    (strip,) = rows_of(rrd, "/world/trajectory", "LineStrips2D:strips")[-1][1]
    np.testing.assert_allclose(strip, result.trajectory[:, 1:3], atol=1e-4)
    (ref,) = rows_of(rrd, "/world/reference", "LineStrips2D:strips")[-1][1]
    np.testing.assert_allclose(ref, result.gt_poses[:, :2], atol=1e-4)
    t, means = rows_of(rrd, "/world/landmarks", "Points2D:positions")[-1]
    np.testing.assert_allclose(means, result.landmark_xy, atol=1e-4)
    t, ellipses = rows_of(rrd, "/world/landmarks/ellipses", "LineStrips2D:strips")[-1]
    assert len(ellipses) == len(result.landmark_xy)
    for strip, m, c in zip(ellipses, result.landmark_xy, result.landmark_cov, strict=True):
        np.testing.assert_allclose(_ellipse_distances(strip, m, c), 4.0, rtol=1e-3)  # 2 sigma
    # the landmarks during the run are the filter's at that step
    during = dict(rows_of(rrd, "/world/landmarks", "Points2D:positions"))
    assert set(during) == {*maps, len(steps)}
    for i, (_, xy, _) in maps.items():
        np.testing.assert_allclose(during[i], xy, atol=1e-4)


def test_reference_from_a_ground_truth_trajectory(tmp_path):
    """Steps without a gt_pose: the observer draws the reference up to each step's time."""
    from dataclasses import replace

    ds = simulate_landmarks(10, 40, seed=5)
    ds = replace(ds, steps=[replace(s, gt_pose=None) for s in ds])
    rrd = tmp_path / "ref.rrd"
    with LiveView("probmap test", save=rrd) as view:
        obs = LandmarkSlamObserver(
            view, ds.measurement_model, every=10, interval=0.0, reference=ds.gt_trajectory
        )
        run_landmark_slam(_ekf(ds), ds, observer=obs)
    steps = list(ds)
    for t, (strip,) in rows_of(rrd, "/world/reference", "LineStrips2D:strips"):
        gt = ds.gt_trajectory
        np.testing.assert_allclose(strip, gt[gt[:, 0] <= steps[t].time, 1:3], atol=1e-5)


def _first_steps(ds, k: int):
    from dataclasses import replace

    return replace(ds, steps=list(ds)[:k])


def test_watching_a_seif_does_not_change_it(tmp_path):
    """SEIF's landmarks() stores the mean it recovers; the observer reads a copy."""
    from probmap.slam.landmark.seif import SeifConfig, build_seif

    ds = simulate_landmarks(15, 80, seed=1)
    rrd = tmp_path / "seif.rrd"
    with LiveView("probmap test", save=rrd) as view:
        observer = LandmarkSlamObserver(view, ds.measurement_model, every=4, interval=0.0)
        watched = run_landmark_slam(build_seif(ds, SeifConfig(max_active=4)), ds, observer=observer)
    plain = run_landmark_slam(build_seif(ds, SeifConfig(max_active=4)), ds)
    np.testing.assert_array_equal(watched.trajectory, plain.trajectory)
    np.testing.assert_array_equal(watched.landmark_xy, plain.landmark_xy)
    shown = shown_steps(list(ds), 4)
    assert read_recording(rrd)["/world/landmarks/ellipses"] == len(shown)  # a map from step 0


def test_watching_fastslam_does_not_change_it(tmp_path):
    """The heaviest particle's map, read during the run, leaves the particles as they were."""
    from probmap.slam.landmark.fastslam import FastSLAM, FastSLAMConfig

    ds = simulate_landmarks(10, 60, seed=6)

    def fresh() -> FastSLAM:
        cfg = FastSLAMConfig(n_particles=8, seed=2)
        return FastSLAM(ds.motion_model, ds.measurement_model, ds.initial_pose, cfg)

    rrd = tmp_path / "fastslam.rrd"
    with LiveView("probmap test", save=rrd) as view:
        observer = LandmarkSlamObserver(view, ds.measurement_model, every=3, interval=0.0)
        watched = run_landmark_slam(fresh(), ds, observer=observer)
    plain = run_landmark_slam(fresh(), ds)
    np.testing.assert_array_equal(watched.trajectory, plain.trajectory)
    np.testing.assert_array_equal(watched.landmark_xy, plain.landmark_xy)
    _, means = rows_of(rrd, "/world/landmarks", "Points2D:positions")[-1]
    assert len(means) > 0


def test_graphslam_shows_its_final_solve(tmp_path):
    from probmap.slam.landmark.graphslam import build_graphslam

    ds = simulate_landmarks(15, 60, seed=2)
    rrd = tmp_path / "graph.rrd"
    with LiveView("probmap test", save=rrd) as view:
        observer = LandmarkSlamObserver(view, ds.measurement_model, every=1, interval=0.0)
        result = run_landmark_slam(build_graphslam(ds), ds, observer=observer)
        observer.finish(result, ds)
    counts = read_recording(rrd)
    # nothing before the solve (a batch smoother has no estimate), then the solve once
    assert counts["/world/trajectory"] == 1 and counts["/world/landmarks"] == 1
    assert "/world/measurements" not in counts
    (strip,) = rows_of(rrd, "/world/trajectory", "LineStrips2D:strips")[-1][1]
    np.testing.assert_allclose(strip, result.trajectory[:, 1:3], atol=1e-4)


def test_run_stops_when_asked_and_equals_the_shorter_run():
    ds = simulate_landmarks(20, 100, seed=4)
    asked = [0]

    def stop() -> bool:
        asked[0] += 1
        return asked[0] > 40

    cut = run_landmark_slam(_ekf(ds), ds, stop=stop)
    assert cut.interrupted and cut.steps_total == 100 and cut.trajectory.shape == (40, 4)
    head = run_landmark_slam(_ekf(ds), _first_steps(ds, 40))
    assert not head.interrupted and head.steps_total == 40
    np.testing.assert_array_equal(cut.trajectory, head.trajectory)
    np.testing.assert_array_equal(cut.landmark_xy, head.landmark_xy)


def test_gps_is_drawn_in_the_estimate_frame(tmp_path):
    """GPS fixes go through the inverse of the metrics' alignment (estimate -> GPS)."""
    from types import SimpleNamespace

    rrd = tmp_path / "gps.rrd"
    traj = np.column_stack([np.arange(5.0), np.arange(5.0), np.zeros(5), np.zeros(5)])
    result = SimpleNamespace(
        trajectory=traj, landmark_xy=np.zeros((0, 2)), landmark_cov=np.zeros((0, 2, 2)),
        gt_poses=None,
    )  # fmt: skip
    t, phi = np.array([3.0, -1.0]), 0.4
    rot = np.array([[np.cos(phi), -np.sin(phi)], [np.sin(phi), np.cos(phi)]])
    est = traj[:, 1:3]
    gps = np.column_stack([traj[:, 0], est @ rot.T + t])  # the estimate seen in the GPS frame
    ds = SimpleNamespace(gps=gps, measurement_model=None)
    with LiveView("probmap test", save=rrd) as view:
        obs = LandmarkSlamObserver(view, None)
        obs.finish(result, ds, {"gps": {"alignment": [t[0], t[1], phi]}})
    (_, pts) = rows_of(rrd, "/world/gps", "Points2D:positions")[-1]
    np.testing.assert_allclose(pts, est, atol=1e-5)
