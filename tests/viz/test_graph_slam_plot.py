"""The graph-SLAM picture: the trajectory drawn over a light layer of closures, start and end
marked, a scale bar, the input's name and a subtitle of the run's numbers."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.figure import Figure

from probmap.grid.occupancy import OccupancyGrid
from probmap.grid.spec import GridSpec
from probmap.viz.laser_slam import graph_slam_subtitle, plot_graph_slam, save_graph_slam_figure


def fake_run(n_closures: int = 3000) -> SimpleNamespace:
    rng = np.random.default_rng(0)
    spec = GridSpec(0.1, (0.0, 0.0), (200, 300))
    grid = OccupancyGrid.from_log_odds(
        spec, rng.normal(0, 2, spec.shape).astype(np.float32),
        observed=rng.random(spec.shape) < 0.8,
    )  # fmt: skip
    s = np.linspace(0, 2 * np.pi, 400)
    poses = np.column_stack([15 + 10 * np.cos(s), 10 + 6 * np.sin(s), s])
    nodes = poses[::4]
    pairs = rng.integers(0, len(nodes), (n_closures, 2))
    weights = np.where(np.arange(n_closures) < 7, 0.1, 1.0)  # 7 down-weighted
    return SimpleNamespace(
        grid=grid, poses=poses, times=np.arange(400.0), node_poses=nodes, closures=pairs,
        closure_weights=weights, duration=1200.0, seconds=20.0,
    )  # fmt: skip


def test_trajectory_over_a_light_closure_layer_with_markers_and_scale():
    run = fake_run()
    ax = Figure().add_subplot()
    plot_graph_slam(ax, run, title="graph SLAM: intel.clf.bz2")
    green, red = ax.collections  # one collection per colour, not 3,000 lines
    assert len(green.get_segments()) == 2993 and len(red.get_segments()) == 7
    assert green.get_alpha() <= 0.2 and max(green.get_linewidths()) <= 0.5
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    traj = lines["trajectory"]
    np.testing.assert_allclose(traj.get_xydata(), run.poses[:, :2])
    assert traj.get_zorder() > green.get_zorder() and traj.get_zorder() > red.get_zorder()
    np.testing.assert_allclose(lines["start"].get_xydata(), run.poses[:1, :2])
    np.testing.assert_allclose(lines["end"].get_xydata(), run.poses[-1:, :2])
    texts = [t.get_text() for t in ax.texts]
    assert "5 m" in texts  # 30 m wide: a 5 m bar
    assert "400 scans, 3,000 loop closures (7 down-weighted), 60x real time" in texts
    assert ax.get_title(loc="left") == "graph SLAM: intel.clf.bz2"
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels[:5] == [
        "trajectory", "start", "end", "loop closures (2,993)", "down-weighted (7)"
    ]  # fmt: skip
    assert "unknown (never observed)" in labels


def test_subtitle_without_timestamps_has_no_real_time_factor():
    run = SimpleNamespace(times=np.zeros(5), closure_weights=np.ones(2), duration=0.0, seconds=1.0)
    assert graph_slam_subtitle(run) == "5 scans, 2 loop closures"


def test_save_writes_a_png(tmp_path):
    from PIL import Image

    out = save_graph_slam_figure(tmp_path / "g.plot.png", fake_run(10), title="x")
    with Image.open(out) as im:
        assert im.format == "PNG" and min(im.size) > 300


@pytest.mark.parametrize("n", [0])
def test_no_closures_no_poses(n):
    run = fake_run(n)
    run.poses = run.poses[:0]
    ax = Figure().add_subplot()
    plot_graph_slam(ax, run)
    assert [ln.get_label() for ln in ax.get_lines()] == []


def test_closures_the_pairwise_check_left_out_are_neither_drawn_nor_counted():
    from types import SimpleNamespace as NS

    from probmap.viz.laser_slam import graph_slam_subtitle

    loops = NS(left_out=np.array([False, True, False, True]))
    run = NS(times=np.zeros(100), closure_weights=np.array([1.0, 0.0, 0.3, 0.0]),
             duration=100.0, seconds=10.0, slam=NS(loops=loops))  # fmt: skip
    assert graph_slam_subtitle(run) == "100 scans, 2 loop closures (1 down-weighted), 10x real time"
    run.slam = None  # a run without the check: every closure counts
    assert graph_slam_subtitle(run).startswith("100 scans, 4 loop closures (3 down-weighted)")
