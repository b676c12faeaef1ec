"""Download the public datasets from their public addresses, checked against sha256 hashes.

Every file probmap's tests and benchmarks use is public data published by others in public
GitHub repositories (``../shared/data/README.md`` gives each file's source repository, path and
commit, its authors and terms). :data:`FILES` is the registry: for each file its place under the
data directory (the same layout as ``shared/data``, so that :func:`probmap.datasets.registry.load`
finds a fetched dataset by name), the repository, commit and path it comes from, and the sha256
of its bytes (computed from the copies in ``shared/data``). :data:`DATASETS` groups the files
under the names ``probmap datasets fetch`` takes.

:func:`fetch` downloads with `pooch <https://www.fatiando.org/pooch>`_: a file already present
with the right hash is not downloaded again; a download is written to a temporary file beside
its target and moved into place only when its hash matches, so a wrong hash leaves no file and
raises a one-line :class:`~probmap.errors.DatasetError` naming the file and both hashes.

Where the files come from can be overridden, for a mirror or a test server: ``base_url=`` (or
the environment variable ``PROBMAP_DATA_URL``) fetches every file from ``BASE/<place under the
data directory>`` instead of its GitHub address (``BASE`` laid out like ``shared/data``; the
hashes are checked all the same).

Examples
--------
>>> [f.path for f in files_of("gtsam-examples")]
['pose-graphs/w100.graph', 'pose-graphs/pose2example.txt', 'pose-graphs/noisyToyGraph.txt']
>>> file_url(FILES["pose-graphs/w100.graph"], base_url="http://127.0.0.1:8000/data/")
'http://127.0.0.1:8000/data/pose-graphs/w100.graph'
"""

from __future__ import annotations

import hashlib
import logging
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# DATA_ENV stays a name of this module (fetch.DATA_ENV): registry's, the one definition.
from probmap.datasets.registry import DATA_ENV as DATA_ENV
from probmap.datasets.registry import given_data_dir
from probmap.errors import DatasetError

__all__ = [
    "DATASETS",
    "DATA_URL_ENV",
    "FILES",
    "FetchedFile",
    "RemoteDataset",
    "RemoteFile",
    "default_directory",
    "fetch",
    "file_url",
    "files_of",
    "sha256_of",
]

DATA_URL_ENV = "PROBMAP_DATA_URL"
"""Environment variable: a base URL to fetch every file from instead of its public address."""

ProgressCallback = Callable[[str, int, int], None]
"""``progress(path, done_bytes, total_bytes)``; ``total_bytes`` is 0 when the server sent none."""


@dataclass(frozen=True)
class RemoteFile:
    """One file of the registry.

    Attributes
    ----------
    path : str
        Place under the data directory (``/``-separated, as in ``shared/data``).
    repo : str
        The GitHub repository it comes from, ``owner/name``.
    commit : str
        The commit the address is pinned to.
    source_path : str
        Its path in that repository.
    sha256 : str
        Hash of the file as stored (after ``strip_cr``).
    strip_cr : bool
        The repository stores the file with CRLF line ends; every ``\\r`` byte is removed after
        the download, which restores the dataset's published bytes (see the MRCLAM section of
        ``shared/data/README.md``), and the hash is that of the result.
    """

    path: str
    repo: str
    commit: str
    source_path: str
    sha256: str
    strip_cr: bool = False

    @property
    def url(self) -> str:
        """GitHub's raw-file address of the file, pinned to the commit."""
        return f"https://github.com/{self.repo}/raw/{self.commit}/{self.source_path}"


@dataclass(frozen=True)
class RemoteDataset:
    """A name ``fetch`` takes and the files it downloads."""

    name: str
    description: str
    files: tuple[str, ...]


@dataclass(frozen=True)
class FetchedFile:
    """A file :func:`fetch` made present: where it is, where it came from, whether it had to be
    downloaded (False: it was there already with the right hash)."""

    path: Path
    url: str
    downloaded: bool
    size: int


