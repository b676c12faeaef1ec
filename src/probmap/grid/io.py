"""Map files: the ROS map_server format (YAML + PGM/PNG), a lossless ``.npz`` and a PNG preview.

Every writer is atomic (temporary file, fsync, rename; see :mod:`probmap._atomic`): an
interrupted write never leaves a truncated map, and a failed write leaves no file behind.

Orientation. Grid arrays are indexed ``[iy, ix]`` with row 0 at the *smallest* y (see
:class:`~probmap.grid.spec.GridSpec`); images are stored with row 0 at the *top* (largest y), as
map_server expects, so rows are flipped on the way out and back in. The YAML ``origin`` is the
world ``(x, y, yaw)`` of the lower-left corner of the lower-left pixel.

map_server semantics (ROS ``map_server`` / ``nav2_map_server``). A pixel's value ``v`` (the mean
of its colour channels, 0-255) becomes ``p = (255 - v) / 255`` (``p = v / 255`` with
``negate: 1``). Then, per ``mode``:

- ``trinary``: ``p > occupied_thresh`` is occupied (100), ``p < free_thresh`` free (0), anything
  else unknown (-1);
- ``scale``: as trinary, except that in-between values are kept as a graded occupancy
  ``1 + 98 (p - free_thresh) / (occupied_thresh - free_thresh)``; only pixels with alpha 0 are
  unknown;
- ``raw``: the pixel value itself (after ``negate``) is the occupancy 0-100; larger values are
  unknown.
"""

from __future__ import annotations

import io
import math
import os
import re
import struct
import warnings
import zipfile
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from probmap._atomic import atomic_files
from probmap._checks import require_integer
from probmap.errors import DatasetError, MapFileError
from probmap.grid.spec import GridSpec

if TYPE_CHECKING:
    from probmap.grid.occupancy import OccupancyGrid

__all__ = [
    "MODES",
    "MapFileError",
    "MapServerMap",
    "load_npz",
    "read_map_server",
    "read_pgm",
    "save_map",
    "save_npz",
    "save_png",
    "write_map_server",
]

MODES = ("trinary", "scale", "raw")
NPZ_FORMAT = "probmap.OccupancyGrid"
NPZ_VERSION = 1
UNKNOWN_GREY = 205  # map_saver's value for unknown cells
#: The preview PNG's palette: unknown mid-grey; observed cells from white (p <= 0.25, free) to
#: black (p >= 0.75, occupied), linear between, so that a free cell seen a few times is white
#: and a wall black (``255 (1 - p)`` made free space light grey 224 next to unknown 205).
PREVIEW_UNKNOWN = 128
PREVIEW_FREE_P, PREVIEW_OCCUPIED_P = 0.25, 0.75
FREE_WHITE = 254
OCCUPIED_BLACK = 0
_IMAGE_SUFFIXES = (".pgm", ".png")


class GridLike(Protocol):
    """What the writers need from a grid (:class:`~probmap.grid.occupancy.OccupancyGrid`)."""

    @property
    def spec(self) -> GridSpec: ...

    @property
    def log_odds(self) -> NDArray[np.float32]: ...

    @property
    def observed(self) -> NDArray[np.bool_]: ...

    @property
    def p0(self) -> float: ...

    @property
    def clamp(self) -> tuple[float, float]: ...

    def probability(self) -> NDArray[np.float64]: ...


# ---------------------------------------------------------------------------- map_server


@dataclass(frozen=True, eq=False)
class MapServerMap:
    """A map read from a map_server YAML file.

    Attributes
    ----------
    spec : GridSpec
        Geometry: ``resolution`` and ``origin`` from the YAML, ``shape`` (H, W) from the image.
    probability : ndarray, shape (H, W), float64
        Occupancy probability per cell, rows from the smallest y, NaN where map_server would
        report unknown (-1). In ``raw`` mode, ``value / 100``.
    occupied_thresh, free_thresh : float
        The YAML thresholds.
    negate : bool
        Whether white means occupied.
    mode : str
        ``"trinary"``, ``"scale"`` or ``"raw"``.
    image : Path
        The image file that was read.
    origin_yaw : float
        The third ``origin`` value in radians (GridSpec itself is axis-aligned).
    """

    spec: GridSpec
    probability: NDArray[np.float64]
    occupied_thresh: float
    free_thresh: float
    negate: bool
    mode: str
    image: Path
    origin_yaw: float = 0.0

    def classify(self) -> NDArray[np.int8]:
        """Trinary map: 1 occupied, 0 free, -1 unknown (the YAML thresholds; shape (H, W))."""
        p = self.probability
        out = np.full(p.shape, -1, dtype=np.int8)
        with np.errstate(invalid="ignore"):
            out[p > self.occupied_thresh] = 1
            out[p < self.free_thresh] = 0
        return out

    def occupancy(self) -> NDArray[np.int8]:
        """The ``nav_msgs/OccupancyGrid`` values map_server would publish: 0-100, -1 unknown."""
        p = self.probability
        known = ~np.isnan(p)
        out = np.full(p.shape, -1, dtype=np.int8)
        if self.mode == "raw":
            out[known] = np.rint(p[known] * 100.0).astype(np.int8)
            return out
        occ, free = self.occupied_thresh, self.free_thresh
        q = np.where(known, p, 0.5)
        mid = known & (q <= occ) & (q >= free)
        if self.mode == "scale" and occ > free:
            out[mid] = (1.0 + 98.0 * (q[mid] - free) / (occ - free)).astype(np.int8)
        out[known & (q > occ)] = 100
        out[known & (q < free)] = 0
        return out


