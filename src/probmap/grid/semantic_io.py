"""Semantic map files and labelled scan files.

Semantic map (``.npz``, lossless): the grid's float32 log odds, observed mask, class names,
colours, geometry, prior, clamping bounds and inverse sensor model; :func:`load_semantic` rebuilds
exactly the grid :func:`save_semantic` wrote. Colour image (``.png``): each observed cell in the
colour of its most probable class, unknown cells grey, with a legend of class names on the right.
The derived occupancy grid goes to the ROS map_server format through :mod:`probmap.grid.io`.

Labelled scans (``.npz``), read by :func:`read_labelled_scans`:

============== ================ ===========================================================
key            shape, dtype     meaning
============== ================ ===========================================================
poses          (S, 3) float     sensor pose ``(x, y, theta)`` per scan, metres and radians
ranges         (S, B) float     range per beam, metres; NaN/inf/<= 0: dropped reading;
                                ``>= max_range``: no return
angles         (B,) or (S, B)   beam angles in the sensor frame, radians (CCW, 0 = ahead)
max_range      () float         the sensor's maximum range, metres
classes        (K + 1,) str     class names; ``classes[0]`` is free space (the reference)
labels         (S, B) int       hard label 1..K of each beam's endpoint (any value for
                                beams without an endpoint), or instead:
probabilities  (S, B, K) float  class distribution over classes 1..K of each endpoint
colors         (K + 1, 3) uint8 optional RGB colour per class
============== ================ ===========================================================

Exactly one of ``labels`` and ``probabilities`` is present. Every writer is atomic.
"""

from __future__ import annotations

import io
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from probmap._atomic import atomic_files, atomic_outputs
from probmap._checks import require_integer
from probmap.errors import SemanticFileError
from probmap.grid.io import check_npz_format, npz_array, open_npz, prefix_path
from probmap.grid.semantic import (
    LabelledInverseModel,
    SemanticGrid,
    check_labels,
    check_probabilities,
)
from probmap.grid.spec import GridSpec

NPZ_FORMAT = "probmap.SemanticGrid"
NPZ_VERSION = 1
UNKNOWN_RGB = (205, 205, 205)


# --------------------------------------------------------------------------- semantic map npz
def _grid_arrays(grid: SemanticGrid) -> dict[str, NDArray[Any]]:
    m = grid.model
    return {
        "format": np.array(NPZ_FORMAT),
        "version": np.array(NPZ_VERSION),
        "log_odds": grid.log_odds,
        "observed": grid.observed,
        "scans": np.array(grid.scans_integrated, dtype=np.int64),
        "classes": np.array(grid.classes),
        "colors": grid.colors,
        "resolution": np.array(grid.spec.resolution),
        "origin": np.array(grid.spec.origin),
        "shape": np.array(grid.spec.shape, dtype=np.int64),
        "prior": grid.prior,
        "clamp": grid.clamp,
        "fixed": np.array(grid.fixed),
        "model": np.array(
            [
                m.p_hit,
                m.p_miss,
                m.p_correct,
                m.thickness,
                math.nan if m.max_clear_range is None else m.max_clear_range,
                m.label_floor,
            ]
        ),
    }