# ------------------------------------------------------------------------------ the registry
_MOLA = ("MOLAorg/mola_test_datasets", "13a2ed141116bc654e14ffca1d88fb740b3d1253")
_XIAOFENG = ("xiaofeng419/SLAM-2D-LIDAR-SCAN", "d469252f5b33e574bd239ad2625779497ac1d4cc")
_PLE = ("acschaefer/ple", "cfcb5a7f12a793b616357381a688cfcc26eed347")
_RICO = ("INESCTEC/ricoslam", "52bfaa91c8e5e56f119265d409b1692ca29d48d2")
_CHAMELEON = ("fernando10/Chameleon", "ef0bf6fc00bd14759e0a866e07ec965c470803b7")
_CHAMELEON_G2O = ("fernando10/Chameleon", "8a2c3ee14d43afe2cd4d88fa8cdcb9a8130151a3")
_RFS = ("kykleung/RFS-SLAM", "aa5170be675391642c7ecfe6c7a3d39d218e674d")
_MRCLAM = ("raisul-kibria/localization_and_mapping", "41559172f4e926a4bbe813ec6d984001b9acc2e6")
_CARTO = ("cartographer-project/cartographer_ros", "189835d0fd037d3e80117d31957eccbc4b35b25e")
# the pose graphs: shared/data/README.md names these commits by their first 8 hex digits
_DPGO = ("MurpheyLab/DPGO", "da0157f0")
_APEX = ("amin-abouee/apex-solver", "33f5e627")
_SESYNC = ("david-m-rosen/SE-Sync", "9b631b6b")
_SUBMAP = ("israni/Submapping--Graph-SLAM", "56190e91")
_NANO = ("gisbi-kim/nano-pgo", "b85562f0")
_GTSAM = ("borglab/gtsam", "0ffe6c93")

