"""The live view (rerun): a recording is read back and checked against the run it shows; the
recording is all-or-nothing; ``slam grid --viz-save`` writes one; without rerun, one line."""

from __future__ import annotations

import builtins
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rerun")

from probmap.datasets.carmen import load_scans  # noqa: E402
from probmap.pipelines.laser_slam import load_laser_log, run_submap_slam  # noqa: E402
from probmap.viz.live import GraphSlamObserver, LiveView, _ellipse, read_recording  # noqa: E402


def last_value(path: Path, entity: str, component: str):
    """The value of ``component`` (``"LineStrips2D:strips"``) in the last row logged to
    ``entity`` on the ``scan`` timeline, as Python lists."""
    from rerun.chunk import RrdReader

    best = None
    for chunk in RrdReader(path).store().stream():
        if chunk.entity_path != entity or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        if component not in batch.schema.names:
            continue
        scans = batch.column("scan").to_pylist()
        values = batch.column(component)
        for k, t in enumerate(scans):
            if values[k].is_valid and (best is None or t >= best[0]):
                best = (t, values[k].as_py())
    assert best is not None, (entity, component)
    return best[1]


def test_recording_round_trip_and_all_or_nothing(tmp_path):
    rrd = tmp_path / "sub" / "run.rrd"  # a missing folder is created
    view = LiveView("probmap test", save=rrd)
    view.step(0)
    view.points("world/scan", [[0.0, 1.0], [2.0, 3.0]])
    view.step(1)
    view.path("world/trajectory", [[0.0, 0.0], [1.0, 0.5], [2.0, 1.0]])
    view.ellipses("world/landmarks", [[1.0, 1.0]], [np.diag([0.04, 0.01])])
    assert not rrd.exists()  # written beside it until closed
    view.close()
    assert rrd.exists() and not [p for p in rrd.parent.iterdir() if p != rrd]
    counts = read_recording(rrd)
    assert counts == {"/world/scan": 1, "/world/trajectory": 1, "/world/landmarks": 1}
    (strip,) = last_value(rrd, "/world/trajectory", "LineStrips2D:strips")
    np.testing.assert_allclose(strip, [[0.0, 0.0], [1.0, 0.5], [2.0, 1.0]])
    failed = tmp_path / "failed.rrd"
    with pytest.raises(RuntimeError), LiveView("probmap test", save=failed) as v:
        v.step(0)
        v.points("world/scan", [[0.0, 0.0]])
        raise RuntimeError("the run failed")
    assert list(tmp_path.iterdir()) == [tmp_path / "sub"]  # nothing left of the failed one
    with pytest.raises(ValueError, match="FILE.rrd"):
        LiveView("probmap test", save=tmp_path / "run.png")
    with pytest.raises(ValueError, match="save=FILE.rrd, spawn=True"):
        LiveView("probmap test")


def test_recording_carries_a_2d_layout_and_a_y_up_map_frame(tmp_path):
    """The recording brings its own layout: one 2-D view and one time-series plot, no 3-D
    view; and ``world`` is mirrored in y (a 2-D view is y-down, the map frame y-up)."""
    from rerun.chunk import RrdReader

    rrd = tmp_path / "run.rrd"
    with LiveView("probmap test", save=rrd) as view:
        view.step(0)
        view.points("world/scan", [[0.0, 1.0]])
    reader = RrdReader(rrd)
    (blueprint,) = reader.blueprints()
    kinds = []
    for chunk in reader.store(store=blueprint).stream():
        table = chunk.to_record_batch()
        if "ViewBlueprint:class_identifier" in table.schema.names:
            kinds += [k for row in table.column("ViewBlueprint:class_identifier").to_pylist()
                      for k in row]  # fmt: skip
    assert sorted(kinds) == ["2D", "TimeSeries"]
    scales = []
    for chunk in reader.store().stream():
        table = chunk.to_record_batch()
        if chunk.entity_path == "/world" and "Transform3D:scale" in table.schema.names:
            scales += table.column("Transform3D:scale").to_pylist()
    assert scales and np.allclose(np.asarray(scales[-1]).ravel(), [1.0, -1.0, 1.0])


