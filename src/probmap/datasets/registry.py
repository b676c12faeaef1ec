"""The dataset registry: known datasets by name, format guessing, and loading.

``load("victoria-park")`` looks the name up in :data:`DATASETS` and opens it under the data
directory (the ``data_dir`` argument, else the ``PROBMAP_DATA`` environment variable, else
``../shared/data`` relative to the working directory when it exists);
``load("/some/folder/MRCLAM_Dataset3", robot=2)`` guesses the format from the path instead
(:func:`guess_format`). Readers are imported only when used. :func:`resolve_input` is what every
command that takes a path uses: the path when it exists, else a registered name's file.
"""

from __future__ import annotations

import difflib
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from probmap.errors import DatasetError

__all__ = [
    "DATASETS",
    "FORMATS",
    "DatasetInfo",
    "data_dir",
    "guess_format",
    "load",
    "resolve",
    "resolve_input",
]

DATA_ENV = "PROBMAP_DATA"
#: The data directory when neither an argument nor ``$PROBMAP_DATA`` names one (relative to the
#: working directory: a clone beside ``shared/data``).
DEFAULT_DATA = Path("..") / "shared" / "data"


def _victoria_park(path: Path, **kw: Any) -> Any:
    from probmap.datasets.victoria_park import VictoriaPark

    return VictoriaPark(path, **kw)


def _mrclam(path: Path, **kw: Any) -> Any:
    from probmap.datasets.utias import MRCLAM

    return MRCLAM(path, **kw)


def _g2o(path: Path, **kw: Any) -> Any:
    from probmap.datasets.g2o import read_g2o

    return read_g2o(path, **kw)


def _carmen(path: Path, **kw: Any) -> Any:
    from probmap.datasets.carmen import CarmenLog

    return CarmenLog(path, **kw)


def _rosbag(path: Path, **kw: Any) -> Any:
    from probmap.datasets.ros.scans import RosBag

    return RosBag(path, **kw)


def _simulation(path: Path | None, **kw: Any) -> Any:
    from probmap.datasets.simulation import simulate_landmarks

    kw.setdefault("n_landmarks", 200)
    kw.setdefault("n_steps", 2000)
    kw.setdefault("seed", 0)
    return simulate_landmarks(**kw)


FORMATS: dict[str, Callable[..., Any]] = {
    "victoria-park": _victoria_park,
    "mrclam": _mrclam,
    "g2o": _g2o,
    "carmen": _carmen,
    "rosbag": _rosbag,
    "simulation": _simulation,
}
"""Format name -> loader ``(path, **options) -> dataset``."""


@dataclass(frozen=True)
class DatasetInfo:
    """A registered dataset.

    Attributes
    ----------
    name : str
    format : str
        Key of :data:`FORMATS`.
    relpath : str or None
        Location under the data directory (None for generated data).
    kind : str
        ``landmarks``, ``laser`` or ``graph``: what the dataset yields.
    description : str
    options : dict
        Default loader options.
    """

    name: str
    format: str
    relpath: str | None
    kind: str
    description: str
    options: dict[str, Any] = field(default_factory=dict)


# Not fetch.DATASETS (the files `datasets fetch` downloads): this table is what a command reads
# and with which loader (simulation included, relation files and graph collections not).
DATASETS: dict[str, DatasetInfo] = {
    d.name: d
    for d in (
        DatasetInfo(
            "victoria-park",
            "victoria-park",
            "victoria-park",
            "landmarks",
            "Victoria Park, Sydney: car with encoder/steering, tree detections, GPS (unknown ids)",
        ),
        DatasetInfo(
            "mrclam7",
            "mrclam",
            "utias-mrclam/MRCLAM_Dataset7",
            "landmarks",
            "UTIAS MRCLAM Dataset 7: 5 robots, 15 barcoded landmarks, Vicon truth (--robot N)",
        ),
        DatasetInfo(
            "victoria-park-g2o",
            "g2o",
            "victoria-park/victoriaPark-full.g2o",
            "graph",
            "Victoria Park as a g2o pose-landmark graph (6,969 poses, 151 landmarks)",
        ),
        DatasetInfo(
            "intel",
            "carmen",
            "intel-research-lab/intel.clf.bz2",
            "laser",
            "Intel Research Lab, Seattle: raw CARMEN laser log",
        ),
        DatasetInfo(
            "intel-corrected",
            "carmen",
            "intel-research-lab/intel-corrected.log.gz",
            "laser",
            "Intel Research Lab, GMapping-corrected poses (910 scans)",
        ),
        DatasetInfo(
            "intel-bag",
            "rosbag",
            "intel-research-lab/intel.orig.bag",
            "laser",
            "Intel Research Lab, the raw log as a ROS 1 bag (/scan, /odom, /tf)",
        ),
        DatasetInfo(
            "freiburg-clinic",
            "carmen",
            "freiburg-clinic/fr-clinic_robotlaser.clf.bz2",
            "laser",
            "Freiburg university hospital: raw ROBOTLASER1 log",
        ),
        DatasetInfo(
            "deutsches-museum-bag",
            "rosbag",
            "ros-bags/b0-2014-07-21-12-42-53-short.bag",
            "laser",
            "Cartographer's Deutsches Museum backpack, 10 s ROS 1 bag (two multi-echo lasers: "
            "--scan-topic)",
        ),
        DatasetInfo(
            "freiburg-campus-corrected",
            "carmen",
            "freiburg-campus/freiburg-campus-corrected.log.gz",
            "laser",
            "Freiburg campus, GMapping-corrected poses",
        ),
        DatasetInfo(
            "simulation",
            "simulation",
            None,
            "landmarks",
            "Seeded simulated landmark world (n_landmarks, n_steps, seed options)",
        ),
    )
}