_MR7 = "utias-mrclam/MRCLAM_Dataset7"
_TABLE: tuple[tuple[str, tuple[str, str], str, str], ...] = (
    # (place under the data directory, (repository, commit), path there, sha256)
    ("intel-research-lab/intel.clf.bz2", _MOLA, "datasets/radish/intel.clf.bz2",
     "d9ce4addefc9405d5e78fd883d2214766552537d262009f8e6f0137885f9f72a"),
    ("intel-research-lab/intel.relations", _XIAOFENG, "DataSet/RawData/intel.relations",
     "330378f153eeae652d6756c1746f335801f66c3e097d90611548e6c4f593c359"),
    ("intel-research-lab/intel-corrected.log.gz", _PLE, "data/carmen/intel-corrected.log.gz",
     "71bef16e9926506cf7417995ef35ace09dbd5de067fd042a3aab85188b5480dc"),
    ("intel-research-lab/intel.orig.bag", _RICO,
     "inesctec_mrdt_slam_2d_datasets/bag/intel.orig.bag",
     "b37cdd3988b49893edb7afe353d55739327a6e68196f257e62e7fb287860fb5d"),
    ("freiburg-campus/freiburg-campus-corrected.log.gz", _PLE,
     "data/carmen/freiburg-campus-corrected.log.gz",
     "534fae978c3a28fd9994c9b3327a36a2752df8339e232b9b70f96f67f76341b0"),
    ("freiburg-clinic/fr-clinic_robotlaser.clf.bz2", _MOLA,
     "datasets/radish/fr-clinic_robotlaser.clf.bz2",
     "f1123753be7308178547d487df96dfc230669a55c21253c3225c7627b124d6d8"),
    ("freiburg-clinic/fr-clinic.relations", _RICO,
     "inesctec_mrdt_slam_2d_datasets/data/fr-clinic.relations",
     "583b7bba8c1a3ef1f7ad41221c151534333e71b52f5fc267d5e343c79355300c"),
    ("mit-killian/mit-killian.relations", _XIAOFENG, "DataSet/RawData/mit-killian.relations",
     "0b0f8dfc0746f9dee20b9d6d2a47a805674fd2f5be94f0ba11876bc6e97fab4b"),
    ("victoria-park/aa3_dr.mat", _CHAMELEON, "data/victoria_park/aa3_dr.mat",
     "6ce2c4f757023b7d275cc14f24ff2ffcca21ea68cfa360bc854e620a706eb358"),
    ("victoria-park/aa3_gpsx.mat", _CHAMELEON, "data/victoria_park/aa3_gpsx.mat",
     "521fc4c6e0ea3851ffb463c3d9c0578044e9178c4fb87f37c703bb587f38c755"),
    ("victoria-park/measurements.dat", _RFS, "data/VictoriaPark/measurements.dat",
     "b0737e2d312cbb80d466a8f1d6048e11dd06939a5ffb63becc8b954cde149746"),
    ("victoria-park/inputs.dat", _RFS, "data/VictoriaPark/inputs.dat",
     "94353fa7a529f8a9e9770e69363d27472fe414f3637a107dce54a7f8db96e7d8"),
    ("victoria-park/gps.dat", _RFS, "data/VictoriaPark/gps.dat",
     "944657cdaacdb9c421bf3a7ec1af95f05a8b9fefb513374f1f617bacc5426c07"),
    ("victoria-park/victoriaPark-full.g2o", _CHAMELEON_G2O,
     "data/victoria_park/g2o/victoriaPark-full.g2o",
     "065e321b3f70ed6bbc1a50f10d218a17f0342b7c3e17f93e794a1541f6851209"),
    (f"{_MR7}/Barcodes.dat", _MRCLAM, "data/MRCLAM_Dataset7/Barcodes.dat",
     "3448dfa8fdf7c6e52c4d778c9e3166a704fc1b3f388e5f274532ff1af3b37362"),
    (f"{_MR7}/Landmark_Groundtruth.dat", _MRCLAM, "data/MRCLAM_Dataset7/Landmark_Groundtruth.dat",
     "3ced51810a265804d0785306f9cae4b3da0075db1b0d341395881b0e14af8bd2"),
    (f"{_MR7}/Robot1_Groundtruth.dat", _MRCLAM, "data/MRCLAM_Dataset7/Robot1_Groundtruth.dat",
     "d2b3594d9aaab6afb00fde6f3525fa0210969ab5dc04b568b998bac9ce1149c0"),
    (f"{_MR7}/Robot1_Measurement.dat", _MRCLAM, "data/MRCLAM_Dataset7/Robot1_Measurement.dat",
     "d4308f262fd0fe6b6ac6acc7f174880d849966146fd681c2569da5f25248f1bc"),
    (f"{_MR7}/Robot1_Odometry.dat", _MRCLAM, "data/MRCLAM_Dataset7/Robot1_Odometry.dat",
     "1ceab23977b9125336d672c35a87323a5c3c849ac2e5cbd0281b1a258fb3427e"),
    (f"{_MR7}/Robot2_Groundtruth.dat", _MRCLAM, "data/MRCLAM_Dataset7/Robot2_Groundtruth.dat",
     "78343b671c686b36975a7cb1bba96030fa05265f147904754130a665b3ea7f2e"),
    (f"{_MR7}/Robot2_Measurement.dat", _MRCLAM, "data/MRCLAM_Dataset7/Robot2_Measurement.dat",
     "f2344ea30ff7df50e7493dae985ec1c9df8f0f74d98a258332aa072f8083b534"),
    (f"{_MR7}/Robot2_Odometry.dat", _MRCLAM, "data/MRCLAM_Dataset7/Robot2_Odometry.dat",
     "a38d562ff79e081c5071facea52ee39ee09f3c308e630e61b2fe8b8ed3ecbd73"),
    (f"{_MR7}/Robot3_Groundtruth.dat", _MRCLAM, "data/MRCLAM_Dataset7/Robot3_Groundtruth.dat",
     "277e076cda04ca117eed1b7977e7366a878b0764a302e27c324cd2fd68e9889f"),
    (f"{_MR7}/Robot3_Measurement.dat", _MRCLAM, "data/MRCLAM_Dataset7/Robot3_Measurement.dat",
     "aaffb457a1c47f7a7e25ad475f64c892e303db5295292c79a1021df29c1f7cb9"),
    (f"{_MR7}/Robot3_Odometry.dat", _MRCLAM, "data/MRCLAM_Dataset7/Robot3_Odometry.dat",
     "f6a74a334a7b6d94bea7ab0fdcf88f6bee5580c05801584eb20b93e14985f198"),
    ("ros-bags/b0-2014-07-21-12-42-53-short.bag", _CARTO,
     "cartographer_ros/tests/data/b0-2014-07-21-12-42-53-short.bag",
     "816081b949ccbfcef510e420d5172b26ed06e54019f671077822aa41db98a93b"),
    ("pose-graphs/M3500.g2o", _DPGO, "dataset/M3500.g2o",
     "1883593980e602b11bd0ba95799c969e59ee8a6892bdb2a3a48f495459efe9d8"),
    ("pose-graphs/MITb.g2o", _DPGO, "dataset/MITb.g2o",
     "e5922be0d0689c7a5bc04c58adf3a8e697e240bdd7691cc4218470eaf92956eb"),
    ("pose-graphs/M3500a.g2o", _APEX, "data/M3500a.g2o",
     "34deb00c3ff7206048d805c612c545cd8764ac3a7fd933a4ee2d3419fc3a0b8f"),
    ("pose-graphs/M3500b.g2o", _APEX, "data/M3500b.g2o",
     "55342238a0d45d724ce590202f4c3ad3004e02c3d770e029677030b50a632f48"),
    ("pose-graphs/manhattanOlson3500.g2o", _APEX, "data/manhattanOlson3500.g2o",
     "84d6ac6faffe2f120bd8df6f80185db0fafacdd9c0eedfa118ae475e035f9f40"),
    ("pose-graphs/ring.g2o", _APEX, "data/ring.g2o",
     "786a004adc98e7a530d3ba3c11200f7d8ba6cad6ca59929d64e1cbbf164d49aa"),
    ("pose-graphs/ringCity.g2o", _APEX, "data/ringCity.g2o",
     "059b6def507e46b86c236b18cae00f3308063258c378feca42540b703a218ebd"),
    ("pose-graphs/intel.g2o", _SESYNC, "data/intel.g2o",
     "3e0724c048e0ba524be9dd268a8b78e19a2497043143584cbb61310638b15c4b"),
    ("pose-graphs/city10000.g2o", _SESYNC, "data/city10000.g2o",
     "df5988994339e990be198a36e7f640e31a5a1b26df3ed400363fafc49d5ca630"),
    ("pose-graphs/kitti_00.g2o", _SESYNC, "data/kitti_00.g2o",
     "8a9807f604852a44254910100917918def94d7357748c633e1fd7ce73dd17468"),
    ("pose-graphs/INTEL_P_toro.graph", _SUBMAP, "Datasets/INTEL_P_toro.graph",
     "c715e7b5c9035080582e67bbaa1f9aca6b2bf7f166046333be0218c9923fa37c"),
    ("pose-graphs/CSAIL_P_toro.graph", _NANO, "data/CSAIL_P_toro.graph",
     "fcf4de76b262e7f58ea64b8c5db806fec926a519d2f5d85fcc9c553f8f82fa98"),
    ("pose-graphs/FR079_P_toro.graph", _NANO, "data/FR079_P_toro.graph",
     "ba53624ae4ed843258359c8e5713e7456943b6daf2e4a17b800a90e170d7e659"),
    ("pose-graphs/FRH_P_toro.graph", _NANO, "data/FRH_P_toro.graph",
     "56868ab910e876e358ab74478c55f48aa6275bd133739f927510e442b3a523ee"),
    ("pose-graphs/w100.graph", _GTSAM, "examples/Data/w100.graph",
     "00e68e8ba3985213814862f53a533916a005c2b40d374d840f6d069d91abaa06"),
    ("pose-graphs/pose2example.txt", _GTSAM, "examples/Data/pose2example.txt",
     "578f33a41273d7e7be0bd542e9a6bc8963bbb86c33891f4851d07b633035ec8f"),
    ("pose-graphs/noisyToyGraph.txt", _GTSAM, "examples/Data/noisyToyGraph.txt",
     "9b2d2930cf50b2b2c756172f50c34503c41644e529727bd7a4960f6e785ff859"),
    # shared/data took w10000.graph from the gtsam 4.3.0 wheel, "the same git blob as
    # borglab/gtsam examples/Data/w10000.graph" without naming a commit: pinned here to the
    # commit of the other gtsam example files (the hash decides).
    ("pose-graphs/w10000.graph", _GTSAM, "examples/Data/w10000.graph",
     "1e88f220bd580a4c2b9fc065358608a53b26b1c30033405990b4cdc83236fc89"),
)  # fmt: skip