def _check_thresholds(occupied_thresh: float, free_thresh: float) -> None:
    if not (math.isfinite(occupied_thresh) and math.isfinite(free_thresh)):
        raise ValueError("occupied_thresh and free_thresh must be finite")
    if not 0.0 < free_thresh <= occupied_thresh < 1.0:
        raise ValueError(
            "need 0 < free_thresh <= occupied_thresh < 1, got "
            f"free_thresh={free_thresh}, occupied_thresh={occupied_thresh}"
        )


def _unknown_value(occupied_thresh: float, free_thresh: float) -> int:
    """A grey that map_server classifies unknown: 205 (map_saver's) when the thresholds allow."""
    for v in sorted(range(1, 255), key=lambda v: (abs(v - UNKNOWN_GREY), v)):
        p = (255 - v) / 255.0
        if free_thresh <= p <= occupied_thresh:
            return v
    raise ValueError(
        f"no 8-bit grey is classified unknown between free_thresh={free_thresh} and "
        f"occupied_thresh={occupied_thresh}; widen the interval"
    )


def encode_map_server(
    grid: GridLike,
    *,
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
    negate: bool = False,
    mode: str = "trinary",
) -> tuple[NDArray[np.uint8], NDArray[np.uint8] | None]:
    """Pixel values of a grid for map_server, image orientation (row 0 = largest y).

    Returns
    -------
    grey : ndarray, shape (H, W), uint8
    alpha : ndarray, shape (H, W), uint8, or None
        Only in ``scale`` mode: 0 on never-observed cells, 255 elsewhere (used for PNG images).
    """
    p = np.asarray(grid.probability(), dtype=np.float64)
    seen = np.asarray(grid.observed, dtype=bool)
    return _encode_pixels(p, seen, float(grid.p0), occupied_thresh, free_thresh, negate, mode)


def _encode_pixels(
    p: NDArray[np.float64],
    seen: NDArray[np.bool_],
    p0: float,
    occupied_thresh: float,
    free_thresh: float,
    negate: bool,
    mode: str,
) -> tuple[NDArray[np.uint8], NDArray[np.uint8] | None]:
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    _check_thresholds(occupied_thresh, free_thresh)
    alpha: NDArray[np.uint8] | None = None
    if mode == "trinary":
        v = np.full(p.shape, _unknown_value(occupied_thresh, free_thresh), dtype=np.uint8)
        v[seen & (p < free_thresh)] = FREE_WHITE if free_thresh > 1.0 / 255.0 else 255
        v[seen & (p > occupied_thresh)] = OCCUPIED_BLACK
    elif mode == "scale":
        v = np.rint(255.0 * (1.0 - p)).astype(np.uint8)
        v[~seen] = round(255.0 * (1.0 - p0))
        alpha = np.where(seen, 255, 0).astype(np.uint8)
    else:  # raw: the value is the occupancy in percent, 255 (-1 as int8) unknown
        v = np.rint(100.0 * p).astype(np.uint8)
        v[~seen] = 255
    if negate:
        v = (255 - v).astype(np.uint8)
    return np.ascontiguousarray(v[::-1]), None if alpha is None else np.ascontiguousarray(
        alpha[::-1]
    )


def _yaml_text(
    image: str, spec: GridSpec, occupied_thresh: float, free_thresh: float, negate: bool, mode: str
) -> str:
    import yaml

    doc = {
        "image": image,
        "resolution": float(spec.resolution),
        "origin": [float(spec.origin[0]), float(spec.origin[1]), 0.0],
        "negate": int(bool(negate)),
        "occupied_thresh": float(occupied_thresh),
        "free_thresh": float(free_thresh),
        "mode": mode,
    }
    return str(yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))


def pgm_bytes(grey: NDArray[np.uint8], comment: str = "probmap") -> bytes:
    """A binary PGM (P5, maxval 255) of an (H, W) uint8 image (row 0 = top)."""
    g = np.ascontiguousarray(grey, dtype=np.uint8)
    return _pgm_header(g, comment) + g.tobytes()


