"""Map pictures: the palette equals the PNG preview's, the axes are the grid's extent in metres,
the trajectory and the scale bar are drawn, the file is all-or-nothing."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.grid.io import preview_image
from probmap.grid.occupancy import OccupancyGrid
from probmap.grid.spec import GridSpec
from probmap.viz.maps import (
    UNKNOWN_RGB,
    map_image,
    nice_length,
    picture_step,
    plot_map,
    pooled_cells,
    save_map_figure,
)


def grid(seed: int = 0) -> OccupancyGrid:
    rng = np.random.default_rng(seed)
    spec = GridSpec(0.1, (-2.0, 1.0), (30, 50))
    lo = rng.normal(0.0, 2.0, spec.shape).astype(np.float32)
    seen = rng.random(spec.shape) < 0.7
    return OccupancyGrid.from_log_odds(spec, lo, observed=seen)


def test_palette_is_the_png_previews_grey_and_unknown_stands_out():
    """Observed cells: the PNG preview's grey ramp; never-observed cells: UNKNOWN_RGB, a
    colour off the grey ramp (no observed cell can be mistaken for unknown)."""
    g = grid()
    img, step = map_image(g)
    assert step == 1 and img.dtype == np.uint8 and img.shape == (30, 50, 3)
    png = preview_image(g)[::-1]  # row 0 at the smallest y, as the picture draws it
    seen = np.asarray(g.observed)
    for c in range(3):
        np.testing.assert_allclose(img[..., c][seen], png[seen], atol=1)
    want = np.rint(255 * np.asarray(UNKNOWN_RGB))
    assert (img[~seen] == want).all()
    assert want[2] - want[0] >= 30  # blue-grey: not on the white-black ramp
    grey = img[seen]
    assert (grey[:, 0] == grey[:, 2]).all()


def reference_pool(lo, seen, step):
    """Obviously correct: loop over the blocks."""
    h, w = lo.shape
    out_lo = np.zeros((-(-h // step), -(-w // step)), np.float32)
    out_seen = np.zeros(out_lo.shape, bool)
    for i in range(out_lo.shape[0]):
        for j in range(out_lo.shape[1]):
            block_lo = lo[i * step : (i + 1) * step, j * step : (j + 1) * step]
            block_seen = seen[i * step : (i + 1) * step, j * step : (j + 1) * step]
            if block_seen.any():
                out_seen[i, j] = True
                out_lo[i, j] = block_lo[block_seen].max()
    return out_lo, out_seen


@pytest.mark.parametrize("step", [1, 2, 3, 7])
def test_pooled_cells_keep_the_most_occupied_observed_cell(step, monkeypatch):
    import probmap.viz.maps as maps

    monkeypatch.setattr(maps, "_STRIP_CELLS", 150)  # several strips, one of them partial
    g = grid(3)
    got_lo, got_seen = pooled_cells(g, step)
    want_lo, want_seen = reference_pool(np.asarray(g.log_odds), np.asarray(g.observed), step)
    np.testing.assert_array_equal(got_seen, want_seen)
    np.testing.assert_allclose(got_lo, want_lo)


def test_a_wall_one_cell_thick_survives_a_large_maps_picture():
    spec = GridSpec(0.05, (0.0, 0.0), (400, 1300))
    lo = np.full(spec.shape, -3.0, np.float32)  # free everywhere
    lo[:, 601] = 3.0  # one wall, one cell thick, in a column stride-3 sampling skips
    g = OccupancyGrid.from_log_odds(spec, lo, observed=np.ones(spec.shape, bool))
    assert picture_step(g, 500) == 3
    img, step = map_image(g, 500)
    assert step == 3 and img.shape == (134, 434, 3)
    dark = np.flatnonzero((img[..., 0] < 10).all(axis=0))
    np.testing.assert_array_equal(dark, [601 // 3])
    assert (img[:, : 601 // 3] == 255).all()


def test_large_map_picture_has_a_pixel_per_image_pixel(tmp_path):
    """A map of 3,000 x 1,300 cells with at most 1,500 pixels a side: step 2, and the file's
    map area is 1,500 x 650 pixels (the old pictures gave any map about 930)."""
    from PIL import Image

    spec = GridSpec(0.05, (0.0, 0.0), (1300, 3000))
    g = OccupancyGrid.from_log_odds(
        spec, np.zeros(spec.shape, np.float32), observed=np.zeros(spec.shape, bool)
    )
    out = save_map_figure(tmp_path / "big.plot.png", g, title="big", max_pixels=1500)
    with Image.open(out) as im:
        rgb = np.asarray(im.convert("RGB"))
    unknown = np.abs(rgb.astype(int) - np.rint(255 * np.asarray(UNKNOWN_RGB))).sum(-1) <= 3
    cols = np.flatnonzero(unknown.sum(axis=0) > 100)
    rows = np.flatnonzero(unknown.sum(axis=1) > 100)
    assert abs((cols[-1] - cols[0] + 1) - 1500) <= 3  # one file pixel per image pixel
    assert abs((rows[-1] - rows[0] + 1) - 650) <= 3


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
    (line, start, end) = ax.get_lines()
    np.testing.assert_allclose(line.get_xydata(), traj[:, :2])
    np.testing.assert_allclose(start.get_xydata(), traj[:1, :2])
    np.testing.assert_allclose(end.get_xydata(), traj[-1:, :2])
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["trajectory", "start", "end", "free", "occupied", "unknown (never observed)"]
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


def whole_map_image(g, max_pixels):
    """The picture's colours computed over the whole map at once (the docstring's formula on
    the obviously correct pooling)."""
    step = picture_step(g, max_pixels)
    lo, seen = reference_pool(np.asarray(g.log_odds), np.asarray(g.observed), step)
    p = 1.0 / (1.0 + np.exp(-lo, dtype=np.float32))
    grey = np.rint(255.0 * np.clip((0.75 - p) / 0.5, 0.0, 1.0)).astype(np.uint8)
    img = np.repeat(grey[..., None], 3, axis=2)
    img[~seen] = np.rint(255.0 * np.asarray(UNKNOWN_RGB)).astype(np.uint8)
    return img, step


@pytest.mark.parametrize(("max_pixels", "step"), [(50, 1), (17, 3), (8, 7)])
def test_map_image_in_strips_is_the_whole_maps_image(max_pixels, step, monkeypatch):
    """Built a strip at a time (several strips, the last one partial), the colours are those
    computed over the whole map, value for value."""
    import probmap.viz.maps as maps

    monkeypatch.setattr(maps, "_STRIP_CELLS", 150)
    g = grid(4)
    got, got_step = map_image(g, max_pixels)
    want, want_step = whole_map_image(g, max_pixels)
    assert got_step == want_step == step
    np.testing.assert_array_equal(got, want)


def large_grid(seed: int = 5) -> OccupancyGrid:
    """A map drawn one file pixel per cell (its longer side over 1,050 pixels)."""
    rng = np.random.default_rng(seed)
    spec = GridSpec(0.05, (-3.0, 2.0), (700, 1200))
    lo = rng.normal(0.0, 2.0, spec.shape).astype(np.float32)
    seen = rng.random(spec.shape) < 0.8
    seen[:200, :300] = False  # a block never observed
    return OccupancyGrid.from_log_odds(spec, lo, observed=seen)


@pytest.mark.parametrize("make", [grid, large_grid])
def test_picture_is_the_picture_of_the_map_drawn_whole(make, tmp_path, monkeypatch):
    """The file draw_grid's opaque RGBA strips and save_picture's own crop write is, pixel
    for pixel, the one of the map drawn as one RGB image and cropped by matplotlib's
    ``bbox_inches="tight"`` (what the pictures were before): a small magnified map drawn
    whole, a large one in 35 strips."""
    from matplotlib.figure import Figure
    from PIL import Image

    import probmap.viz.maps as maps

    monkeypatch.setattr(maps, "_STRIP_PIXELS", 24_000)  # 20 rows of 1,200 pixels
    monkeypatch.setattr(maps, "_WHOLE_PIXELS", 100_000)  # 50 x 30 drawn whole, 1,200 x 700 not
    g = make()
    traj = np.array([[0.0, 2.5, 0.0], [1.0, 2.9, 0.3], [1.5, 3.5, 0.6]])

    def picture(path):
        fig = Figure(figsize=(8.0, 5.0))
        ax = fig.add_subplot()
        plot_map(ax, g, trajectory=traj, title="robot.log")
        return maps.save_picture(fig, ax, path), len(ax.get_images())

    ours, images = picture(tmp_path / "strips.png")
    assert images == (1 if make is grid else 35)

    def whole_rgb(ax, grid, *, max_pixels=maps.MAX_PICTURE_PIXELS):
        img, step = whole_map_image(grid, max_pixels)
        x0, y0, x1, y1 = maps._extent(grid)
        ax.imshow(img, origin="lower", extent=(x0, x1, y0, y1), interpolation="nearest")
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        return step

    monkeypatch.setattr(maps, "draw_grid", whole_rgb)
    monkeypatch.setattr(maps, "_tight_bbox", lambda fig, dpi: "tight")
    before, _ = picture(tmp_path / "whole.png")
    with Image.open(ours) as a, Image.open(before) as b:
        got, want = np.asarray(a), np.asarray(b)
    assert got.shape == want.shape
    np.testing.assert_array_equal(got, want)
