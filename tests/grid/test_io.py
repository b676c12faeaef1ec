"""Map files: npz, map_server (YAML + PGM/PNG) and PNG previews; round trips, orientation, errors."""

from __future__ import annotations

import io
import math
import os
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from probmap.datasets.protocol import DatasetError
from probmap.grid import io as gio
from probmap.grid.io import (
    MapFileError,
    load_npz,
    read_map_server,
    read_pgm,
    save_map,
    save_npz,
    save_png,
    write_map_server,
)
from probmap.grid.logodds import logit
from probmap.grid.occupancy import OccupancyGrid
from probmap.grid.spec import GridSpec


def random_grid(seed=0, shape=(23, 31), origin=(-1.25, 3.5), res=0.1, p0=0.5):
    """A grid with random log odds in the clamping range and a random observed mask."""
    rng = np.random.default_rng(seed)
    spec = GridSpec(res, origin, shape)
    lo = rng.uniform(logit(0.12), logit(0.97), shape).astype(np.float32)
    seen = rng.random(shape) < 0.7
    lo[~seen] = np.float32(logit(p0))
    # make sure every class occurs, including values right at the thresholds' neighbourhood
    lo.flat[:4] = np.array([logit(p) for p in (0.97, 0.12, 0.66, 0.19)], dtype=np.float32)
    seen.flat[:4] = True
    return OccupancyGrid.from_log_odds(spec, lo, p0=p0, observed=seen)


def pil_grey(path: Path) -> np.ndarray:
    """Independent image reader (pillow) for checking what the writers wrote."""
    with Image.open(path) as img:
        return np.asarray(img)


# --------------------------------------------------------------------------- npz


def test_npz_round_trip_is_exact(tmp_path):
    grid = random_grid(p0=0.4)
    path = save_npz(tmp_path / "g.npz", grid)
    back = load_npz(path)
    assert back.spec == grid.spec
    assert back.log_odds.dtype == np.float32
    np.testing.assert_array_equal(back.log_odds, grid.log_odds)
    np.testing.assert_array_equal(back.observed, grid.observed)
    assert back.p0 == 0.4 and back.clamp == grid.clamp
    np.testing.assert_array_equal(back.classify(), grid.classify())
    assert os.listdir(tmp_path) == ["g.npz"]
    # the layout is numpy's own: np.load reads ours, and load_npz reads numpy's
    with np.load(path) as z:
        np.testing.assert_array_equal(z["log_odds"], grid.log_odds)
    np.savez_compressed(tmp_path / "np.npz", **gio._npz_arrays(grid))  # type: ignore[arg-type]
    np.testing.assert_array_equal(load_npz(tmp_path / "np.npz").log_odds, grid.log_odds)


def _npz_with(path: Path, **changes):
    grid = random_grid(shape=(4, 5))
    arrays = gio._npz_arrays(grid)
    for k, v in changes.items():
        if v is None:
            arrays.pop(k)
        else:
            arrays[k] = v
    np.savez(path, **arrays)  # type: ignore[arg-type]
    return path


@pytest.mark.parametrize(
    "changes,needle",
    [
        ({"log_odds": None}, "'log_odds': missing array"),
        ({"format": np.array("something.else")}, "not a probmap map archive"),
        ({"version": np.array(99)}, "format version 99 is newer"),
        ({"log_odds": np.zeros((4, 6), np.float32)}, "does not match shape"),
        ({"log_odds": np.zeros((4, 5), np.float64)}, "2-D float32"),
        ({"observed": np.zeros((4, 5), np.int8)}, "'observed'"),
        ({"origin": np.zeros(3)}, "origin and clamp"),
        ({"resolution": np.array(-0.1)}, "inconsistent map"),
        ({"clamp": np.array([0.9, 0.1])}, "inconsistent map"),
        ({"version": np.array([1, 2])}, "malformed map archive"),
    ],
)
def test_npz_bad_contents(tmp_path, changes, needle):
    path = _npz_with(tmp_path / "bad.npz", **changes)
    with pytest.raises(MapFileError) as info:
        load_npz(path)
    assert str(path) in str(info.value) and needle in str(info.value), str(info.value)