def _pgm_header(g: NDArray[np.uint8], comment: str = "probmap") -> bytes:
    if g.ndim != 2:
        raise ValueError(f"a PGM image must be 2-D, got shape {g.shape}")
    if g.size == 0:
        raise ValueError(f"an empty map ({g.shape[1]} x {g.shape[0]} cells): no image to write")
    return f"P5\n# {comment}\n{g.shape[1]} {g.shape[0]}\n255\n".encode("ascii")


def _write_pgm(f: IO[bytes], grey: NDArray[np.uint8]) -> None:
    """Stream a binary PGM of a C-contiguous (H, W) uint8 image into ``f`` (no copy)."""
    f.write(_pgm_header(grey))
    f.write(memoryview(np.ascontiguousarray(grey).data).cast("B"))


def png_bytes(grey: NDArray[np.uint8], alpha: NDArray[np.uint8] | None = None) -> bytes:
    """A PNG (8-bit grey, or grey + alpha) of an (H, W) image (row 0 = top)."""
    from PIL import Image

    g = np.ascontiguousarray(grey, dtype=np.uint8)
    img = Image.fromarray(g) if alpha is None else Image.fromarray(np.dstack((g, alpha)), "LA")
    buf = io.BytesIO()
    img.save(buf, format="PNG", compress_level=3)  # 6 (the default) is 2x slower, 10% smaller
    return buf.getvalue()


def _image_name(yaml_path: Path, image: str | os.PathLike[str] | None) -> str:
    if image is None:
        return yaml_path.stem + ".pgm"
    name = os.fspath(image)
    if Path(name).suffix.lower() not in _IMAGE_SUFFIXES:
        raise ValueError(f"image must be a .pgm or .png file name, got {name!r}")
    return name


# save_map takes these thresholds too (the same encoding, _yaml_text and _stream_map_images): public.
def write_map_server(
    yaml_path: str | os.PathLike[str],
    grid: GridLike,
    *,
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
    negate: bool = False,
    mode: str = "trinary",
    image: str | os.PathLike[str] | None = None,
) -> list[Path]:
    """Write a grid as a map_server map: a YAML file and its image, both atomically.

    Parameters
    ----------
    yaml_path : path-like
        The YAML file.
    grid : OccupancyGrid
        The map (any object with ``spec``, ``observed``, ``p0`` and ``probability()``).
    occupied_thresh, free_thresh : float
        map_server thresholds, ``0 < free_thresh <= occupied_thresh < 1``.
    negate : bool
        Store white as occupied.
    mode : {"trinary", "scale", "raw"}
        ``trinary``: occupied 0, free 254, unknown 205 (map_saver's values). ``scale``: grey
        ``255 (1 - p)``, never-observed cells at the prior's grey and, in a PNG, alpha 0.
        ``raw``: the value is ``round(100 p)``, 255 for never-observed cells.
    image : str or path-like, optional
        Image file name, relative to the YAML's folder (``.pgm`` or ``.png``); default the YAML's
        name with ``.pgm``.

    Returns
    -------
    list of Path
        ``[yaml_path, image_path]``.
    """
    ypath = Path(yaml_path)
    name = _image_name(ypath, image)
    ipath = ypath.parent / name
    grey, alpha = encode_map_server(
        grid, occupied_thresh=occupied_thresh, free_thresh=free_thresh, negate=negate, mode=mode
    )
    data = png_bytes(grey, alpha) if ipath.suffix.lower() == ".png" else pgm_bytes(grey)
    text = _yaml_text(name, grid.spec, occupied_thresh, free_thresh, negate, mode)
    with atomic_files([ypath, ipath]) as (fy, fi):
        fy.write(text.encode("utf-8"))
        fi.write(data)
    return [ypath, ipath]


# ---------------------------------------------------------------------------- images in

_PNM_TOKEN = re.compile(rb"\s*(?:#[^\n]*\n\s*)*(\S+)")


