"""The MCL picture (viz.localize): no line across a jump of the estimate, nothing drawn before
the filter converged but faint dots, the reference clipped to the localized span; and the live
view of a localization run (viz.live.LocalizationObserver), read back from its recording."""

from __future__ import annotations

import math

import numpy as np
import pytest
from matplotlib.figure import Figure

from probmap.grid.occupancy import OccupancyGrid
from probmap.grid.spec import GridSpec
from probmap.viz.localize import (
    converged_index,
    plot_localization,
    save_localization_figure,
    split_at_jumps,
)


def reference_split(xy, max_step):
    """Obviously correct: walk the points, start a new piece after a long step."""
    pieces, cur = [], []
    for p in xy:
        if cur and math.dist(cur[-1], p) > max_step:
            pieces.append(cur)
            cur = []
        cur.append(list(p))
    return pieces + ([cur] if cur else [])


def reference_converged(spread, threshold, hold):
    for i in range(len(spread)):
        window = spread[i : i + hold]
        if all(s <= threshold for s in window):  # hold updates, or all that are left
            return i
    return len(spread)


@pytest.mark.parametrize("seed", range(5))
def test_split_and_convergence_match_plain_loops(seed):
    rng = np.random.default_rng(seed)
    steps = np.where(rng.random((60, 1)) < 0.1, 3.0, 0.1) * rng.normal(size=(60, 2))
    xy = np.cumsum(steps, axis=0)
    got = split_at_jumps(xy, 1.0)
    want = reference_split(xy.tolist(), 1.0)
    assert [len(p) for p in got] == [len(p) for p in want]
    np.testing.assert_array_equal(np.concatenate(got), xy)
    spread = np.where(rng.random(40) < 0.2, 5.0, 0.2)
    for hold in (1, 3, 10):
        got = converged_index(spread, 1.0, hold)
        assert got == reference_converged(spread.tolist(), 1.0, hold)
    assert converged_index(spread[:0]) == 0
    with pytest.raises(ValueError, match="hold"):
        converged_index(spread, 1.0, 0)
    with pytest.raises(ValueError, match="max_step"):
        split_at_jumps(xy, 0.0)


def test_plot_draws_no_jump_and_clips_the_reference():
    grid = OccupancyGrid(0.1, spec=GridSpec.around(0.1, -1.0, 21.0, -1.0, 11.0))
    # a global localization: 5 wandering estimates (spread 8 m), then it converges on a
    # straight path, jumps once by 6 m (a relocalization) and goes on
    t = np.arange(25, dtype=float)
    early = np.array([[2.0, 9.0], [15.0, 2.0], [8.0, 8.0], [1.0, 1.0], [18.0, 9.0]])
    path = np.column_stack([np.linspace(2.0, 12.0, 20), np.full(20, 5.0)])
    path[12:, 1] += 6.0  # a jump of 6 m up after the 12th converged update
    xy = np.vstack([early, path])
    poses = np.column_stack([xy, np.zeros(25)])
    spread = np.r_[np.full(5, 8.0), np.full(20, 0.1)]
    ref_t = np.arange(-10.0, 40.0, 0.5)  # spans far more than the run
    ref_p = np.column_stack([ref_t * 0.5, np.full_like(ref_t, 5.0), np.zeros_like(ref_t)])
    ax = Figure().add_subplot()
    plot_localization(ax, grid, t, poses, spread, reference=(ref_t, ref_p), max_step=1.0)
    lines = {}
    for line in ax.get_lines():
        lines.setdefault(line.get_color(), []).append(line)
    mcl = [ln for ln in lines["tab:red"] if ln.get_linestyle() == "-"]
    assert len(mcl) == 2  # broken at the jump
    for ln in mcl:
        d = np.hypot(*np.diff(np.column_stack(ln.get_data()), axis=0).T)
        assert d.max() <= 1.0
    drawn = np.vstack([np.column_stack(ln.get_data()) for ln in mcl])
    np.testing.assert_array_equal(drawn, path)  # from convergence on, every estimate
    dots = [ln for ln in lines["tab:red"] if ln.get_linestyle() == "None"]
    np.testing.assert_array_equal(np.column_stack(dots[0].get_data()), early)
    (ref,) = lines["tab:green"]
    rx = ref.get_data()[0]
    keep = (ref_t >= t[5]) & (ref_t <= t[-1])  # the converged span only
    np.testing.assert_array_equal(rx, ref_p[keep, 0])


