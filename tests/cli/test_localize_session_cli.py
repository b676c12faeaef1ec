"""``probmap localize --map SESSION`` on a simulated tour: the session of ``probmap slam grid
--save-session`` is the map, its trajectory the reference; ``--viz-save`` records the run
(read back and checked against trajectory.csv); bad maps and arguments are one-line errors."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.pipelines.sessions import load_session

register(app)
runner = CliRunner()


def run(*args: object):
    return runner.invoke(app, [str(a) for a in args])


def write_log(path, n: int = 120):
    """A CARMEN log of the seeded localization world (a building with clutter): 60 beams over
    180 degrees from the true poses, 1 cm noise, and the world's drifting odometry."""
    from probmap.models.beam import BeamModel
    from probmap.sim.localization import simulate_localization_world

    world = simulate_localization_world(0)
    angles = -np.pi / 2 + np.arange(60) * np.pi / 60
    ranges = BeamModel(world.spec, world.occupied, max_range=8.0).expected_ranges(
        world.poses[:n], angles
    )
    noise = np.random.default_rng(0).normal(0, 0.01, ranges.shape)
    ranges = np.where(ranges < 8.0, ranges + noise, 8.0)
    lines = ["PARAM robot_front_laser_max 8.0"]
    for k in range(n):
        r = " ".join(f"{v:.3f}" for v in ranges[k])
        odo = " ".join(f"{v:.5f}" for v in world.odometry[k])
        t = 100.0 + 0.2 * k
        lines.append(f"FLASER 60 {r} {odo} {odo} {t:.6f} sim {t:.6f}")
    path.write_text("\n".join(lines) + "\n")
    return path


def last_value(path, entity: str, component: str):
    """The last value of ``component`` logged to ``entity`` on the ``scan`` timeline."""
    from rerun.chunk import RrdReader

    best = None
    for chunk in RrdReader(path).store().stream():
        if chunk.entity_path != entity or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        if component not in batch.schema.names:
            continue
        for t, value in zip(batch.column("scan").to_pylist(), batch.column(component), strict=True):
            if value.is_valid and (best is None or t >= best[0]):
                best = (t, value.as_py())
    assert best is not None, (entity, component)
    return best[1]


def test_localize_in_a_session_with_a_recording(tmp_path):
    pytest.importorskip("rerun")
    from probmap.pipelines.laser_slam import load_laser_log, run_submap_slam
    from probmap.viz.live import read_recording

    log = write_log(tmp_path / "tour.log")
    session = tmp_path / "tour.session"  # what slam grid --save-session writes
    # the session covers the first 90 of the log's 120 scans; the localization all of them
    run_submap_slam(load_laser_log(log, end_time=17.9), save_session=session)
    out, rrd = tmp_path / "loc", tmp_path / "rec" / "loc.rrd"
    res = run("localize", log, "--map", session, "-o", out, "-n", "300", "--viz-save", rrd)
    assert res.exit_code == 0, res.output
    assert "error against the session's trajectory" in res.output
    assert "(read " in res.output and "compute " in res.output and "write " in res.output
    traj = np.loadtxt(out / "trajectory.csv", delimiter=",", skiprows=1, ndmin=2)
    # against the session's own trajectory (computed here, not by the command)
    slam = load_session(session)
    slam.finish()
    t, poses = slam.trajectory()
    assert len(t) == 90
    inside = traj[:, 0] <= t[-1] + 1e-6
    assert inside.sum() > 60 and (~inside).sum() > 20  # it went on beyond the session
    idx = np.searchsorted(t, traj[inside, 0] - 1e-6)
    np.testing.assert_allclose(t[idx], traj[inside, 0], atol=1e-6)
    err = np.hypot(*(traj[inside, 1:3] - poses[idx, :2]).T)
    assert np.median(err) < 0.05 and err.max() < 0.3
    # and kept track to the end; beyond the session's map the scans hold less evidence and
    # the tempered cloud (10 independent beams) widens, as it should, to under a metre
    assert np.all(traj[:, 4] < 1.0)
    # the recording: one row per update of the particles, estimate, scan and spread; the map
    # (transform and image) and the reference once; the trajectory at least at the end
    counts = read_recording(rrd)
    n = traj.shape[0]
    for entity in ("particles", "estimate", "scan"):
        assert counts[f"/world/{entity}"] == n, entity
    assert counts["/stats/spread"] == n
    assert counts["/world/map"] == 2 and counts["/world/reference"] == 1
    assert 1 <= counts["/world/trajectory"] <= n + 1
    (strip,) = last_value(rrd, "/world/trajectory", "LineStrips2D:strips")
    np.testing.assert_allclose(strip, traj[:, 1:3], atol=1e-5)
    # the same map as a positional argument: the same run (its first 30 scans)
    res = run("localize", session, log, "-o", tmp_path / "loc2", "-n", "300", "--stop", "30")
    assert res.exit_code == 0, res.output
    again = np.loadtxt(tmp_path / "loc2" / "trajectory.csv", delimiter=",", skiprows=1, ndmin=2)
    assert 10 < len(again) < len(traj)
    np.testing.assert_array_equal(again, traj[: len(again)])
    # a part of the log the session does not cover: no error table, no error
    res = run("localize", session, log, "-o", tmp_path / "loc3", "-n", "300", "--start", "95")
    assert res.exit_code == 0, res.output
    assert "error against" not in res.output and (tmp_path / "loc3" / "trajectory.csv").exists()


def test_bad_map_or_arguments_are_one_line(tmp_path):
    log = write_log(tmp_path / "tour.log", n=5)
    png = tmp_path / "map.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(64))
    cases = [
        (("localize", log, "--map", png, "-o", tmp_path / "o"), "neither a map_server YAML map"),
        (("localize", log, "--map", tmp_path / "no.session", "-o", tmp_path / "o"), "no.session"),
        (("localize", png, log, "--map", png, "-o", tmp_path / "o"), "--map names the map"),
        (("localize", log, "-o", tmp_path / "o"), "missing the LOG argument"),
        (("localize", png, log, "-o", tmp_path / "o", "--viz-save", "x.png"), "FILE.rrd"),
    ]
    for args, expected in cases:
        res = run(*args)
        assert res.exit_code == 1, (args, res.output)
        assert expected in res.output and "Traceback" not in res.output, res.output
        assert res.output.strip().count("\n") == 0, res.output
    assert not (tmp_path / "o").exists()