def read_pgm(path: str | os.PathLike[str]) -> NDArray[np.float64]:
    """Read a PGM (binary P5 or ASCII P2) into grey levels 0-255, shape (H, W), row 0 = top.

    Files with ``maxval`` other than 255 (including 16-bit P5) are scaled to 0-255.

    Raises
    ------
    MapFileError
        A bad header or truncated pixel data, naming the file.
    """
    p = Path(path)
    data = p.read_bytes()
    pos = 0
    tokens: list[bytes] = []
    for _ in range(4):
        m = _PNM_TOKEN.match(data, pos)
        if m is None:
            raise MapFileError("PGM header is incomplete", path=p)
        tokens.append(m.group(1))
        pos = m.end()
    magic = tokens[0]
    if magic not in (b"P5", b"P2"):
        raise MapFileError(f"not a PGM file (magic {magic[:8]!r}, expected P5 or P2)", path=p)
    try:
        w, h, maxval = (int(t) for t in tokens[1:])
    except ValueError:
        raise MapFileError(f"bad PGM header {b' '.join(tokens)!r}", path=p) from None
    if w <= 0 or h <= 0 or not 0 < maxval < 65536:
        raise MapFileError(f"bad PGM size {w} x {h} or maxval {maxval}", path=p)
    if magic == b"P5":
        pos += 1  # exactly one whitespace byte separates the header from the pixels
        dtype = np.dtype(">u2") if maxval > 255 else np.dtype(np.uint8)
        need = w * h * dtype.itemsize
        if len(data) - pos < need:
            raise MapFileError(
                f"PGM pixel data truncated: {len(data) - pos} bytes, expected {need}", path=p
            )
        vals = np.frombuffer(data, dtype=dtype, count=w * h, offset=pos).astype(np.float64)
    else:
        try:
            vals = np.array(data[pos:].split(), dtype=np.float64)
        except ValueError:
            raise MapFileError("non-numeric pixel in ASCII PGM", path=p) from None
        if vals.size < w * h:
            raise MapFileError(f"PGM has {vals.size} pixels, expected {w * h}", path=p)
        vals = vals[: w * h]
    if vals.max(initial=0.0) > maxval:
        raise MapFileError(f"pixel value above maxval {maxval}", path=p)
    img = vals.reshape(h, w)
    return img if maxval == 255 else img * (255.0 / maxval)


def _read_image(path: Path) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
    """Grey level 0-255 (mean of the colour channels) and alpha (or None), row 0 = top."""
    with open(path, "rb") as f:
        head = f.read(2)
    if head in (b"P5", b"P2"):
        return read_pgm(path), None
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as img:
            img.load()
            has_alpha = img.mode in ("LA", "RGBA", "PA") or "transparency" in img.info
            if img.mode in ("I;16", "I;16B", "I;16L", "I"):
                a16 = np.asarray(img, dtype=np.float64)
                return a16 * (255.0 / 65535.0), None
            conv = img.convert("RGBA" if has_alpha else "RGB")
            arr = np.asarray(conv, dtype=np.float64)
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise MapFileError(f"cannot read image: {exc}", path=path) from None
    grey = arr[..., :3].mean(axis=-1)
    return grey, (arr[..., 3] if has_alpha else None)


# ---------------------------------------------------------------------------- map_server in