def given_data_dir(explicit: str | os.PathLike[str] | None = None) -> Path | None:
    """The data directory the caller or the environment names: ``explicit``, else
    ``$PROBMAP_DATA`` (when set and not empty), else None. :func:`data_dir` and
    :func:`probmap.datasets.fetch.default_directory` start from it, each with its own last
    resort."""
    if explicit is not None:
        return Path(explicit)
    env = os.environ.get(DATA_ENV)
    if env:
        return Path(env)
    return None


def data_dir(explicit: str | os.PathLike[str] | None = None) -> Path | None:
    """The data directory: ``explicit``, else ``$PROBMAP_DATA``, else ``../shared/data``
    (relative to the working directory) when that folder exists, else None."""
    given = given_data_dir(explicit)
    if given is not None:
        return given
    return DEFAULT_DATA if DEFAULT_DATA.is_dir() else None


def guess_format(path: str | os.PathLike[str]) -> str:
    """Guess a dataset's format from its path (folder contents or file suffix).

    Raises
    ------
    DatasetError
        When the path does not exist or matches no known format.
    """
    p = Path(path)
    if not p.exists():
        raise DatasetError("no such file or directory", path=p)
    if p.is_dir():
        if (p / "Barcodes.dat").exists():
            return "mrclam"
        if (p / "measurements.dat").exists() and (
            (p / "inputs.dat").exists() or (p / "aa3_dr.mat").exists()
        ):
            return "victoria-park"
        raise DatasetError(
            "cannot guess the dataset format of this folder (expected MRCLAM files with "
            "Barcodes.dat, or Victoria Park measurements.dat + inputs.dat)",
            path=p,
        )
    name = p.name.lower()
    for comp in (".gz", ".bz2"):
        if name.endswith(comp):
            name = name[: -len(comp)]
    if name.endswith(".g2o"):
        return "g2o"
    if name.endswith(".bag"):
        return "rosbag"
    if name.endswith((".clf", ".log", ".carmen")):
        return "carmen"
    raise DatasetError("cannot guess the dataset format from the file name", path=p)


def resolve(name_or_path: str, data_directory: str | os.PathLike[str] | None = None) -> Path:
    """Path of a registered dataset (under the data directory) or the given path itself."""
    info = DATASETS.get(name_or_path)
    if info is None:
        return Path(name_or_path)
    if info.relpath is None:
        raise ValueError(f"dataset {info.name!r} is generated and has no path")
    root = data_dir(data_directory)
    if root is None:
        raise DatasetError(
            f"dataset {info.name!r} needs a data directory: pass --data-dir, set {DATA_ENV} "
            f"or put the data in {DEFAULT_DATA}"
        )
    path = root / info.relpath
    if not path.exists():
        raise DatasetError(f"dataset {info.name!r} not found under the data directory", path=path)
    return path


def resolve_input(
    name_or_path: str | os.PathLike[str],
    data_directory: str | os.PathLike[str] | None = None,
    *,
    kind: str | None = None,
) -> Path:
    """What a command's input argument names: the path itself when it exists, else the file
    of the registered dataset of that name (of ``kind``, when given) under the data directory.

    Raises
    ------
    FileNotFoundError
        Neither an existing path nor a registered name; the one-line message lists the
        registered names close to it.
    DatasetError
        A registered name of another kind, one without a file, or one whose file is absent.
    """
    path = Path(name_or_path)
    if path.exists():
        return path
    text = str(name_or_path)
    names = [n for n, i in DATASETS.items() if kind is None or i.kind == kind]
    info = DATASETS.get(text)
    if info is not None and (kind is None or info.kind == kind):
        return resolve(text, data_directory)
    if info is not None:
        raise DatasetError(
            f"dataset {text!r} holds {info.kind}, not {kind} data ({kind} datasets: "
            f"{', '.join(names)})"
        )
    close = difflib.get_close_matches(text, names, n=3, cutoff=0.6)
    if close:
        hint = f" or dataset name (close dataset names: {', '.join(close)})"
    elif os.sep not in text and "/" not in text and not path.suffix:
        hint = f" or dataset name ({kind + ' ' if kind else ''}datasets: {', '.join(names)})"
    else:
        hint = ""
    raise FileNotFoundError(f"{text}: no such file{hint}")


def load(
    name_or_path: str,
    *,
    data_directory: str | os.PathLike[str] | None = None,
    **options: Any,
) -> Any:
    """Open a dataset by registered name or by path (format guessed).

    Parameters
    ----------
    name_or_path : str
        A key of :data:`DATASETS` or a file/folder path.
    data_directory : path-like, optional
        Root of the data (default ``$PROBMAP_DATA``).
    **options
        Passed to the reader (e.g. ``robot=2`` for MRCLAM, ``end_time=300`` for a prefix).
    """
    info = DATASETS.get(name_or_path)
    if info is not None:
        opts = {**info.options, **options}
        if info.relpath is None:
            return FORMATS[info.format](None, **opts)
        return FORMATS[info.format](resolve(name_or_path, data_directory), **opts)
    path = Path(name_or_path)
    return FORMATS[guess_format(path)](path, **options)
