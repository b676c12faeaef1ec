"""One output rule for every command that writes files (issue 20): all outputs or none.

For every command (``map``, ``map --method map``, ``map --to-bag``, ``slam grid`` graph and rbpf,
``slam ekf``, ``slam seif``, ``localize``, ``semantic``, ``fit-sensor-model``, ``demo`` and its
``--localize`` / ``--semantic`` variants, ``optimize``, ``evaluate relations``) on small inputs
made here:

- a missing output folder (and its missing parents) is created; files are 0644 and new folders
  0755 under umask 022;
- ``-o`` naming an existing folder, or a name ending in ``/``, writes ``FOLDER/<default name>.*``;
- a writer failing mid-run (disk full), Ctrl-C while writing, or an output path taken by a
  folder leaves no output file, no temporary file and no folder the command created; the exit
  code is 1 and the message is one line naming the path, without a traceback;
- an output path under a regular file, or in a folder that is not writable, is refused before
  any work.

``match`` and ``slam compare`` write no files and are not in the matrix.
"""

from __future__ import annotations

import errno
import importlib.util
import os
import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app

register(app)
runner = CliRunner()

TESTS = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------ small inputs
def _room(n_scans: int = 20, n_beams: int = 90):
    """A 6 x 4 m box room scanned from a short line of poses (true poses = odometry)."""
    from probmap.grid.raycast import cast_rays
    from probmap.grid.spec import GridSpec

    spec = GridSpec(0.05, (-1.0, -1.0), (100, 140))
    occ = np.zeros(spec.shape, bool)
    occ[:4, :] = occ[-4:, :] = occ[:, :4] = occ[:, -4:] = True
    angles = -np.pi / 2 + np.arange(n_beams) * np.pi / n_beams
    rng = np.random.default_rng(0)
    poses = np.array([(0.5 + 0.15 * k, 1.5, 0.2 * k) for k in range(n_scans)])
    ranges = np.stack([cast_rays(occ, spec, p, angles, 20.0) for p in poses])
    ranges = np.minimum(ranges + rng.normal(0, 0.01, ranges.shape), 20.0)
    return poses, ranges, angles


def _carmen_log(path: Path) -> Path:
    poses, ranges, angles = _room()
    lines = ["PARAM robot_front_laser_max 20.0\n"]
    for k, ((x, y, th), r) in enumerate(zip(poses, ranges, strict=True)):
        txt = " ".join(f"{v:.3f}" for v in r)
        t = 100.0 + 0.5 * k
        lines.append(
            f"FLASER {len(r)} {txt} {x:.4f} {y:.4f} {th:.5f} {x:.4f} {y:.4f} {th:.5f} "
            f"{t:.6f} host {t:.6f}\n"
        )
    path.write_text("".join(lines))
    return path


def _bag(path: Path) -> Path:
    """The room as a ROS 1 bag (the bag writer of tests/datasets/test_rosbag.py)."""
    pytest.importorskip("rosbags")
    spec = importlib.util.spec_from_file_location(
        "_probmap_test_rosbag", TESTS / "datasets" / "test_rosbag.py"
    )
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    poses, ranges, angles = _room()

    @dataclass
    class World:
        poses: np.ndarray
        ranges: np.ndarray
        angles: np.ndarray
        times: np.ndarray
        max_range: float

    world = World(poses, ranges, angles, 0.5 * np.arange(len(poses)), 20.0)
    return mod.write_sim_bag(path, world, ros=1, source="odom")


def _labelled_scans(path: Path) -> Path:
    from probmap.grid.semantic_io import LabelledScans, write_labelled_scans

    poses, ranges, angles = _room()
    labels = np.where(ranges < 20.0, 1, 0).astype(np.int64)
    scans = LabelledScans(poses, ranges, angles, 20.0, ("free", "wall"), labels=labels)
    return write_labelled_scans(path, scans)


def _graph(path: Path) -> Path:
    info = "100 0 0 100 0 100"
    path.write_text(
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1.1 0 0\nVERTEX_SE2 2 2.0 0.1 0\n"
        f"EDGE_SE2 0 1 1 0 0 {info}\nEDGE_SE2 1 2 1 0 0 {info}\nEDGE_SE2 0 2 2 0 0 {info}\n"
    )
    return path


