"""Semantic map files and labelled scan files: exact round trips and errors naming file and key."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from probmap.grid.semantic import LabelledInverseModel, SemanticGrid
from probmap.grid.semantic_io import (
    UNKNOWN_RGB,
    LabelledScans,
    SemanticFileError,
    legend_swatch_centres,
    load_semantic,
    read_labelled_scans,
    save_semantic,
    save_semantic_png,
    write_labelled_scans,
)

CLASSES = ("floor", "wall", "door")


def _grid():
    rng = np.random.default_rng(1)
    model = LabelledInverseModel(p_hit=0.8, p_miss=0.3, p_correct=0.7, thickness=0.05)
    grid = SemanticGrid(
        CLASSES,
        resolution=0.1,
        prior=[0.5, 0.3, 0.2],
        clamp=[[0.05, 0.95], [0.02, 0.9]],
        model=model,
        colors=[[250, 250, 250], [10, 20, 30], [200, 0, 0]],
    )
    poses = np.column_stack([rng.uniform(-1, 1, (4, 2)), rng.uniform(-3, 3, 4)])
    grid.integrate_scans(
        poses,
        rng.uniform(0.3, 2.0, (4, 30)),
        np.linspace(-1.5, 1.5, 30),
        labels=rng.integers(1, 3, (4, 30)),
        max_range=5.0,
    )
    return grid


def test_semantic_npz_round_trip_is_exact(tmp_path):
    g = _grid()
    h = load_semantic(save_semantic(tmp_path / "m.npz", g))
    assert h.classes == g.classes and h.spec == g.spec
    np.testing.assert_array_equal(h.log_odds, g.log_odds)
    assert h.log_odds.dtype == np.float32
    np.testing.assert_array_equal(h.observed, g.observed)
    np.testing.assert_array_equal(h.colors, g.colors)
    np.testing.assert_array_equal(h.prior, g.prior)
    np.testing.assert_array_equal(h.clamp, g.clamp)
    assert h.model == g.model and h.scans_integrated == g.scans_integrated
    # the reloaded map keeps integrating exactly like the original
    for grid in (g, h):
        grid.integrate_scan([0.2, 0.1, 0.3], [1.0, 1.2], [0.0, 0.1], labels=[2, 1], max_range=5)
    np.testing.assert_array_equal(h.log_odds, g.log_odds)


def test_semantic_npz_errors(tmp_path):
    g = _grid()
    p = save_semantic(tmp_path / "m.npz", g)
    z = dict(np.load(p))
    del z["classes"]
    np.savez(tmp_path / "bad.npz", **z)
    with pytest.raises(SemanticFileError, match=r"bad\.npz.*'classes'"):
        load_semantic(tmp_path / "bad.npz")
    z = dict(np.load(p))
    z["log_odds"] = z["log_odds"][:, :, :1]
    np.savez(tmp_path / "bad2.npz", **z)
    with pytest.raises(SemanticFileError, match=r"bad2\.npz.*'log_odds'.*does not match"):
        load_semantic(tmp_path / "bad2.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(SemanticFileError, match="junk.npz"):
        load_semantic(tmp_path / "junk.npz")
    with pytest.raises(FileNotFoundError):
        load_semantic(tmp_path / "missing.npz")


def test_colour_png_pixels_and_legend(tmp_path):
    g = _grid()
    path = save_semantic_png(tmp_path / "m.png", g, scale=2)
    img = np.asarray(Image.open(path).convert("RGB"))
    h, w = g.spec.shape
    cls = g.classify()
    # map pixels (row 0 = top = largest y), 2 x 2 per cell
    want = np.where(cls[..., None] >= 0, g.colors[np.maximum(cls, 0)], UNKNOWN_RGB)[::-1]
    np.testing.assert_array_equal(img[: 2 * h : 2, : 2 * w : 2], want.astype(np.uint8))
    # the legend swatches carry the class colours, then the unknown grey
    for (x, y), col in zip(
        legend_swatch_centres(len(g.classes), 2 * w),
        [*g.colors.tolist(), list(UNKNOWN_RGB)],
        strict=True,
    ):
        assert img[y, x].tolist() == col
    # and it is not all swatches: some dark text pixels to the right of them
    assert (img[:, 2 * w + 24 :] < 100).any()


def _scans(rng, soft=False):
    S, B = 5, 12
    probs = rng.dirichlet(np.ones(2), (S, B)) if soft else None
    return LabelledScans(
        poses=rng.normal(size=(S, 3)),
        ranges=rng.uniform(0.5, 4.0, (S, B)),
        angles=np.linspace(-1, 1, B),
        max_range=4.5,
        classes=CLASSES,
        labels=None if soft else rng.integers(1, 3, (S, B)),
        probabilities=probs,
        colors=np.array([[1, 2, 3], [4, 5, 6], [7, 8, 9]], np.uint8),
    )


@pytest.mark.parametrize("soft", [False, True])
def test_labelled_scans_round_trip(tmp_path, soft):
    sc = _scans(np.random.default_rng(0), soft)
    back = read_labelled_scans(write_labelled_scans(tmp_path / "s.npz", sc))
    for key in ("poses", "ranges", "angles", "labels", "probabilities", "colors"):
        a, b = getattr(sc, key), getattr(back, key)
        if a is None:
            assert b is None
        else:
            np.testing.assert_allclose(b, a, rtol=1e-15, atol=0)
    assert back.classes == sc.classes and back.max_range == sc.max_range and len(back) == 5
    # mapping from the file equals mapping from memory
    g1, g2 = back.make_grid(resolution=0.1), sc.make_grid(resolution=0.1)
    back.integrate_into(g1)
    sc.integrate_into(g2)
    np.testing.assert_array_equal(g1.log_odds, g2.log_odds)


def _write_raw(path, **arrays):
    np.savez(path, **arrays)
    return path


def test_labelled_scans_errors_name_key_and_scan(tmp_path):
    sc = _scans(np.random.default_rng(0))
    base = {
        "poses": sc.poses,
        "ranges": sc.ranges,
        "angles": sc.angles,
        "max_range": np.array(sc.max_range),
        "classes": np.array(sc.classes),
        "labels": sc.labels,
    }
    bad = dict(base, labels=sc.labels.copy())
    bad["labels"][3, 4] = 7
    p = _write_raw(tmp_path / "a.npz", **bad)
    with pytest.raises(SemanticFileError, match=r"a\.npz.*'labels'.*scan 3: label 7 of beam 4"):
        read_labelled_scans(p)
    p = _write_raw(tmp_path / "b.npz", **dict(base, labels=sc.labels[:, :-1]))
    with pytest.raises(SemanticFileError, match=r"'labels'.*11 entries per scan.*12 beams"):
        read_labelled_scans(p)
    probs = np.full((5, 12, 2), 0.5)
    probs[2, 0] = [0.9, 0.3]
    nolab = {k: v for k, v in base.items() if k != "labels"}
    p = _write_raw(tmp_path / "c.npz", probabilities=probs, **nolab)
    with pytest.raises(SemanticFileError, match=r"'probabilities'.*scan 2.*beam 0 does not sum"):
        read_labelled_scans(p)
    p = _write_raw(tmp_path / "d.npz", **nolab)
    with pytest.raises(SemanticFileError, match="exactly one of"):
        read_labelled_scans(p)
    p = _write_raw(tmp_path / "e.npz", **dict(base, poses=sc.poses[:4]))
    with pytest.raises(SemanticFileError, match=r"'ranges'.*5 scans of ranges for 4 poses"):
        read_labelled_scans(p)
    p = _write_raw(tmp_path / "f.npz", **{k: v for k, v in base.items() if k != "angles"})
    with pytest.raises(SemanticFileError, match="field 'angles': missing array"):
        read_labelled_scans(p)


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ({"format": np.array("probmap.OccupancyGrid")}, "field 'format': not a probmap semantic"),
        ({"version": np.array(7)}, "field 'version': format version 7 is newer"),
        ({"log_odds": None}, "field 'log_odds': missing array"),
    ],
)
def test_semantic_map_header_errors_name_the_field(tmp_path, change, needle):
    path = save_semantic(tmp_path / "m.npz", _grid())
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    for k, v in change.items():
        if v is None:
            del arrays[k]
        else:
            arrays[k] = v
    bad = _write_raw(tmp_path / "bad.npz", **arrays)
    with pytest.raises(SemanticFileError, match=needle):
        load_semantic(bad)
    np.save(tmp_path / "one.npy", np.zeros(3))
    with pytest.raises(SemanticFileError, match="single .npy array"):
        load_semantic(tmp_path / "one.npy")