def test_ellipse_is_the_two_sigma_contour():
    cov = np.array([[0.09, 0.03], [0.03, 0.04]])
    pts = _ellipse(np.array([1.0, -2.0]), cov)
    d = pts - [1.0, -2.0]
    m = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)
    np.testing.assert_allclose(m, 4.0, rtol=1e-9)  # Mahalanobis distance 2 everywhere


def test_graph_slam_recording_shows_the_run(tmp_path, sim_log):
    """Every finished submap once, the final trajectory and closures equal to the run's."""
    log = sim_log(tmp_path / "tour.log")
    batch = load_laser_log(log)
    rrd = tmp_path / "slam.rrd"
    with LiveView("probmap test", save=rrd) as view:
        observer = GraphSlamObserver(view, every=3)
        run = run_submap_slam(batch, observer=observer)
    plain = run_submap_slam(batch)  # watching does not change the result
    np.testing.assert_array_equal(run.sensor_poses, plain.sensor_poses)
    counts = read_recording(rrd)
    finished = [sm.index for sm in run.slam.submaps if sm.finished]
    assert {f"/world/submaps/{i}" for i in finished} <= set(counts)
    assert counts["/world/map"] >= 1 and counts["/world/scan"] >= run.nodes // 3
    (strip,) = last_value(rrd, "/world/trajectory", "LineStrips2D:strips")
    np.testing.assert_allclose(strip, run.sensor_poses[:, :2], atol=1e-9)
    if len(run.closures):
        segs = last_value(rrd, "/world/closures", "LineStrips2D:strips")
        assert len(segs) == len(run.closures)
        p = run.node_poses
        np.testing.assert_allclose(np.asarray(segs)[:, 0], p[run.closures[:, 0], :2], atol=1e-9)
    # the submap points are its occupied cells, in the anchor's frame
    sm = run.slam.submaps[finished[0]]
    pts = last_value(rrd, f"/world/submaps/{sm.index}", "Points2D:positions")
    np.testing.assert_allclose(np.asarray(pts), sm.occupied_points(), atol=1e-5)


def test_slam_grid_viz_save_on_the_cli(tmp_path, sim_log):
    from typer.testing import CliRunner

    from probmap.cli import register
    from probmap.cli.app import app

    register(app)
    log = sim_log(tmp_path / "tour.log")
    rrd = tmp_path / "rec" / "tour.rrd"
    res = CliRunner().invoke(
        app, ["slam", "grid", str(log), "-o", str(tmp_path / "out"), "--viz-save", str(rrd)]
    )
    assert res.exit_code == 0, res.output
    assert "recorded" in res.output and rrd.exists()
    n_scans = len(load_scans(log).times)
    counts = read_recording(rrd)
    # the final map once: its transform and its image are two rows of one entity
    assert counts["/world/map"] == 2
    # the trajectory every 5th node and once at the end
    assert counts["/world/trajectory"] >= 2 and counts["/world/trajectory"] <= n_scans // 5 + 2
    bad = CliRunner().invoke(
        app, ["slam", "grid", str(log), "-o", str(tmp_path / "o2"), "--viz-save", "x.png"]
    )
    assert bad.exit_code == 1 and "FILE.rrd" in bad.output and "Traceback" not in bad.output


def test_without_rerun_one_line(monkeypatch, tmp_path):
    real = builtins.__import__

    def no_rerun(name, *args, **kwargs):
        if name == "rerun" or name.startswith("rerun."):
            raise ImportError("No module named 'rerun'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_rerun)
    with pytest.raises(ImportError, match=r"pip install 'probmap\[viz\]'"):
        LiveView("probmap test", save=tmp_path / "x.rrd")