def _trajectory_and_relations(folder: Path) -> tuple[Path, Path]:
    traj = folder / "traj.csv"
    rows = [f"{t:.1f},{0.5 * t:.3f},0,0" for t in range(10)]
    traj.write_text("time,x,y,theta\n" + "\n".join(rows) + "\n")
    rel = folder / "rel.relations"
    rel.write_text("".join(f"{t}.0 {t + 1}.0 0.5 0 0 0 0 0\n" for t in range(9)))
    return traj, rel


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("inputs")
    log = _carmen_log(d / "room.clf")
    res = runner.invoke(app, ["map", str(log), "-o", str(d / "room"), "-r", "0.1"])
    assert res.exit_code == 0, res.output
    traj, rel = _trajectory_and_relations(d)
    return {
        "log": log,
        "map": d / "room.yaml",
        "scans": _labelled_scans(d / "scans.npz"),
        "graph": _graph(d / "graph.g2o"),
        "traj": traj,
        "relations": rel,
        "bag": _bag(d / "room.bag"),
    }


# ------------------------------------------------------------------------------ the commands
MAP = (".yaml", ".pgm", ".npz", ".png")
MAPPED = (*MAP, ".plot.png")  # what write_map writes: the map files and the picture
MAP_CMD = (*MAPPED, ".config.yaml")  # probmap map also records its configuration


@dataclass(frozen=True)
class Command:
    """One command of the matrix.

    ``argv(inputs, out, folder)`` gives the arguments for the output argument ``out`` (a prefix,
    a file or a folder); ``folder`` is where the files are expected (for ``--to-bag``).
    ``prefix``: the command takes an output prefix or file (``default`` is its name inside a
    folder); otherwise ``-o`` is a folder and ``files`` are the names inside it.
    """

    name: str
    argv: Callable[[dict[str, Path], str, Path], list[str]]
    files: tuple[str, ...]
    prefix: bool = True
    default: str = ""
    explicit: str = "run"  # the prefix or file name used when the test names one
    extra: tuple[str, ...] = ()  # files beside the prefix's (--to-bag)

    def outputs(self, folder: Path, name: str | None = None) -> list[Path]:
        if not self.prefix:
            return [folder / f for f in self.files]
        stem = name or self.default
        return [folder / f"{stem}{s}" for s in self.files] + [folder / e for e in self.extra]


def _to_bag(i: dict[str, Path], out: str, folder: Path) -> list[str]:
    return ["map", str(i["bag"]), "-o", out, "-r", "0.1", "--to-bag", str(folder / "grid.bag")]


COMMANDS = [
    Command(
        "map", lambda i, o, f: ["map", str(i["log"]), "-o", o, "-r", "0.1"], MAP_CMD, default="map"
    ),
    Command(
        "map --method map",
        lambda i, o, f: ["map", str(i["log"]), "-o", o, "-r", "0.2", "--method", "map"],
        MAP_CMD,
        default="map",
    ),
    Command("map --to-bag", _to_bag, MAP_CMD, default="map", extra=("grid.bag",)),
    Command(
        "slam grid",
        lambda i, o, f: ["slam", "grid", str(i["log"]), "-o", o],
        (*MAP, ".trajectory.csv", ".g2o", ".plot.png", ".report.json", ".config.yaml"),
        default="slam",
    ),
    Command(
        "slam grid --method rbpf",
        lambda i, o, f: ["slam", "grid", str(i["log"]), "-o", o, "--method", "rbpf", "-n", "5"],
        (*MAP, ".trajectory.csv", ".plot.png", ".config.yaml"),
        default="slam",
    ),
    Command(
        "semantic",
        lambda i, o, f: ["semantic", str(i["scans"]), "-o", o, "-r", "0.1"],
        (".npz", ".png", *(f".occupancy{s}" for s in MAP), ".occupancy.plot.png", ".config.yaml"),
        default="semantic",
    ),
    Command(
        "fit-sensor-model",
        lambda i, o, f: ["fit-sensor-model", str(i["log"]), "-o", o, "-r", "0.1"],
        ("",),
        default="beam_model.yaml",
        explicit="beam.yaml",
    ),
    Command(  # FILE.g2o, FILE.config.yaml and FILE.plot.png: the explicit name gets its .g2o
        "optimize",
        lambda i, o, f: [
            "optimize",
            str(i["graph"]),
            "-o",
            o + ".g2o" if o.endswith("/out") else o,
        ],
        (".g2o", ".config.yaml", ".plot.png"),
        default="optimized",
        explicit="out",
    ),
    Command(
        "evaluate relations",
        lambda i, o, f: ["evaluate", "relations", str(i["traj"]), str(i["relations"]), "-o", o],
        ("",),
        default="relations.json",
        explicit="rel.json",
    ),
    Command(
        "slam ekf",
        lambda i, o, f: ["slam", "ekf", "simulation", "-o", o],
        ("trajectory.csv", "landmarks.csv", "metrics.json", "slam.png", "config.yaml"),
        prefix=False,
    ),
    Command(
        "slam seif",
        lambda i, o, f: ["slam", "seif", "simulation", "-o", o],
        ("trajectory.csv", "landmarks.csv", "metrics.json", "slam.png", "config.yaml"),
        prefix=False,
    ),
    Command(
        "localize",
        lambda i, o, f: ["localize", str(i["map"]), str(i["log"]), "-o", o, "-n", "200"],
        ("trajectory.csv", "trajectory.png", "config.yaml"),
        prefix=False,
    ),
    Command(
        "demo",
        lambda i, o, f: ["demo", "-o", o],
        (*(f"map{s}" for s in MAPPED), "map.config.yaml"),
        prefix=False,
    ),
    Command(
        "demo --semantic",
        lambda i, o, f: ["demo", "--semantic", "-o", o],
        (
            "semantic.npz",
            "semantic.png",
            *(f"semantic.occupancy{s}" for s in MAP),
            "semantic.occupancy.plot.png",
        ),  # fmt: skip
        prefix=False,
    ),
    Command(
        "demo --localize",
        lambda i, o, f: ["demo", "--localize", "-o", o],
        ("trajectory.csv",),
        prefix=False,
    ),
]
FAST = [c for c in COMMANDS if c.name not in ("demo --localize", "slam seif")]  # slow; same writers
IDS = [c.name for c in COMMANDS]