def _yaml_number(doc: Mapping[str, Any], key: str, path: Path) -> float:
    if key not in doc:
        raise MapFileError("missing field", path=path, field=key)
    v = doc[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise MapFileError(f"expected a finite number, got {v!r}", path=path, field=key)
    return float(v)


def read_map_server(yaml_path: str | os.PathLike[str]) -> MapServerMap:
    """Read a map_server map (YAML + PGM/PNG image) as map_server interprets it.

    Required fields: ``image``, ``resolution``, ``origin``, ``occupied_thresh`` and
    ``free_thresh``; ``negate`` defaults to 0 and ``mode`` to ``trinary``. A relative ``image``
    is taken from the YAML's folder.

    Raises
    ------
    FileNotFoundError
        The YAML or the image does not exist.
    MapFileError
        Invalid YAML or a missing or invalid field (named), or an unreadable image.
    """
    import yaml

    ypath = Path(yaml_path)
    text = ypath.read_text(encoding="utf-8", errors="replace")
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:  # one line: its problem and where, not yaml's drawing
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or type(exc).__name__
        at = f" at line {mark.line + 1}" if mark is not None else ""
        raise MapFileError(f"not valid YAML ({problem}{at})", path=ypath) from None
    if not isinstance(doc, dict):
        raise MapFileError("expected a YAML mapping of map_server fields", path=ypath)

    if "image" not in doc:
        raise MapFileError("missing field", path=ypath, field="image")
    if not isinstance(doc["image"], str) or not doc["image"].strip():
        raise MapFileError(f"expected a file name, got {doc['image']!r}", path=ypath, field="image")
    res = _yaml_number(doc, "resolution", ypath)
    if res <= 0.0:
        raise MapFileError(f"must be positive, got {res}", path=ypath, field="resolution")
    if "origin" not in doc:
        raise MapFileError("missing field", path=ypath, field="origin")
    origin = doc["origin"]
    if (
        not isinstance(origin, list)
        or len(origin) not in (2, 3)
        or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            for v in origin
        )
    ):
        raise MapFileError(
            f"expected [x, y, yaw] finite numbers, got {origin!r}", path=ypath, field="origin"
        )
    yaw = float(origin[2]) if len(origin) == 3 else 0.0
    occ = _yaml_number(doc, "occupied_thresh", ypath)
    free = _yaml_number(doc, "free_thresh", ypath)
    for key, val in (("occupied_thresh", occ), ("free_thresh", free)):
        if not 0.0 <= val <= 1.0:
            raise MapFileError(f"must lie in [0, 1], got {val}", path=ypath, field=key)
    if free > occ:
        raise MapFileError(
            f"free_thresh {free} is above occupied_thresh {occ}", path=ypath, field="free_thresh"
        )
    neg = doc.get("negate", 0)
    if isinstance(neg, bool) or neg in (0, 1):
        negate = bool(neg)
    else:
        raise MapFileError(f"expected 0 or 1, got {neg!r}", path=ypath, field="negate")
    mode = doc.get("mode", "trinary")
    if mode not in MODES:
        raise MapFileError(f"expected one of {MODES}, got {mode!r}", path=ypath, field="mode")

    ipath = Path(doc["image"])
    if not ipath.is_absolute():
        ipath = ypath.parent / ipath
    if not ipath.is_file():
        raise FileNotFoundError(
            2, f"{ypath}: field 'image': image file {ipath} does not exist", str(ipath)
        )
    grey, alpha = _read_image(ipath)
    if negate:
        grey = 255.0 - grey
    if mode == "raw":
        level = np.rint(grey)
        prob = np.where(level <= 100.0, level / 100.0, np.nan)
    else:
        prob = (255.0 - grey) / 255.0
        unknown = (prob <= occ) & (prob >= free)
        if mode == "scale":
            unknown &= alpha == 0 if alpha is not None else np.zeros_like(unknown)
        prob = np.where(unknown, np.nan, prob)
    if yaw != 0.0:
        warnings.warn(
            f"{ypath}: origin yaw {yaw} rad is kept in origin_yaw; GridSpec is axis-aligned",
            stacklevel=2,
        )
    h, w = prob.shape
    spec = GridSpec(res, (float(origin[0]), float(origin[1])), (h, w))
    return MapServerMap(
        spec=spec,
        probability=np.ascontiguousarray(prob[::-1], dtype=np.float64),
        occupied_thresh=occ,
        free_thresh=free,
        negate=negate,
        mode=mode,
        image=ipath,
        origin_yaw=yaw,
    )


# ---------------------------------------------------------------------------- npz


def _npz_arrays(
    grid: GridLike, observed: NDArray[np.bool_] | None = None
) -> dict[str, NDArray[Any]]:
    spec = grid.spec
    lo = np.asarray(grid.log_odds, dtype=np.float32)
    seen = np.asarray(grid.observed if observed is None else observed, dtype=bool)
    if lo.shape != spec.shape or seen.shape != spec.shape:
        raise ValueError(
            f"grid arrays {lo.shape}, {seen.shape} do not match spec.shape {spec.shape}"
        )
    return {
        "format": np.array(NPZ_FORMAT),
        "version": np.array(NPZ_VERSION, dtype=np.int64),
        "log_odds": lo,
        "observed": seen,
        "resolution": np.array(spec.resolution, dtype=np.float64),
        "origin": np.array(spec.origin, dtype=np.float64),
        "shape": np.array(spec.shape, dtype=np.int64),
        "p0": np.array(float(grid.p0), dtype=np.float64),
        "clamp": np.array(grid.clamp, dtype=np.float64),
    }


