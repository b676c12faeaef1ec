"""Map pictures: the palette equals the PNG preview's, the axes are the grid's extent in metres,
the trajectory and the scale bar are drawn, the file is all-or-nothing."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.grid.io import preview_image
from probmap.grid.occupancy import OccupancyGrid
from probmap.grid.spec import GridSpec
from probmap.viz.maps import map_image, nice_length, plot_map, save_map_figure


def grid(seed: int = 0) -> OccupancyGrid:
    rng = np.random.default_rng(seed)
    spec = GridSpec(0.1, (-2.0, 1.0), (30, 50))
    lo = rng.normal(0.0, 2.0, spec.shape).astype(np.float32)
    seen = rng.random(spec.shape) < 0.7
    return OccupancyGrid.from_log_odds(spec, lo, observed=seen)


def test_palette_is_the_png_previews():
    g = grid()
    img, step = map_image(g)
    assert step == 1
    png = preview_image(g)[::-1] / 255.0  # row 0 at the smallest y, as the picture draws it
    np.testing.assert_allclose(img, png, atol=0.5 / 255 + 1e-12)


def test_nice_length_is_round_and_about_a_fifth():
    for span in np.geomspace(0.01, 5000.0, 200):
        bar = nice_length(float(span))
        mant = bar / 10.0 ** np.floor(np.log10(bar))
        assert np.isclose(mant, [1.0, 2.0, 5.0]).any()
        assert span / 12.5 < bar <= span / 5.0 + 1e-12
    with pytest.raises(ValueError):
        nice_length(0.0)


def test_plot_axes_trajectory_and_scale_bar():
    from matplotlib.figure import Figure

    g = grid(1)
    traj = np.array([[0.0, 2.0, 0.0], [1.0, 2.5, 0.3], [2.0, 3.0, 0.6]])
    ax = Figure().add_subplot()
    plot_map(ax, g, trajectory=traj, title="robot.log")
    assert ax.get_xlim() == pytest.approx((-2.0, 3.0)) and ax.get_ylim() == pytest.approx(
        (1.0, 4.0)
    )
    (line, start) = ax.get_lines()
    np.testing.assert_allclose(line.get_xydata(), traj[:, :2])
    assert "1 m" in [t.get_text() for t in ax.texts]  # 5 m span: a 1 m bar
    assert "robot.log" in ax.get_title(loc="left")
    with pytest.raises(ValueError, match=r"\(T, 2\) or \(T, 3\)"):
        plot_map(Figure().add_subplot(), g, trajectory=np.zeros((3, 4)))


def test_save_map_figure_writes_a_png_atomically(tmp_path, monkeypatch):
    out = save_map_figure(tmp_path / "m.plot.png", grid(2), title="x")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from matplotlib.figure import Figure

    def broken(self, *a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(Figure, "savefig", broken)
    with pytest.raises(OSError):
        save_map_figure(tmp_path / "n.plot.png", grid(2))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.plot.png"]


@pytest.mark.parametrize(("title", "legend"), [(None, None), ("run 7", "best")])
def test_label_metric_axes_labels_in_metres(title, legend):
    """The one finishing step of every viz picture: equal aspect, metres, optional title/legend."""
    from matplotlib.figure import Figure

    from probmap.viz.maps import label_metric_axes

    ax = Figure().add_subplot()
    ax.plot([0.0, 1.0], [0.0, 2.0], label="trajectory")
    assert label_metric_axes(ax, title, legend=legend) is ax
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x [m]", "y [m]")
    assert ax.get_aspect() == 1.0  # "equal"
    assert ax.get_title() == (title or "")
    got = ax.get_legend()
    assert (got is None) == (legend is None)
    if got is not None:
        assert [t.get_text() for t in got.get_texts()] == ["trajectory"]
