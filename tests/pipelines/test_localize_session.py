"""Localizing in a graph-SLAM session (``probmap slam grid --save-session``): the session's map
is its occupancy grid at its optimized poses, and MCL over a later part of the same log follows
the session's own trajectory; a file that is neither a map nor a session is a one-line error."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from probmap.pipelines.localize import (
    LocalizeConfig,
    load_localization_map,
    localize_scans,
    trajectory_errors,
)


@pytest.fixture(scope="module")
def intel_session(tmp_path_factory):
    """A session of the first 70 s of the raw Intel log (about 360 scans, 1 s of SLAM), and
    those scans (a raw log's poses are the odometry; Intel's laser sits at the robot's centre)."""
    from conftest import _need as need
    from probmap.pipelines.laser_slam import load_laser_log, run_submap_slam

    path = need("intel-research-lab/intel.clf.bz2")
    session = tmp_path_factory.mktemp("session") / "intel.session"
    scans = load_laser_log(path, end_time=70.0)
    assert np.array_equal(scans.robot_poses, scans.laser_poses)
    run = run_submap_slam(scans, save_session=session)
    return session, run, scans


@pytest.mark.realdata
def test_session_map_is_the_runs_map_and_trajectory(intel_session):
    session, run, _ = intel_session
    m = load_localization_map(session)
    assert m.kind == "session" and m.source == session
    # what slam grid wrote beside the session: the same grid and trajectory
    assert m.spec.shape == run.grid.spec.shape
    np.testing.assert_allclose(m.spec.origin, run.grid.spec.origin)
    seen = run.grid.observed
    np.testing.assert_array_equal(np.isfinite(m.probability), seen)
    np.testing.assert_allclose(m.probability[seen], run.grid.probability()[seen], atol=1e-12)
    np.testing.assert_allclose(m.times, run.times)
    np.testing.assert_allclose(m.poses, run.sensor_poses, atol=1e-9)
    # drawn as a grid: log odds back to the same probability
    lo = m.log_odds[seen]
    np.testing.assert_allclose(1.0 - 1.0 / (1.0 + np.exp(lo)), m.probability[seen], atol=1e-9)


@pytest.mark.realdata
def test_mcl_in_a_session_follows_its_trajectory(intel_session):
    session, _, scans = intel_session
    m = load_localization_map(session)
    start = int(np.searchsorted(scans.times, scans.times[0] + 35.0))  # the second half
    pose0 = m.pose_at(float(scans.times[start]))
    assert pose0 is not None
    run = localize_scans(
        m.spec, m.probability, scans.times, scans.ranges, scans.angles, scans.robot_poses,
        scans.max_range, LocalizeConfig(n_particles=500, initial_pose=tuple(pose0)), start=start,
    )  # fmt: skip
    assert run.lost is None and run.times.size > 50
    err, head = trajectory_errors(run, m.times, m.poses)
    assert err.size >= run.times.size  # the session has a pose at every scan
    assert np.median(err) < 0.08 and np.percentile(err, 95) < 0.5
    assert np.median(np.degrees(head)) < 2.0
    # the odometry over the same stretch, put at the same start, drifts farther
    from probmap.geometry.se2 import between, compose

    odo = compose(pose0, between(scans.robot_poses[start], scans.robot_poses[run.scan_index]))
    drift = np.hypot(*(odo[:, :2] - m.poses[run.scan_index, :2]).T)
    assert np.median(drift) > 2 * np.median(err)


@pytest.mark.parametrize(
    "content",
    [
        b"FLASER 3 1 2 3 0 0 0 0 0 0 1.0 host 1.0\n",  # a log
        b"\x89PNG\r\n\x1a\n" + bytes(100),  # an image
        b"PK\x03\x04" + bytes(100),  # a broken zip
    ],
)
def test_neither_map_nor_session_is_one_line(tmp_path, content):
    bad = tmp_path / "thing.bin"
    bad.write_bytes(content)
    with pytest.raises(ValueError) as info:
        load_localization_map(bad)
    msg = str(info.value)
    assert "\n" not in msg and str(bad) in msg
    assert "neither a map_server YAML map" in msg and "session" in msg
    with pytest.raises(FileNotFoundError, match="no such map or session file"):
        load_localization_map(tmp_path / "missing.session")


@pytest.mark.parametrize(
    "content",
    [
        pickle.dumps({"format": "something else"}),  # a pickle, but no session
        pickle.dumps([1, 2, 3])[:5],  # a truncated pickle
    ],
)
def test_a_pickle_is_never_loaded_and_named_as_an_old_session(tmp_path, content):
    """Sessions were pickles once: any pickle is refused unread, with a line to re-run."""
    bad = tmp_path / "thing.bin"
    bad.write_bytes(content)
    with pytest.raises(ValueError) as info:
        load_localization_map(bad)
    msg = str(info.value)
    assert "\n" not in msg and str(bad) in msg
    assert "pickle" in msg and "re-run probmap slam grid --save-session" in msg