FILES: dict[str, RemoteFile] = {
    path: RemoteFile(path, repo, commit, source, sha, strip_cr=(repo, commit) == _MRCLAM)
    for path, (repo, commit), source, sha in _TABLE
}
"""Every downloadable file by its place under the data directory."""


def _dataset(name: str, description: str, *files: str) -> RemoteDataset:
    return RemoteDataset(name, description, tuple(files))


_MR7_FILES = [f"{_MR7}/Barcodes.dat", f"{_MR7}/Landmark_Groundtruth.dat"] + [
    f"{_MR7}/Robot{r}_{kind}.dat"
    for r in (1, 2, 3)
    for kind in ("Groundtruth", "Measurement", "Odometry")
]

# Not registry.DATASETS (what a command reads, with its format): this table is what `datasets
# fetch` downloads (relations, graph collections and "all" too; no generated data).
DATASETS: dict[str, RemoteDataset] = {
    d.name: d
    for d in (
        _dataset(
            "intel",
            "Intel Research Lab: raw CARMEN log and the Freiburg relations",
            "intel-research-lab/intel.clf.bz2",
            "intel-research-lab/intel.relations",
        ),
        _dataset(
            "intel-corrected",
            "Intel Research Lab, GMapping-corrected poses (910 scans)",
            "intel-research-lab/intel-corrected.log.gz",
        ),
        _dataset(
            "intel-bag",
            "the raw Intel log as a ROS 1 bag (/scan, /odom, /tf)",
            "intel-research-lab/intel.orig.bag",
        ),
        _dataset(
            "freiburg-campus-corrected",
            "Freiburg campus, GMapping-corrected poses",
            "freiburg-campus/freiburg-campus-corrected.log.gz",
        ),
        _dataset(
            "freiburg-clinic",
            "Freiburg university hospital: raw ROBOTLASER1 log and its local relations",
            "freiburg-clinic/fr-clinic_robotlaser.clf.bz2",
            "freiburg-clinic/fr-clinic.relations",
        ),
        _dataset(
            "mit-killian-relations",
            "MIT Killian Court relations (the log is not in the registry)",
            "mit-killian/mit-killian.relations",
        ),
        _dataset(
            "victoria-park",
            "Victoria Park: dead reckoning, GPS and tree detections",
            "victoria-park/aa3_dr.mat",
            "victoria-park/aa3_gpsx.mat",
            "victoria-park/measurements.dat",
            "victoria-park/inputs.dat",
            "victoria-park/gps.dat",
        ),
        _dataset(
            "victoria-park-g2o",
            "Victoria Park as a g2o pose-landmark graph",
            "victoria-park/victoriaPark-full.g2o",
        ),
        _dataset(
            "mrclam7",
            "UTIAS MRCLAM Dataset 7, robots 1-3 with Vicon truth",
            *_MR7_FILES,
        ),
        _dataset(
            "deutsches-museum-bag",
            "Cartographer's Deutsches Museum backpack, 10 s ROS 1 bag (multi-echo scans, IMU)",
            "ros-bags/b0-2014-07-21-12-42-53-short.bag",
        ),
        _dataset(
            "pose-graphs",
            "18 standard 2-D pose graphs (g2o and TORO)",
            *(p for p in FILES if p.startswith("pose-graphs/")),
        ),
        _dataset(
            "gtsam-examples",
            "GTSAM's small example pose graphs (w100, pose2example, noisyToyGraph)",
            "pose-graphs/w100.graph",
            "pose-graphs/pose2example.txt",
            "pose-graphs/noisyToyGraph.txt",
        ),
        _dataset("all", "every file of the registry", *FILES),
    )
}
"""The names :func:`fetch` takes (a file's place under the data directory works too)."""