def run(cmd: Command, inputs: dict[str, Path], out: str, folder: Path):
    return runner.invoke(app, cmd.argv(inputs, out, folder))


def _out_arg(cmd: Command, folder: Path) -> str:
    return str(folder / cmd.explicit) if cmd.prefix else str(folder)


def _leftovers(root: Path) -> list[str]:
    """Temporary files or folders of the atomic writer anywhere below ``root``."""
    return [
        str(p)
        for p in root.rglob("*")
        if p.name.startswith(".") and (p.name.endswith(".tmp") or p.name.endswith(".bak"))
    ]


def _one_line_error(res, *words: str) -> str:
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


@pytest.fixture
def umask022():
    old = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(old)


# ------------------------------------------------------------------------------ the matrix
@pytest.mark.parametrize("cmd", COMMANDS, ids=IDS)
def test_a_missing_folder_is_created_with_plain_modes(cmd, inputs, tmp_path, umask022):
    folder = tmp_path / "new" / "sub"
    res = run(cmd, inputs, _out_arg(cmd, folder), folder)
    assert res.exit_code == 0, res.output
    want = cmd.outputs(folder, cmd.explicit if cmd.prefix else None)
    assert sorted(folder.iterdir()) == sorted(want)
    assert sorted(tmp_path.iterdir()) == [tmp_path / "new"]
    for p in want:
        if p.is_file():
            assert stat.S_IMODE(p.stat().st_mode) == 0o644, p
    for d in (tmp_path / "new", folder):
        assert stat.S_IMODE(d.stat().st_mode) == 0o755, d
    assert not _leftovers(tmp_path)


@pytest.mark.parametrize("cmd", FAST, ids=[c.name for c in FAST])
def test_an_existing_folder_as_output_writes_inside_it(cmd, inputs, tmp_path):
    folder = tmp_path / "outdir"
    folder.mkdir()
    res = run(cmd, inputs, str(folder), folder)
    assert res.exit_code == 0, res.output
    assert sorted(folder.iterdir()) == sorted(cmd.outputs(folder))
    assert sorted(tmp_path.iterdir()) == [folder]  # nothing beside it (no outdir.yaml)
    if cmd.prefix:  # a name ending in "/" is a folder too, created when missing
        fresh = tmp_path / "fresh"
        res = run(cmd, inputs, str(fresh) + "/", fresh)
        assert res.exit_code == 0, res.output
        assert sorted(fresh.iterdir()) == sorted(cmd.outputs(fresh))
        assert sorted(tmp_path.iterdir()) == [fresh, folder]