def semantic_npz_bytes(grid: SemanticGrid) -> bytes:
    """The ``.npz`` encoding of a semantic map (see :func:`save_semantic`)."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **_grid_arrays(grid))  # type: ignore[arg-type]
    return buf.getvalue()


def save_semantic(path: str | os.PathLike[str], grid: SemanticGrid) -> Path:
    """Write a semantic map losslessly to ``path`` (``.npz``), atomically.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> g = SemanticGrid(["free", "wall", "door"], resolution=0.1)
    >>> _ = g.integrate_scan([0, 0, 0], [1.0, 1.5], [0.0, 0.5], labels=[1, 2], max_range=4)
    >>> p = save_semantic(pathlib.Path(tempfile.mkdtemp()) / "m.npz", g)
    >>> h = load_semantic(p)
    >>> bool((h.log_odds == g.log_odds).all()), h.classes
    (True, ('free', 'wall', 'door'))
    """
    p = Path(path)
    data = semantic_npz_bytes(grid)
    with atomic_files([p]) as (f,):
        f.write(data)
    return p


def _get(z: Any, key: str, path: Path) -> NDArray[Any]:
    return npz_array(z, key, path, SemanticFileError)


def _open_npz(path: str | os.PathLike[str]) -> tuple[Path, Any]:
    return open_npz(path, ".npz file", SemanticFileError)


def load_semantic(path: str | os.PathLike[str]) -> SemanticGrid:
    """Read a semantic map written by :func:`save_semantic`.

    Raises
    ------
    SemanticFileError
        A missing or inconsistent key; the message names the file and key.
    """
    p, z = _open_npz(path)
    with z:
        check_npz_format(
            z, p, NPZ_FORMAT, NPZ_VERSION, "probmap semantic map archive", SemanticFileError
        )
        lo = _get(z, "log_odds", p)
        observed = _get(z, "observed", p)
        classes = [str(c) for c in _get(z, "classes", p).ravel()]
        model_v = _get(z, "model", p).astype(np.float64).ravel()
        if model_v.shape != (6,):
            raise SemanticFileError(
                f"expected 6 numbers, got {model_v.shape}", path=p, field="model"
            )
        field = "spec"
        try:
            spec = GridSpec(
                float(_get(z, "resolution", p)),
                tuple(float(v) for v in _get(z, "origin", p).ravel()),  # type: ignore[arg-type]
                tuple(int(v) for v in _get(z, "shape", p).ravel()),  # type: ignore[arg-type]
            )
            field = "model"
            model = LabelledInverseModel(
                p_hit=float(model_v[0]),
                p_miss=float(model_v[1]),
                p_correct=float(model_v[2]),
                thickness=float(model_v[3]),
                max_clear_range=None if math.isnan(model_v[4]) else float(model_v[4]),
                label_floor=float(model_v[5]),
            )
            field = "log_odds"
            return SemanticGrid.from_log_odds(
                classes,
                spec,
                lo,
                observed=observed,
                scans=int(_get(z, "scans", p)),
                prior=_get(z, "prior", p),
                clamp=_get(z, "clamp", p),
                model=model,
                colors=_get(z, "colors", p),
                fixed=bool(_get(z, "fixed", p)),
            )
        except (ValueError, TypeError) as exc:
            if isinstance(exc, SemanticFileError):
                raise
            raise SemanticFileError(f"inconsistent map ({exc})", path=p, field=field) from None


# --------------------------------------------------------------------------- colour image
def semantic_image(grid: SemanticGrid, *, scale: int = 1, legend: bool = True) -> NDArray[np.uint8]:
    """RGB image (row 0 = top) of the most probable class of each observed cell.

    Unknown cells are grey (205). With ``legend`` a panel on the right lists each class's colour
    and name. ``scale`` enlarges every cell to ``scale x scale`` pixels.
    """
    require_integer("scale", scale, 1)
    cls = grid.classify()
    rgb = np.empty((*cls.shape, 3), dtype=np.uint8)
    rgb[...] = UNKNOWN_RGB
    seen = cls >= 0
    rgb[seen] = grid.colors[cls[seen]]
    img = rgb[::-1]
    if scale > 1:
        img = np.repeat(np.repeat(img, scale, axis=0), scale, axis=1)
    if not legend:
        return np.ascontiguousarray(img)
    panel = _legend_panel(grid.classes, grid.colors, img.shape[0])
    h = max(img.shape[0], panel.shape[0])
    out = np.full((h, img.shape[1] + panel.shape[1], 3), 255, dtype=np.uint8)
    out[: img.shape[0], : img.shape[1]] = img
    out[: panel.shape[0], img.shape[1] :] = panel
    return out


LEGEND_ROW = 18  # pixels per legend entry
LEGEND_SWATCH = 12


def _legend_panel(
    classes: tuple[str, ...], colors: NDArray[np.uint8], height: int
) -> NDArray[np.uint8]:
    """A white panel with, per class, a colour swatch (outlined) and the class name."""
    from PIL import Image, ImageDraw, ImageFont

    font = ImageFont.load_default()
    rows = len(classes) + 1
    width = (
        24
        + max(
            int(ImageDraw.Draw(Image.new("RGB", (1, 1))).textlength(c, font=font))
            for c in [*classes, "unknown"]
        )
        + 8
    )
    panel = Image.new("RGB", (width, max(rows * LEGEND_ROW + 8, 1)), (255, 255, 255))
    draw = ImageDraw.Draw(panel)
    rgb = [(int(c[0]), int(c[1]), int(c[2])) for c in colors]
    entries = [*zip(classes, rgb, strict=True), ("unknown", UNKNOWN_RGB)]
    for i, (name, col) in enumerate(entries):
        y = 4 + i * LEGEND_ROW
        box = (6, y + 2, 6 + LEGEND_SWATCH, y + 2 + LEGEND_SWATCH)
        draw.rectangle(box, fill=col, outline=(0, 0, 0))
        draw.text((24, y + 2), name, fill=(0, 0, 0), font=font)
    return np.asarray(panel, dtype=np.uint8)


def legend_swatch_centres(n_classes: int, map_width: int) -> list[tuple[int, int]]:
    """Pixel ``(x, y)`` at the centre of each legend swatch: ``n_classes`` classes (class 0
    included), then "unknown"; ``map_width`` is the map's width in pixels."""
    c = 6 + LEGEND_SWATCH // 2 + 1
    return [
        (map_width + c, 4 + i * LEGEND_ROW + 2 + LEGEND_SWATCH // 2 + 1)
        for i in range(n_classes + 1)
    ]


def semantic_png_bytes(grid: SemanticGrid, *, scale: int = 1, legend: bool = True) -> bytes:
    """PNG encoding of :func:`semantic_image`."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(semantic_image(grid, scale=scale, legend=legend), "RGB").save(
        buf, format="PNG", compress_level=3
    )
    return buf.getvalue()


def save_semantic_png(
    path: str | os.PathLike[str], grid: SemanticGrid, *, scale: int = 1, legend: bool = True
) -> Path:
    """Write the colour class map with its legend as a PNG, atomically."""
    p = Path(path)
    data = semantic_png_bytes(grid, scale=scale, legend=legend)
    with atomic_files([p]) as (f,):
        f.write(data)
    return p


def write_semantic_maps(prefix: str | os.PathLike[str], grid: SemanticGrid) -> list[Path]:
    """Write ``PREFIX.npz`` and ``PREFIX.png`` (semantic map and colour image, together
    all-or-nothing), then the derived occupancy grid as ``PREFIX.occupancy.{yaml,pgm,npz,png}``
    (map_server format, :func:`probmap.grid.io.save_map`), the six files all or none. Returns
    the six files."""
    from probmap.grid.io import save_map

    base = prefix_path(prefix)
    paths = [base.parent / f"{base.name}.npz", base.parent / f"{base.name}.png"]
    npz, png = semantic_npz_bytes(grid), semantic_png_bytes(grid)
    occupancy = grid.to_occupancy()
    with atomic_outputs(create_folders=False):
        with atomic_files(paths) as (fn, fp):
            fn.write(npz)
            fp.write(png)
        occ = save_map(base.parent / f"{base.name}.occupancy", occupancy)
    return [*paths, *occ]


# --------------------------------------------------------------------------- labelled scans
@dataclass(frozen=True, eq=False)
class LabelledScans:
    """Labelled range scans with known poses (the ``.npz`` format of this module's docstring).

    Attributes
    ----------
    poses : ndarray, shape (S, 3)
    ranges : ndarray, shape (S, B)
    angles : ndarray, shape (B,) or (S, B)
    max_range : float
    classes : tuple of str
        ``K + 1`` names, ``classes[0]`` free.
    labels : ndarray of int64, shape (S, B), or None
    probabilities : ndarray, shape (S, B, K), or None
    colors : ndarray of uint8, shape (K + 1, 3), or None
    """

    poses: NDArray[np.float64]
    ranges: NDArray[np.float64]
    angles: NDArray[np.float64]
    max_range: float
    classes: tuple[str, ...]
    labels: NDArray[np.int64] | None = None
    probabilities: NDArray[np.float64] | None = None
    colors: NDArray[np.uint8] | None = None

    def __len__(self) -> int:
        return int(self.poses.shape[0])

    def make_grid(self, **kwargs: Any) -> SemanticGrid:
        """A :class:`SemanticGrid` over these classes (``kwargs``: the constructor's)."""
        if self.colors is not None:
            kwargs.setdefault("colors", self.colors)
        return SemanticGrid(self.classes, **kwargs)

    def integrate_into(self, grid: SemanticGrid, start: int = 0, stop: int | None = None) -> Any:
        """Integrate scans ``start:stop`` into ``grid``; returns its ScanStats."""
        sl = slice(start, stop)
        angles = self.angles if self.angles.ndim == 1 else self.angles[sl]
        return grid.integrate_scans(
            self.poses[sl],
            self.ranges[sl],
            angles,
            labels=None if self.labels is None else self.labels[sl],
            probabilities=None if self.probabilities is None else self.probabilities[sl],
            max_range=self.max_range,
        )


def write_labelled_scans(path: str | os.PathLike[str], scans: LabelledScans) -> Path:
    """Write labelled scans in the ``.npz`` format above, atomically."""
    arrays: dict[str, NDArray[Any]] = {
        "poses": np.asarray(scans.poses, dtype=np.float64),
        "ranges": np.asarray(scans.ranges, dtype=np.float64),
        "angles": np.asarray(scans.angles, dtype=np.float64),
        "max_range": np.array(float(scans.max_range)),
        "classes": np.array(scans.classes),
    }
    if scans.labels is not None:
        arrays["labels"] = np.asarray(scans.labels, dtype=np.int64)
    if scans.probabilities is not None:
        arrays["probabilities"] = np.asarray(scans.probabilities, dtype=np.float64)
    if scans.colors is not None:
        arrays["colors"] = np.asarray(scans.colors, dtype=np.uint8)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)  # type: ignore[arg-type]
    p = Path(path)
    with atomic_files([p]) as (f,):
        f.write(buf.getvalue())
    return p


def read_labelled_scans(path: str | os.PathLike[str]) -> LabelledScans:
    """Read and validate labelled scans (the ``.npz`` format of this module's docstring).

    Raises
    ------
    SemanticFileError
        A missing key, a wrong shape or dtype, labels out of range, probability vectors that are
        negative or do not sum to 1, or per-scan arrays of mismatched lengths; the message names
        the file, the key and, for per-scan problems, the scan index.
    """
    p, z = _open_npz(path)
    with z:
        poses = _get(z, "poses", p)
        if poses.ndim != 2 or poses.shape[1] != 3 or poses.dtype.kind not in "fiu":
            raise SemanticFileError(
                f"must be numbers of shape (S, 3), got {poses.shape} {poses.dtype}",
                path=p,
                field="poses",
            )
        poses = poses.astype(np.float64)
        bad = ~np.isfinite(poses).all(axis=1)
        if bad.any():
            raise SemanticFileError(
                f"scan {int(np.argmax(bad))}: pose is not finite", path=p, field="poses"
            )
        S = poses.shape[0]
        ranges = _get(z, "ranges", p)
        if ranges.ndim != 2 or ranges.dtype.kind not in "fiu":
            raise SemanticFileError(
                f"must be numbers of shape (S, B), got {ranges.shape} {ranges.dtype}",
                path=p,
                field="ranges",
            )
        if ranges.shape[0] != S:
            raise SemanticFileError(
                f"{ranges.shape[0]} scans of ranges for {S} poses", path=p, field="ranges"
            )
        ranges = ranges.astype(np.float64)
        B = ranges.shape[1]
        angles = _get(z, "angles", p).astype(np.float64)
        if not (angles.shape == (B,) or angles.shape == (S, B)):
            raise SemanticFileError(
                f"shape {angles.shape} does not match ranges (S, B) = {ranges.shape}",
                path=p,
                field="angles",
            )
        if not np.isfinite(angles).all():
            raise SemanticFileError("angles must be finite", path=p, field="angles")
        mr = _get(z, "max_range", p)
        if mr.size != 1 or not float(mr.ravel()[0]) > 0:
            raise SemanticFileError(
                f"must be one number > 0, got {mr!r}", path=p, field="max_range"
            )
        max_range = float(mr.ravel()[0])
        cl = _get(z, "classes", p)
        if cl.ndim != 1 or cl.dtype.kind not in "US" or cl.size < 2:
            raise SemanticFileError(
                f"must be K + 1 >= 2 class names, got {cl.shape} {cl.dtype}",
                path=p,
                field="classes",
            )
        classes = tuple(str(c) for c in cl)
        K = len(classes) - 1
        has_l, has_p = "labels" in z.files, "probabilities" in z.files
        if has_l == has_p:
            raise SemanticFileError(
                "needs exactly one of the keys 'labels' and 'probabilities'", path=p
            )
        hit = np.isfinite(ranges) & (ranges > 0) & (ranges < max_range)
        labels = probs = None
        key = "labels" if has_l else "probabilities"
        arr = _get(z, key, p)
        want = (S, B) if has_l else (S, B, K)
        if arr.ndim == len(want) and arr.shape[0] == S and S > 0 and arr.shape[1] != B:
            raise SemanticFileError(
                f"{arr.shape[1]} entries per scan from scan 0 on, ranges have {B} beams",
                path=p,
                field=key,
            )
        if arr.shape != want:
            raise SemanticFileError(f"shape {arr.shape}, want {want}", path=p, field=key)
        try:
            if has_l:
                labels = check_labels(arr, hit, classes)
            else:
                probs = check_probabilities(arr, hit)
        except ValueError as exc:
            raise SemanticFileError(str(exc), path=p, field=key) from None
        colors = None
        if "colors" in z.files:
            colors = _get(z, "colors", p)
            if colors.shape != (K + 1, 3) or (colors.dtype.kind not in "iu"):
                raise SemanticFileError(
                    f"must be integers of shape ({K + 1}, 3), got {colors.shape} {colors.dtype}",
                    path=p,
                    field="colors",
                )
            if (colors < 0).any() or (colors > 255).any():
                raise SemanticFileError("must lie in 0..255", path=p, field="colors")
            colors = colors.astype(np.uint8)
    return LabelledScans(poses, ranges, angles, max_range, classes, labels, probs, colors)