# ------------------------------------------------------------------------------ lookups
def files_of(name: str) -> list[RemoteFile]:
    """The files of a dataset name, or the one file whose place under the data directory is
    ``name``.

    Raises
    ------
    ValueError
        For an unknown name; the one-line message lists the known names.
    """
    if name in DATASETS:
        return [FILES[p] for p in DATASETS[name].files]
    key = name.replace(os.sep, "/").strip("/")
    if key in FILES:
        return [FILES[key]]
    raise ValueError(
        f"unknown dataset {name!r}: known names are {', '.join(DATASETS)} "
        "(or one file of the registry, e.g. pose-graphs/M3500.g2o)"
    )


def default_directory(explicit: str | os.PathLike[str] | None = None) -> Path:
    """Where :func:`fetch` puts files: ``explicit``, else ``$PROBMAP_DATA``, else the user
    cache folder ``pooch.os_cache("probmap")`` (``~/.cache/probmap`` on Linux)."""
    given = given_data_dir(explicit)
    if given is not None:
        return given
    import pooch

    return Path(pooch.os_cache("probmap"))


def file_url(entry: RemoteFile, base_url: str | None = None) -> str:
    """The address ``entry`` is downloaded from: ``BASE/<entry.path>`` with a base URL (the
    argument, else ``$PROBMAP_DATA_URL``), else its public GitHub address."""
    base = base_url if base_url is not None else os.environ.get(DATA_URL_ENV) or None
    if base:
        return f"{base.rstrip('/')}/{entry.path}"
    return entry.url