def _break_writers(monkeypatch, error: BaseException) -> None:
    """Every write of a command's output to disk fails: the picture writers (matplotlib,
    Pillow) when they write to a file, and the flush to disk of every other file. Pictures
    encoded in memory first are not affected (no disk is involved)."""
    import io

    import matplotlib.figure
    from PIL import Image

    savefig, save = matplotlib.figure.Figure.savefig, Image.Image.save

    def fail_savefig(self, target, *args, **kwargs):
        if isinstance(target, io.BytesIO):
            return savefig(self, target, *args, **kwargs)
        raise error

    def fail_save(self, target, *args, **kwargs):
        if isinstance(target, io.BytesIO):
            return save(self, target, *args, **kwargs)
        raise error

    def fail(*args, **kwargs):
        raise error

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", fail_savefig)
    monkeypatch.setattr(Image.Image, "save", fail_save)
    monkeypatch.setattr(os, "fsync", fail)


@pytest.mark.parametrize("cmd", FAST, ids=[c.name for c in FAST])
def test_a_writer_failing_midway_leaves_nothing(cmd, inputs, tmp_path, monkeypatch):
    folder = tmp_path / "new" / "sub"
    _break_writers(monkeypatch, OSError(errno.ENOSPC, "No space left on device"))
    res = run(cmd, inputs, _out_arg(cmd, folder), folder)
    line = _one_line_error(res, "No space left on device", str(folder))
    assert "cannot write" in line
    assert list(tmp_path.iterdir()) == []  # no file, no temporary, not even the new folders


@pytest.mark.parametrize("cmd", FAST, ids=[c.name for c in FAST])
def test_ctrl_c_while_writing_leaves_nothing(cmd, inputs, tmp_path, monkeypatch):
    folder = tmp_path / "new"
    _break_writers(monkeypatch, KeyboardInterrupt())
    res = run(cmd, inputs, _out_arg(cmd, folder), folder)
    assert res.exit_code not in (0, None) and "Traceback" not in res.output, res.output
    assert list(tmp_path.iterdir()) == []


MANY = [c for c in FAST if c.files != ("",)]  # a single-file -o naming a folder writes inside it


@pytest.mark.parametrize("cmd", MANY, ids=[c.name for c in MANY])
def test_an_output_path_taken_by_a_folder_leaves_nothing(cmd, inputs, tmp_path):
    folder = tmp_path / "out"
    want = cmd.outputs(folder, cmd.explicit if cmd.prefix else None)
    blocker = want[-1]  # the last file written (usually the picture)
    blocker.mkdir(parents=True)
    (blocker / "keep").write_text("x")
    res = run(cmd, inputs, _out_arg(cmd, folder), folder)
    _one_line_error(res, str(blocker))
    assert sorted(folder.iterdir()) == [blocker]
    assert [p.name for p in blocker.iterdir()] == ["keep"]
    assert not _leftovers(tmp_path)


@pytest.mark.parametrize("cmd", COMMANDS, ids=IDS)
def test_an_output_path_under_a_file_is_refused_before_the_work(cmd, inputs, tmp_path, monkeypatch):
    afile = tmp_path / "afile"
    afile.write_text("")
    folder = afile / "sub"
    # the work must not start: every reader of the inputs and the simulators fail loudly
    import probmap.datasets.carmen as carmen

    def no_work(*args, **kwargs):
        raise AssertionError("the work started before the output path was checked")

    monkeypatch.setattr(carmen, "load_scans", no_work)
    res = run(cmd, inputs, _out_arg(cmd, folder), folder)
    _one_line_error(res, str(afile), "not a folder")
    assert sorted(tmp_path.iterdir()) == [afile]


@pytest.mark.parametrize("cmd", COMMANDS, ids=IDS)
def test_an_unwritable_output_folder_is_refused_before_the_work(cmd, inputs, tmp_path, monkeypatch):
    ro = tmp_path / "ro"
    ro.mkdir()
    folder = ro / "sub"
    real_access = os.access  # root ignores permission bits: the check itself is what is tested
    monkeypatch.setattr(
        os, "access", lambda p, mode, **kw: False if Path(p) == ro else real_access(p, mode, **kw)
    )
    res = run(cmd, inputs, _out_arg(cmd, folder), folder)
    _one_line_error(res, str(ro), "not writable")
    assert list(ro.iterdir()) == []