def test_figure_is_written(tmp_path):
    grid = OccupancyGrid(0.1, spec=GridSpec.around(0.1, 0.0, 5.0, 0.0, 5.0))
    poses = np.column_stack([np.linspace(1, 4, 10), np.full(10, 2.0), np.zeros(10)])
    out = save_localization_figure(
        tmp_path / "t.png", grid, np.arange(10.0), poses, np.full(10, 0.1),
        particles=poses + 0.05,
    )  # fmt: skip
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(ValueError, match="one row per update"):
        save_localization_figure(tmp_path / "u.png", grid, np.arange(3.0), poses, np.ones(10))
    assert not (tmp_path / "u.png").exists()


def test_localization_recording_is_throttled_and_complete(tmp_path):
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    from probmap.models.beam import BeamModel
    from probmap.pipelines.localize import LocalizeConfig, localize_scans
    from probmap.sim.localization import simulate_localization_world
    from probmap.viz.live import LiveView, LocalizationObserver, read_recording

    w = simulate_localization_world(0)
    n = 60
    angles = -np.pi / 2 + np.arange(60) * np.pi / 60
    ranges = BeamModel(w.spec, w.occupied, max_range=8.0).expected_ranges(w.poses[:n], angles)
    args = (w.spec, w.occupied, np.arange(n) * 0.2, ranges, angles, w.poses[:n], 8.0)
    cfg = LocalizeConfig(n_particles=700)
    rrd = tmp_path / "mcl.rrd"
    with LiveView("probmap test", save=rrd) as view:
        obs = LocalizationObserver(
            view, _grid(w), 8.0,
            reference=w.poses[:n], every=3, max_particles=200, interval=0.0,
        )  # fmt: skip
        run = localize_scans(*args, cfg, observer=obs)
    plain = localize_scans(*args, cfg)  # watching does not change the run
    np.testing.assert_array_equal(run.poses, plain.poses)
    updates = run.times.size
    assert obs.updates == updates
    counts = read_recording(rrd)
    shown = -(-updates // 3)  # every third update
    for entity in ("/world/particles", "/world/estimate", "/world/scan", "/stats/spread"):
        assert counts[entity] == shown, entity
    assert counts["/world/trajectory"] == shown + 1  # and the whole one at the end
    assert counts["/world/map"] == 2 and counts["/world/reference"] == 1
    sizes = []
    for chunk in RrdReader(rrd).store().stream():
        if chunk.entity_path == "/world/particles" and not chunk.is_static:
            col = chunk.to_record_batch().column("Points2D:positions")
            sizes += [len(v.as_py()) for v in col if v.is_valid]
    assert len(sizes) == shown and max(sizes) <= 200 and min(sizes) >= 100


def _grid(world):
    """The world's occupancy as an OccupancyGrid-like (spec, log_odds, observed)."""
    from types import SimpleNamespace

    occ = np.asarray(world.occupied, dtype=bool)
    return SimpleNamespace(
        spec=world.spec, log_odds=np.where(occ, 5.0, -5.0), observed=np.ones_like(occ)
    )


def test_legend_is_below_the_map_in_readable_type():
    """The legend names every layer and the map's colours, in 8 pt or more, and lies under
    the axes: it hides no part of the map."""
    grid = OccupancyGrid(0.1, spec=GridSpec.around(0.1, 0.0, 5.0, 0.0, 5.0))
    poses = np.column_stack([np.linspace(1, 4, 10), np.full(10, 2.0), np.zeros(10)])
    fig = Figure()
    ax = fig.add_subplot()
    plot_localization(
        ax, grid, np.arange(10.0), poses, np.r_[np.full(3, 5.0), np.full(7, 0.1)],
        particles=poses, converged=3,
    )  # fmt: skip
    leg = ax.get_legend()
    labels = [t.get_text() for t in leg.get_texts()]
    assert labels[:3] == ["particles", "before convergence (3 updates)", "MCL"]
    assert {"start", "end", "free", "occupied", "unknown (never observed)"} <= set(labels)
    assert min(t.get_fontsize() for t in leg.get_texts()) >= 8
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    r = canvas.get_renderer()
    assert leg.get_window_extent(r).y1 < ax.get_window_extent(r).y0