def sha256_of(path: str | os.PathLike[str]) -> str:
    """The sha256 of a file's bytes, in hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


# ------------------------------------------------------------------------------ downloading
class _Bar:
    """The progress-bar object pooch's HTTP downloader drives, reporting to a callback."""

    def __init__(self, path: str, callback: ProgressCallback) -> None:
        self.path = path
        self.callback = callback
        self.total = 0
        self.done = 0

    def update(self, n: int) -> None:
        self.done += n
        self.callback(self.path, min(self.done, self.total) if self.total else self.done,
                      self.total)  # fmt: skip

    def reset(self) -> None:
        self.done = 0

    def close(self) -> None:
        pass


class _Downloader:
    """Download one file with pooch's HTTP downloader, strip CRs where the registry says so and
    check the hash, so that a mismatch is one line that names the file and both hashes (pooch
    then removes its temporary file)."""

    def __init__(self, entry: RemoteFile, target: Path, progress: ProgressCallback | None):
        self.entry = entry
        self.target = target
        self.progress = progress

    def __call__(self, url: str, output_file: str, store: Any) -> None:
        import pooch
        import requests

        bar = _Bar(self.entry.path, self.progress) if self.progress is not None else False
        http = pooch.HTTPDownloader(progressbar=bar, chunk_size=1 << 16, timeout=60)
        try:
            http(url, output_file, store)
        except requests.RequestException as exc:
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise ConnectionError(f"cannot download {url}: {reason}") from None
        if self.entry.strip_cr:
            data = Path(output_file).read_bytes()
            Path(output_file).write_bytes(data.replace(b"\r", b""))
        actual = sha256_of(output_file)
        if actual != self.entry.sha256:
            raise DatasetError(
                f"sha256 mismatch: expected {self.entry.sha256}, got {actual} "
                f"(downloaded from {url}; nothing was written)",
                path=self.target,
            )
        # pooch downloads into a private temporary file (mode 0600): give the data the mode
        # of every other output, 0666 less the umask (os.umask both reads and sets it)
        mask = os.umask(0o022)
        os.umask(mask)
        os.chmod(output_file, 0o666 & ~mask)