def test_npz_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere.npz"):
        load_npz(tmp_path / "nothere.npz")
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"this is not a zip archive at all")
    with pytest.raises(MapFileError, match="garbage.npz.*not a probmap .npz map"):
        load_npz(garbage)
    single = tmp_path / "single.npy"
    np.save(single, np.zeros(3))
    with pytest.raises(MapFileError, match="single .npy array"):
        load_npz(single)
    good = save_npz(tmp_path / "good.npz", random_grid())
    data = good.read_bytes()
    cut = tmp_path / "cut.npz"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(MapFileError, match="cut.npz"):
        load_npz(cut)
    assert isinstance(MapFileError("x"), DatasetError)


# --------------------------------------------------------------------------- map_server


def test_trinary_round_trip_exact_classes(tmp_path):
    grid = random_grid(seed=1)
    files = write_map_server(tmp_path / "m.yaml", grid)
    assert files == [tmp_path / "m.yaml", tmp_path / "m.pgm"]
    back = read_map_server(tmp_path / "m.yaml")
    assert back.spec == grid.spec and back.mode == "trinary" and not back.negate
    np.testing.assert_array_equal(back.classify(), grid.classify(0.65, 0.196))
    assert set(np.unique(pil_grey(tmp_path / "m.pgm")).tolist()) == {0, 205, 254}
    occ = back.occupancy()
    cls = grid.classify(0.65, 0.196)
    assert (occ[cls == 1] == 100).all() and (occ[cls == 0] == 0).all()
    assert (occ[cls == -1] == -1).all()
    doc = yaml.safe_load((tmp_path / "m.yaml").read_text())
    assert doc == {
        "image": "m.pgm",
        "resolution": 0.1,
        "origin": [-1.25, 3.5, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
        "mode": "trinary",
    }


def test_trinary_with_other_thresholds_picks_a_consistent_unknown_grey(tmp_path):
    grid = random_grid(seed=2)
    write_map_server(tmp_path / "m.yaml", grid, occupied_thresh=0.8, free_thresh=0.3)
    back = read_map_server(tmp_path / "m.yaml")
    np.testing.assert_array_equal(back.classify(), grid.classify(0.8, 0.3))
    unknown = pil_grey(tmp_path / "m.pgm")[::-1][~grid.observed]
    v = int(unknown[0])
    assert (unknown == v).all() and 0.3 <= (255 - v) / 255 <= 0.8


def test_negate(tmp_path):
    grid = random_grid(seed=3)
    write_map_server(tmp_path / "n.yaml", grid, negate=True)
    back = read_map_server(tmp_path / "n.yaml")
    assert back.negate
    np.testing.assert_array_equal(back.classify(), grid.classify())
    pixels = pil_grey(tmp_path / "n.pgm")[::-1]
    cls = grid.classify()
    assert (pixels[cls == 1] == 255).all() and (pixels[cls == 0] == 1).all()
    assert (pixels[cls == -1] == 50).all()


@pytest.mark.parametrize("mode,tol", [("trinary", None), ("scale", 0.5 / 255), ("raw", 0.005)])
@pytest.mark.parametrize("image", ["m.pgm", "m.png"])
def test_negate_round_trips_in_every_mode(tmp_path, mode, tol, image):
    grid = random_grid(seed=8)
    write_map_server(tmp_path / "m.yaml", grid, negate=True, mode=mode, image=image)
    plain = tmp_path / "p"
    plain.mkdir()
    write_map_server(plain / "m.yaml", grid, mode=mode, image=image)
    a, b = pil_grey(tmp_path / image), pil_grey(plain / image)
    np.testing.assert_array_equal(
        a[..., 0] if a.ndim == 3 else a, 255 - (b[..., 0] if b.ndim == 3 else b)
    )
    back = read_map_server(tmp_path / "m.yaml")
    seen = grid.observed
    if tol is None:
        np.testing.assert_array_equal(back.classify(), grid.classify())
    else:
        assert np.abs(back.probability - grid.probability())[seen].max() <= tol + 1e-12


def test_scale_mode_round_trip_within_one_grey_level(tmp_path):
    grid = random_grid(seed=4)
    write_map_server(tmp_path / "s.yaml", grid, mode="scale")
    back = read_map_server(tmp_path / "s.yaml")
    seen = grid.observed
    err = np.abs(back.probability - grid.probability())[seen]
    assert err.max() <= 0.5 / 255 + 1e-12
    # PGM has no alpha: never-observed cells are written as the prior and read back as such
    np.testing.assert_allclose(back.probability[~seen], 0.5, atol=0.5 / 255 + 1e-12)
    # PNG keeps unknown in the alpha channel, as map_server's scale mode reads it
    write_map_server(tmp_path / "a.yaml", grid, mode="scale", image="a.png")
    back = read_map_server(tmp_path / "a.yaml")
    assert np.isnan(back.probability[~seen]).all()
    assert np.abs(back.probability - grid.probability())[seen].max() <= 0.5 / 255 + 1e-12
    occ = back.occupancy()
    p = back.probability
    mid = seen & (p >= 0.196) & (p <= 0.65)
    expect = (1 + 98 * (p[mid] - 0.196) / (0.65 - 0.196)).astype(np.int8)
    np.testing.assert_array_equal(occ[mid], expect)
    assert (occ[~seen] == -1).all()


def test_raw_mode_round_trip(tmp_path):
    grid = random_grid(seed=5)
    write_map_server(tmp_path / "r.yaml", grid, mode="raw")
    back = read_map_server(tmp_path / "r.yaml")
    seen = grid.observed
    assert np.abs(back.probability - grid.probability())[seen].max() <= 0.005 + 1e-12
    assert np.isnan(back.probability[~seen]).all()
    np.testing.assert_array_equal(
        back.occupancy()[seen], np.rint(100 * grid.probability()[seen]).astype(np.int8)
    )


def test_orientation_of_a_known_cell(tmp_path):
    spec = GridSpec(0.1, (-1.0, 2.0), (30, 40))
    lo = np.zeros(spec.shape, np.float32)
    seen = np.zeros(spec.shape, bool)
    ix, iy = math.floor((1.23 + 1.0) / 0.1), math.floor((3.71 - 2.0) / 0.1)  # (22, 17)
    lo[iy, ix] = logit(0.8)
    seen[iy, ix] = True
    grid = OccupancyGrid.from_log_odds(spec, lo, observed=seen)
    save_map(tmp_path / "o", grid, png_scale=2)
    img = pil_grey(tmp_path / "o.pgm")
    assert img.shape == (30, 40)
    rows, cols = np.nonzero(img != 205)
    assert (rows.tolist(), cols.tolist()) == ([30 - 1 - 17], [22])  # image row 0 = largest y
    assert img[12, 22] == 0
    png = pil_grey(tmp_path / "o.png")
    assert png.shape == (60, 80)
    rows, cols = np.nonzero(png != 128)  # the preview's unknown grey
    assert sorted(set(rows.tolist())) == [24, 25] and sorted(set(cols.tolist())) == [44, 45]
    assert png[24, 44] == 0  # p = 0.8 >= 0.75: black
    back = read_map_server(tmp_path / "o.yaml")
    cx, cy = back.spec.world_to_cell([1.23, 3.71])
    assert back.classify()[cy, cx] == 1 and (back.classify() == 1).sum() == 1


def write_pgm_p2(path: Path, rows, maxval=255, comment=True):
    h, w = len(rows), len(rows[0])
    text = "P2\n" + ("# hand written\n" if comment else "") + f"{w} {h}\n{maxval}\n"
    text += "\n".join(" ".join(str(v) for v in r) for r in rows) + "\n"
    path.write_text(text)


def write_yaml(path: Path, **fields):
    doc = {
        "image": "hand.pgm",
        "resolution": 0.5,
        "origin": [10.0, -4.0, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
    }
    for k, v in fields.items():
        if v is None:
            doc.pop(k, None)
        else:
            doc[k] = v
    path.write_text(yaml.safe_dump(doc))
    return path


def test_read_hand_written_ascii_pgm(tmp_path):
    # top row (largest y): occupied, unknown, free; bottom row: free, occupied, mid grey
    write_pgm_p2(tmp_path / "hand.pgm", [[0, 205, 254], [255, 10, 128]])
    m = read_map_server(write_yaml(tmp_path / "hand.yaml"))
    assert m.spec == GridSpec(0.5, (10.0, -4.0), (2, 3))
    expected_top = [1.0, np.nan, 1 / 255]
    expected_bottom = [0.0, 245 / 255, np.nan]
    np.testing.assert_allclose(m.probability[1], expected_top)
    np.testing.assert_allclose(m.probability[0], expected_bottom)
    np.testing.assert_array_equal(m.classify(), [[0, 1, -1], [1, -1, 0]])
    # the cell at world (10.2, -3.2) is column 0, row 1 (the top image row): occupied
    cx, cy = m.spec.world_to_cell([10.2, -3.2])
    assert m.classify()[cy, cx] == 1


def test_read_binary_pgm_with_other_maxvals(tmp_path):
    vals = np.array([[0, 65535], [32768, 13107]], dtype=">u2")
    (tmp_path / "hand.pgm").write_bytes(b"P5\n# c\n2 2\n65535\n" + vals.tobytes())
    grey = read_pgm(tmp_path / "hand.pgm")
    np.testing.assert_allclose(grey, vals.astype(float) * 255 / 65535)
    (tmp_path / "hand.pgm").write_bytes(b"P5 2 1 100\n" + bytes([0, 100]))
    np.testing.assert_allclose(read_pgm(tmp_path / "hand.pgm"), [[0.0, 255.0]])
    m = read_map_server(write_yaml(tmp_path / "hand.yaml", mode="trinary"))
    np.testing.assert_array_equal(m.classify(), [[1, 0]])


def test_read_png_rgb_and_alpha(tmp_path):
    rgb = np.zeros((1, 3, 3), np.uint8)
    rgb[0, 0] = (0, 0, 0)
    rgb[0, 1] = (255, 255, 251)  # mean 253.67 -> free
    rgb[0, 2] = (200, 210, 205)  # mean 205 -> unknown in trinary
    Image.fromarray(rgb, "RGB").save(tmp_path / "c.png")
    m = read_map_server(write_yaml(tmp_path / "c.yaml", image="c.png"))
    np.testing.assert_array_equal(m.classify(), [[1, 0, -1]])
    la = np.array([[[0, 0], [128, 255], [128, 0]]], np.uint8)  # occupied transparent, mid, mid
    Image.fromarray(la, "LA").save(tmp_path / "a.png")
    m = read_map_server(write_yaml(tmp_path / "a.yaml", image="a.png", mode="scale"))
    assert m.probability[0, 0] == 1.0  # alpha only makes in-between values unknown
    assert m.probability[0, 1] == pytest.approx(127 / 255)
    assert np.isnan(m.probability[0, 2])


def test_absolute_image_path_and_yaw_warning(tmp_path):
    write_pgm_p2(tmp_path / "hand.pgm", [[0, 254]])
    sub = tmp_path / "sub"
    sub.mkdir()
    y = write_yaml(sub / "m.yaml", image=str(tmp_path / "hand.pgm"), origin=[0.0, 0.0, 0.5])
    with pytest.warns(UserWarning, match="yaw"):
        m = read_map_server(y)
    assert m.origin_yaw == 0.5 and m.image == tmp_path / "hand.pgm"


@pytest.mark.parametrize(
    "fields,needle",
    [
        ({"resolution": None}, "field 'resolution': missing field"),
        ({"resolution": -0.05}, "field 'resolution': must be positive"),
        ({"resolution": "fine"}, "field 'resolution': expected a finite number"),
        ({"resolution": True}, "field 'resolution'"),
        ({"image": None}, "field 'image': missing field"),
        ({"image": 12}, "field 'image': expected a file name"),
        ({"origin": None}, "field 'origin': missing field"),
        ({"origin": [1.0]}, "field 'origin'"),
        ({"origin": [1.0, "a", 0.0]}, "field 'origin'"),
        ({"occupied_thresh": None}, "field 'occupied_thresh': missing"),
        ({"free_thresh": 1.5}, "field 'free_thresh': must lie in [0, 1]"),
        ({"free_thresh": 0.7}, "field 'free_thresh': free_thresh 0.7 is above occupied_thresh"),
        ({"negate": 2}, "field 'negate'"),
        ({"mode": "fancy"}, "field 'mode'"),
    ],
)
def test_map_server_bad_fields(tmp_path, fields, needle):
    write_pgm_p2(tmp_path / "hand.pgm", [[0, 254]])
    y = write_yaml(tmp_path / "bad.yaml", **fields)
    with pytest.raises(MapFileError) as info:
        read_map_server(y)
    msg = str(info.value)
    assert str(y) in msg and needle in msg, msg


def test_map_server_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="none.yaml"):
        read_map_server(tmp_path / "none.yaml")
    y = write_yaml(tmp_path / "m.yaml", image="missing.pgm")
    with pytest.raises(FileNotFoundError, match=r"m\.yaml: field 'image'.*missing\.pgm"):
        read_map_server(y)
    (tmp_path / "bad.yaml").write_text("image: [unclosed\n")
    with pytest.raises(MapFileError, match="bad.yaml: not valid YAML"):
        read_map_server(tmp_path / "bad.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(MapFileError, match="list.yaml: expected a YAML mapping"):
        read_map_server(tmp_path / "list.yaml")
    (tmp_path / "hand.pgm").write_bytes(b"P5\n4 4\n255\n" + bytes(10))
    with pytest.raises(MapFileError, match=r"hand\.pgm: PGM pixel data truncated"):
        read_map_server(write_yaml(tmp_path / "t.yaml"))
    (tmp_path / "hand.pgm").write_bytes(b"P5\n4")
    with pytest.raises(MapFileError, match="header is incomplete"):
        read_pgm(tmp_path / "hand.pgm")
    (tmp_path / "hand.pgm").write_bytes(b"P5\nfour 4 255\n")
    with pytest.raises(MapFileError, match="bad PGM header"):
        read_pgm(tmp_path / "hand.pgm")
    (tmp_path / "hand.pgm").write_bytes(b"P2\n2 1\n255\n0 300\n")
    with pytest.raises(MapFileError, match="above maxval"):
        read_pgm(tmp_path / "hand.pgm")
    (tmp_path / "x.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(MapFileError, match=r"x\.png: cannot read image"):
        read_map_server(write_yaml(tmp_path / "p.yaml", image="x.png"))


def test_writer_argument_errors(tmp_path):
    grid = random_grid()
    with pytest.raises(ValueError, match="mode"):
        write_map_server(tmp_path / "m.yaml", grid, mode="fancy")
    with pytest.raises(ValueError, match="free_thresh"):
        write_map_server(tmp_path / "m.yaml", grid, occupied_thresh=0.2, free_thresh=0.5)
    with pytest.raises(ValueError, match="image"):
        write_map_server(tmp_path / "m.yaml", grid, image="m.jpg")
    with pytest.raises(ValueError, match="scale"):
        save_png(tmp_path / "p.png", grid, scale=0)
    with pytest.raises(ValueError, match="file name part"):
        save_map(tmp_path / "..", grid)
    assert os.listdir(tmp_path) == []


# --------------------------------------------------------------------------- previews, save_map


def test_png_preview(tmp_path):
    grid = random_grid(seed=6)
    save_png(tmp_path / "p.png", grid, scale=3)
    img = pil_grey(tmp_path / "p.png")
    h, w = grid.spec.shape
    assert img.shape == (3 * h, 3 * w) and img.dtype == np.uint8
    small = img[::3, ::3][::-1]  # back to [iy, ix], row 0 at the smallest y
    seen = grid.observed
    assert (small[~seen] == 128).all()  # unknown: mid-grey
    p = grid.probability()
    expect = np.rint(255 * np.clip((0.75 - p) / 0.5, 0, 1))  # white p <= 0.25, black >= 0.75
    np.testing.assert_array_equal(small[seen], expect[seen])
    assert (small[seen & (p <= 0.25)] == 255).all() and (small[seen & (p >= 0.75)] == 0).all()


def test_save_map_writes_four_consistent_files(tmp_path):
    grid = random_grid(seed=7)
    files = save_map(tmp_path / "intel.v2", grid)
    assert [f.name for f in files] == [f"intel.v2.{e}" for e in ("yaml", "pgm", "npz", "png")]
    assert sorted(os.listdir(tmp_path)) == sorted(f.name for f in files)
    back = read_map_server(files[0])
    np.testing.assert_array_equal(back.classify(), grid.classify())
    np.testing.assert_array_equal(load_npz(files[2]).log_odds, grid.log_odds)
    assert pil_grey(files[3]).shape == grid.spec.shape


def test_save_map_leaves_nothing_when_it_fails(tmp_path, monkeypatch):
    grid = random_grid()
    with pytest.raises(OSError, match="nofolder"):
        save_map(tmp_path / "nofolder" / "m", grid)
    afile = tmp_path / "afile"
    afile.write_text("x")
    with pytest.raises(OSError, match="afile"):
        save_map(afile / "m", grid)

    def boom(*args, **kwargs):
        raise RuntimeError("disk full while writing the PGM")

    # the PGM is streamed inside the all-or-nothing block, after the YAML temp file was written
    monkeypatch.setattr(gio, "_write_pgm_rows", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        save_map(tmp_path / "m", grid)
    assert sorted(os.listdir(tmp_path)) == ["afile"]


def test_save_map_unwritable_folder(read_only_dir):
    with pytest.raises(PermissionError, match="ro"):
        save_map(read_only_dir / "m", random_grid())
    assert os.listdir(read_only_dir) == []


@pytest.mark.parametrize("mode", ["trinary", "scale", "raw"])
@pytest.mark.parametrize("png_scale", [1, 3])
def test_save_map_in_row_blocks_equals_whole_array_encoding(tmp_path, monkeypatch, mode, png_scale):
    # a large map is encoded in blocks of rows; with blocks of 2 rows (and a ragged last
    # block) the files must be exactly those of the whole-array encoders
    grid = random_grid(seed=3, shape=(23, 31))
    monkeypatch.setattr(gio, "_CHUNK_CELLS", 2 * 31 + 5)
    paths = save_map(tmp_path / "m", grid, mode=mode, png_scale=png_scale)
    grey, _ = gio._encode_pixels(
        grid.probability(), grid.observed, grid.p0, 0.65, 0.196, False, mode
    )
    assert paths[1].read_bytes() == gio.pgm_bytes(grey)
    np.testing.assert_array_equal(pil_grey(paths[3]), gio.preview_image(grid, png_scale))
    back = load_npz(paths[2])
    np.testing.assert_array_equal(back.log_odds, grid.log_odds)
    np.testing.assert_array_equal(back.observed, grid.observed)
    # the observed mask is streamed into the archive by blocks: every member's bytes are those
    # of the whole-array writer
    whole = io.BytesIO()
    gio._write_npz(whole, grid)
    with zipfile.ZipFile(paths[2]) as a, zipfile.ZipFile(whole) as b:
        assert a.namelist() == b.namelist()
        for name in a.namelist():
            assert a.read(name) == b.read(name), name


def test_png_stream_equals_pillow_pixels_and_checks_its_rows(tmp_path):
    # the streaming PNG writer against pillow's reader, on a block split that leaves a ragged
    # last block; too many or too few rows are refused
    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (37, 29), dtype=np.uint8)
    buf = io.BytesIO()
    png = gio._PngStream(buf, 29, 37)
    for r0 in range(0, 37, 8):
        png.rows(img[r0 : r0 + 8])
    png.close()
    with Image.open(io.BytesIO(buf.getvalue())) as back:
        assert back.mode == "L"
        np.testing.assert_array_equal(np.asarray(back), img)
    short = gio._PngStream(io.BytesIO(), 29, 37)
    short.rows(img[:10])
    with pytest.raises(ValueError, match="27 rows"):
        short.close()
    with pytest.raises(ValueError, match="do not fit"):
        short.rows(img)