def _write_npz(
    f: IO[bytes],
    grid: GridLike,
    observed_rows: Callable[[int, int], NDArray[np.bool_]] | None = None,
) -> None:
    """The ``.npz`` layout of ``np.savez_compressed`` (one ``NAME.npy`` per array in a zip), at
    deflate level 3: twice as fast as numpy's default level on large grids, files ~30% larger.
    ``observed_rows(r0, r1)``, when given, yields the observed mask in blocks of rows, which are
    streamed into the archive instead of the whole mask (the bytes are those of the whole)."""
    h, w = grid.spec.shape
    if observed_rows is None:
        arrays = _npz_arrays(grid)
    else:  # a zero-stride stand-in of the right shape (no memory) for the shape checks
        stub = np.lib.stride_tricks.as_strided(np.zeros(1, dtype=bool), (h, w), (0, 0))
        arrays = _npz_arrays(grid, stub)
    rows = max(1, _CHUNK_CELLS // max(w, 1))
    with zipfile.ZipFile(f, "w", zipfile.ZIP_DEFLATED, compresslevel=3) as zf:
        for name, arr in arrays.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as member:
                if name != "observed" or observed_rows is None:
                    np.lib.format.write_array(member, arr, allow_pickle=False)
                    continue
                header = {"descr": "|b1", "fortran_order": False, "shape": (h, w)}
                np.lib.format.write_array_header_1_0(member, header)
                for r0 in range(0, h, rows):
                    block = np.asarray(observed_rows(r0, min(h, r0 + rows)), dtype=bool)
                    member.write(np.ascontiguousarray(block).tobytes())


def save_npz(path: str | os.PathLike[str], grid: GridLike) -> Path:
    """Save a grid losslessly (float32 log odds, observed mask, spec, p0, clamp) atomically.

    The file is a compressed NumPy archive holding ``format``, ``version``, ``log_odds`` (H, W)
    float32, ``observed`` (H, W) bool, ``resolution``, ``origin`` (2,), ``shape`` (2,), ``p0`` and
    ``clamp`` (2,). Load it with :func:`load_npz`.
    """
    p = Path(path)
    buf = io.BytesIO()
    _write_npz(buf, grid)
    with atomic_files([p]) as (f,):
        f.write(buf.getvalue())
    return p


def open_npz(
    path: str | os.PathLike[str], what: str, error: type[DatasetError] = MapFileError
) -> tuple[Path, Any]:
    """``(path, archive)``: the ``.npz`` archive at ``path`` opened without pickles.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    DatasetError
        ``error`` (a :class:`~probmap.errors.DatasetError`), "not a ``what``", when the file
        is not an ``.npz`` archive (a single ``.npy`` array included).
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(2, f"{p}: no such file", str(p))
    try:
        z = np.load(p, allow_pickle=False)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise error(f"not a {what} ({exc})", path=p) from None
    if not hasattr(z, "files"):
        raise error(f"not a {what} (a single .npy array)", path=p)
    return p, z


def npz_array(
    z: Any, key: str, path: Path, error: type[DatasetError] = MapFileError
) -> NDArray[Any]:
    """Array ``key`` of the open archive ``z``; ``error`` naming the file and the key when it
    is missing or cannot be read."""
    if key not in z.files:
        raise error("missing array", path=path, field=key)
    try:
        return np.asarray(z[key])
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise error(f"corrupt array ({exc})", path=path, field=key) from None


def check_npz_format(
    z: Any,
    path: Path,
    fmt: str,
    version: int,
    what: str,
    error: type[DatasetError] = MapFileError,
) -> None:
    """Raise ``error`` unless the archive's ``format`` is ``fmt`` and its ``version`` is at most
    ``version`` (this reader reads older versions)."""
    found = npz_array(z, "format", path, error)
    if found.shape != () or str(found) != fmt:
        raise error(f"not a {what} (format {found!r})", path=path, field="format")
    v = int(npz_array(z, "version", path, error))
    if v > version:
        raise error(
            f"format version {v} is newer than this probmap reads ({version})",
            path=path,
            field="version",
        )


def load_npz(path: str | os.PathLike[str]) -> OccupancyGrid:
    """Load a grid saved by :func:`save_npz` as an :class:`~probmap.grid.occupancy.OccupancyGrid`.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    MapFileError
        Not a probmap map archive, a newer format version, or missing/corrupt/inconsistent arrays
        (the message names the file and array).
    """
    from probmap.grid.occupancy import OccupancyGrid

    p, z = open_npz(path, "probmap .npz map")
    with z:
        try:
            check_npz_format(z, p, NPZ_FORMAT, NPZ_VERSION, "probmap map archive")
            lo = npz_array(z, "log_odds", p)
            seen = npz_array(z, "observed", p)
            shape = tuple(int(v) for v in npz_array(z, "shape", p).ravel())
            origin = npz_array(z, "origin", p).astype(np.float64).ravel()
            res = float(npz_array(z, "resolution", p))
            p0 = float(npz_array(z, "p0", p))
            clamp_a = npz_array(z, "clamp", p).astype(np.float64).ravel()
        except MapFileError:
            raise
        except (TypeError, ValueError) as exc:
            raise MapFileError(f"malformed map archive ({exc})", path=p) from None
    if lo.dtype != np.float32 or lo.ndim != 2:
        raise MapFileError(
            f"expected a 2-D float32 array, got {lo.dtype} {lo.shape}", path=p, field="log_odds"
        )
    if len(shape) != 2 or lo.shape != shape:
        raise MapFileError(
            f"log_odds shape {lo.shape} does not match shape {shape}", path=p, field="shape"
        )
    if seen.dtype != np.bool_ or seen.shape != lo.shape:
        raise MapFileError(f"expected a bool array of shape {lo.shape}", path=p, field="observed")
    if origin.shape != (2,) or clamp_a.shape != (2,):
        raise MapFileError("origin and clamp must hold two numbers", path=p, field="origin")
    for name, vals in (("origin", origin), ("resolution", [res]), ("p0", [p0]), ("clamp", clamp_a)):
        if not np.isfinite(vals).all():
            raise MapFileError(f"must be finite, got {list(map(float, vals))}", path=p, field=name)
    if not np.isfinite(lo).all():
        bad = int(np.count_nonzero(~np.isfinite(lo)))
        raise MapFileError(f"{bad:,} cells hold NaN or inf", path=p, field="log_odds")
    try:
        spec = GridSpec(res, (float(origin[0]), float(origin[1])), (shape[0], shape[1]))
        grid = OccupancyGrid.from_log_odds(
            spec, lo, p0=p0, clamp=(float(clamp_a[0]), float(clamp_a[1])), observed=seen
        )
    except ValueError as exc:
        raise MapFileError(f"inconsistent map ({exc})", path=p) from None
    # stored log odds lie within the clamp (float32 rounding allowed); outside it they would
    # never be reached by an update and break the map's probabilities
    tol = 1e-4 * max(1.0, abs(grid.l_min), abs(grid.l_max))
    if lo.size and (float(lo.min()) < grid.l_min - tol or float(lo.max()) > grid.l_max + tol):
        raise MapFileError(
            f"values {float(lo.min()):g}..{float(lo.max()):g} lie outside the clamp bounds "
            f"[{grid.l_min:g}, {grid.l_max:g}] (logit of clamp {grid.clamp})",
            path=p,
            field="log_odds",
        )
    return grid


# ---------------------------------------------------------------------------- preview


def preview_image(grid: GridLike, scale: int = 1) -> NDArray[np.uint8]:
    """Grey preview, row 0 = top: observed cells white (``p <= 0.25``) to black
    (``p >= 0.75``), linear between; never-observed cells mid-grey (128)."""
    p = np.asarray(grid.probability(), dtype=np.float64)
    return _preview_pixels(p, np.asarray(grid.observed, dtype=bool), scale)


def _preview_pixels(
    p: NDArray[np.float64], seen: NDArray[np.bool_], scale: int
) -> NDArray[np.uint8]:
    require_integer("scale", scale, 1)
    q = np.clip((PREVIEW_OCCUPIED_P - p) / (PREVIEW_OCCUPIED_P - PREVIEW_FREE_P), 0.0, 1.0)
    v = np.where(seen, np.rint(255.0 * q), PREVIEW_UNKNOWN).astype(np.uint8)[::-1]
    if scale > 1:
        v = np.repeat(np.repeat(v, scale, axis=0), scale, axis=1)
    return np.ascontiguousarray(v)


def save_png(path: str | os.PathLike[str], grid: GridLike, *, scale: int = 1) -> Path:
    """Write a grey PNG preview (free white, occupied black, unknown mid-grey), atomically.

    ``scale`` enlarges every cell to ``scale x scale`` pixels.
    """
    p = Path(path)
    data = png_bytes(preview_image(grid, scale))
    with atomic_files([p]) as (f,):
        f.write(data)
    return p


# ---------------------------------------------------------------------------- all at once


def prefix_path(prefix: str | os.PathLike[str]) -> Path:
    """``prefix`` as a path whose name the writers extend (``PREFIX.npz`` ...); a
    :class:`ValueError` when it has no file name part (``""``, ``"."``, ``".."``)."""
    base = Path(prefix)
    if base.name in ("", ".", ".."):
        raise ValueError(f"output prefix {os.fspath(prefix)!r} needs a file name part")
    return base


# write_map_server's thresholds (the same encoding helpers), then the preview's png_scale.
def save_map(
    prefix: str | os.PathLike[str],
    grid: GridLike,
    *,
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
    mode: str = "trinary",
    png_scale: int = 1,
) -> list[Path]:
    """Write ``PREFIX.yaml``, ``PREFIX.pgm``, ``PREFIX.npz`` and ``PREFIX.png`` all-or-nothing.

    The images and the observed mask are streamed into temporary files in blocks of rows (a
    large map never needs them, nor its probabilities, whole); the files are renamed only
    once all four are complete, so a failure (an unwritable folder, a full disk) leaves no
    output file at all.

    Returns
    -------
    list of Path
        The four files, in the order above.
    """
    base = prefix_path(prefix)
    paths = [base.parent / f"{base.name}.{ext}" for ext in ("yaml", "pgm", "npz", "png")]
    yaml_text = _yaml_text(paths[1].name, grid.spec, occupied_thresh, free_thresh, False, mode)
    _check_thresholds(occupied_thresh, free_thresh)
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    require_integer("png_scale", png_scale, 1)
    seen_rows = _observed_rows(grid)
    with atomic_files(paths) as (fy, fp, fn, fi):
        fy.write(yaml_text.encode("utf-8"))
        _stream_map_images(grid, seen_rows, fp, fi, occupied_thresh, free_thresh, mode, png_scale)
        _write_npz(fn, grid, seen_rows)
    return paths


_CHUNK_CELLS = 1 << 20  # cells per block when a large map is encoded block by block


def _observed_rows(grid: GridLike) -> Callable[[int, int], NDArray[np.bool_]]:
    """``rows(r0, r1)``: the grid's observed mask over rows ``r0:r1``. An
    :class:`~probmap.grid.occupancy.OccupancyGrid` reads its stamps block by block; another
    grid's whole mask is computed once."""
    from probmap.grid.occupancy import OccupancyGrid

    if isinstance(grid, OccupancyGrid):
        return grid.observed_rows
    whole = np.asarray(grid.observed, dtype=bool)
    return lambda r0, r1: whole[r0:r1]


def _stream_map_images(
    grid: GridLike,
    seen_rows: Callable[[int, int], NDArray[np.bool_]],
    pgm: IO[bytes],
    png: IO[bytes],
    occupied_thresh: float,
    free_thresh: float,
    mode: str,
    scale: int,
) -> None:
    """Stream the map-server PGM and the grey preview PNG of ``grid`` into ``pgm`` and
    ``png``, top row first, in blocks of rows: a large map never needs its probabilities
    (8 bytes a cell), its observed mask or either image all at once. The pixels are those of
    the whole-array encoders (:func:`_encode_pixels`, :func:`_preview_pixels`)."""
    from probmap.grid.logodds import prob
    from probmap.grid.occupancy import OccupancyGrid

    h, w = grid.spec.shape
    p0 = float(grid.p0)
    whole = None if isinstance(grid, OccupancyGrid) else np.asarray(grid.probability(), float)
    _write_pgm_header(pgm, h, w)
    preview = _PngStream(png, w * scale, h * scale)
    rows = max(1, _CHUNK_CELLS // max(w, 1))
    for r1 in range(h, 0, -rows):  # top (largest y) first, as both images are stored
        r0 = max(0, r1 - rows)
        if whole is None:  # exactly OccupancyGrid.probability, block by block
            p = np.asarray(prob(grid.log_odds[r0:r1]), dtype=np.float64)
        else:
            p = whole[r0:r1]
        sb = np.asarray(seen_rows(r0, r1), dtype=bool)
        g, _ = _encode_pixels(p, sb, p0, occupied_thresh, free_thresh, False, mode)
        _write_pgm_rows(pgm, g)
        preview.rows(_preview_pixels(p, sb, scale))
    preview.close()


def _write_pgm_header(f: IO[bytes], h: int, w: int) -> None:
    """The header of a binary PGM of ``h`` rows of ``w`` pixels (:func:`_pgm_header`)."""
    f.write(_pgm_header(np.empty((h, w), dtype=np.uint8)))


def _write_pgm_rows(f: IO[bytes], rows: NDArray[np.uint8]) -> None:
    """The pixels of a block of rows of a binary PGM (top row first)."""
    f.write(memoryview(np.ascontiguousarray(rows, dtype=np.uint8).data).cast("B"))


class _PngStream:
    """An 8-bit grey PNG written block of rows by block of rows (filter type 0 on every row,
    one zlib stream at level 3 split over ``IDAT`` chunks), for an image too large to hold
    whole, as an encoder given the whole array would need.

    Parameters
    ----------
    f : binary file
        Where the PNG goes.
    width, height : int
        Image size, pixels.
    """

    def __init__(self, f: IO[bytes], width: int, height: int) -> None:
        self._f = f
        self._zlib = zlib.compressobj(3)
        self._width = int(width)
        self._left = int(height)
        f.write(b"\x89PNG\r\n\x1a\n")
        self._chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))

    def _chunk(self, kind: bytes, data: bytes) -> None:
        self._f.write(struct.pack(">I", len(data)) + kind)
        self._f.write(data)
        self._f.write(struct.pack(">I", zlib.crc32(data, zlib.crc32(kind)) & 0xFFFFFFFF))

    def rows(self, block: NDArray[np.uint8]) -> None:
        """Append rows (top first), shape (n, width) uint8."""
        block = np.asarray(block, dtype=np.uint8)
        if block.ndim != 2 or block.shape[1] != self._width or block.shape[0] > self._left:
            raise ValueError(f"rows of shape {block.shape} do not fit the image")
        self._left -= block.shape[0]
        raw = np.zeros((block.shape[0], self._width + 1), dtype=np.uint8)  # filter byte 0
        raw[:, 1:] = block
        data = self._zlib.compress(raw.tobytes())
        if data:
            self._chunk(b"IDAT", data)

    def close(self) -> None:
        """Flush the compressed stream and end the image."""
        if self._left:
            raise ValueError(f"{self._left} rows of the image were never written")
        self._chunk(b"IDAT", self._zlib.flush())
        self._chunk(b"IEND", b"")