@contextmanager
def _quiet_pooch() -> Iterator[None]:
    """pooch logs every download on stderr; a library prints nothing, so hold its log back."""
    import pooch

    logger = pooch.get_logger()
    level = logger.level
    logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        logger.setLevel(level)


def _missing_folders(folder: Path) -> list[Path]:
    """``folder`` and its parents that do not exist yet, deepest first."""
    missing = []
    p = folder
    while not p.exists() and p.parent != p:
        missing.append(p)
        p = p.parent
    return missing


def fetch(
    name: str,
    directory: str | os.PathLike[str] | None = None,
    *,
    base_url: str | None = None,
    progress: ProgressCallback | None = None,
) -> list[FetchedFile]:
    """Make the files of a dataset present under ``directory``, downloading what is missing.

    Parameters
    ----------
    name : str
        A key of :data:`DATASETS` (``"intel"``, ``"mrclam7"``, ``"all"`` ...) or one file's
        place under the data directory (``"pose-graphs/M3500.g2o"``).
    directory : path-like, optional
        The data directory (default :func:`default_directory`: ``$PROBMAP_DATA``, else the
        user cache). Files go to ``directory/<place>``, the layout
        :func:`probmap.datasets.registry.load` reads by name.
    base_url : str, optional
        Fetch every file from ``base_url/<place>`` instead of its public address (default
        ``$PROBMAP_DATA_URL``; a mirror, or a local test server).
    progress : callable, optional
        ``progress(place, done_bytes, total_bytes)`` while a file downloads.

    Returns
    -------
    list of FetchedFile
        One per file, in the registry's order; ``downloaded`` is False for a file that was
        present with the right hash (it is neither downloaded nor rewritten).

    Raises
    ------
    ValueError
        For an unknown name (the message lists the known ones).
    DatasetError
        When a download's sha256 differs from the registry's: names the file, the expected and
        the actual hash; the file is not written (a file already there is left as it was).
    ConnectionError
        When a file cannot be downloaded (no network, an HTTP error); names the address.
    """
    import pooch

    entries = files_of(name)
    root = default_directory(directory)
    store = pooch.create(
        path=root,
        base_url="",
        registry={e.path: f"sha256:{e.sha256}" for e in entries},
        urls={e.path: file_url(e, base_url) for e in entries},
        retry_if_failed=0,
    )
    results = []
    with _quiet_pooch():
        for entry in entries:
            target = Path(store.abspath) / entry.path
            created = _missing_folders(target.parent)
            actions: list[str] = []

            def record(fname: str, action: str, _store: Any, actions: list[str] = actions) -> str:
                actions.append(action)
                return fname

            try:
                store.fetch(
                    entry.path, processor=record,
                    downloader=_Downloader(entry, target, progress),
                )  # fmt: skip
            except BaseException:
                for folder in created:  # deepest first; only folders left empty
                    with suppress(OSError):
                        folder.rmdir()
                raise
            results.append(
                FetchedFile(
                    path=target,
                    url=store.get_url(entry.path),
                    downloaded=bool(actions) and actions[0] != "fetch",
                    size=target.stat().st_size,
                )
            )
    return results
