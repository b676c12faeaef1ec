"""The README's quickstart runs as printed on the shared data: a bag -> ``slam grid`` -> a nav2
(map_server) map -> ``localize`` -> ``--tum`` -> evo.

The commands are read from the README's quickstart block, with the bag named there replaced by
the Intel bag of the shared data and the run cut short for CI time (``--end-time`` on
``slam grid``, ``--stop`` on ``localize``). Each runs as a user runs it, in a process of its own.
The oracles: every file the README names exists; the map is a map_server map that the map reader
loads with the stated thresholds; the TUM files hold the same poses as the CSVs, in the format
evo reads; the localization stays within a few centimetres of the SLAM trajectory it tracks.
``evo_ape``/``evo_rpe`` run too where evo is installed.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
BAG_IN_README = "run.bag"
DATASET = "intel-bag"
SHORT = {("slam", "grid"): ["--end-time", "60"], ("localize",): ["--stop", "300"]}


def quickstart_lines() -> list[str]:
    """The command lines of the README's quickstart block, comments stripped."""
    text = README.read_text(encoding="utf-8")
    section = text.split("## Quickstart with your own data", 1)[1].split("\n## ", 1)[0]
    m = re.search(r"```bash\n(.*?)```", section, flags=re.DOTALL)
    assert m, "no bash block under 'Quickstart with your own data'"
    lines = [line.split("#", 1)[0].strip() for line in m.group(1).splitlines()]
    return [line for line in lines if line]


def test_the_quickstart_goes_from_a_bag_to_evo():
    """The block is the path the README promises, in order."""
    lines = quickstart_lines()
    words = [line.split()[:3] for line in lines]
    order = [" ".join(w[:3] if w[:2] == ["probmap", "slam"] else w[:2]) for w in words]
    assert order == [
        "pip install",
        "probmap info",
        "probmap slam grid",
        "probmap localize",
        "evo_ape tum",
        "evo_rpe tum",
    ], order
    assert all(BAG_IN_README in line for line in lines if line.startswith("probmap"))
    assert all(
        "--tum" in line for line in lines if line.startswith(("probmap slam", "probmap loc"))
    )


def _probmap(args: list[str], cwd: Path, data: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    env["PROBMAP_DATA"] = str(data)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), env.get("PYTHONPATH", "")])
    code = "import sys; from probmap.cli.app import main; main(sys.argv[1:])"
    return subprocess.run(
        [sys.executable, "-c", code, *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


@pytest.fixture(scope="module")
def quickstart_run(tmp_path_factory):
    """Run the quickstart's probmap lines once; return the folder and each line's output."""
    from conftest import _need  # skips, or fails under CI, without the shared data

    _need("intel-research-lab/intel.orig.bag")
    data = _need("intel-research-lab").parent
    work = tmp_path_factory.mktemp("quickstart")
    outputs = {}
    for line in quickstart_lines():
        words = shlex.split(line)
        if words[0] != "probmap":
            continue
        args = [DATASET if w == BAG_IN_README else w for w in words[1:]]
        for command, extra in SHORT.items():
            if tuple(args[: len(command)]) == command:
                args += extra
        done = _probmap(args, work, data)
        assert done.returncode == 0, f"{line}\n{done.stdout}\n{done.stderr}"
        outputs[" ".join(words[:3])] = done.stdout + done.stderr
    return work, outputs


def test_slam_grid_writes_a_nav2_map(quickstart_run):
    from probmap.grid.io import read_map_server

    work, outputs = quickstart_run
    out = work / "out"
    for name in ("yaml", "pgm", "plot.png", "trajectory.csv", "tum", "report.json"):
        assert (out / f"slam.{name}").is_file(), f"out/slam.{name} is missing"
    import yaml

    meta = yaml.safe_load((out / "slam.yaml").read_text())
    # what the README and the docs state, and what nav2's map_server needs
    assert meta["image"] == "slam.pgm" and meta["mode"] == "trinary"
    assert meta["occupied_thresh"] == 0.65 and meta["free_thresh"] == 0.196
    assert meta["resolution"] == 0.05 and len(meta["origin"]) == 3
    m = read_map_server(out / "slam.yaml")
    classes = m.classify()
    # a building: walls, free space and unknown beyond, and not a blank image
    assert classes.shape[0] > 100 and classes.shape[1] > 100
    n = {int(v): int(c) for v, c in zip(*np.unique(classes, return_counts=True), strict=True)}
    assert n.get(1, 0) > 300 and n.get(0, 0) > 5000 and n.get(-1, 0) > 1000, n
    assert "probmap info" in " ".join(outputs) and "/scan" in outputs["probmap info run.bag"]


def _same_poses(csv_path: Path, tum_path: Path) -> int:
    from probmap.datasets.tum import read_tum
    from probmap.metrics.relations import read_trajectory

    t_csv, p_csv = read_trajectory(csv_path)
    t_tum, p_tum = read_tum(tum_path)
    np.testing.assert_allclose(t_tum, t_csv, rtol=0, atol=2e-6)
    np.testing.assert_allclose(p_tum[:, :2], p_csv[:, :2], rtol=0, atol=2e-6)
    return len(t_tum)


def _tum_rows(path: Path) -> np.ndarray:
    """The TUM file as evo's reader takes it: 8 numbers a line, ``#`` comments."""
    rows = [
        [float(v) for v in line.split()]
        for line in path.read_text().splitlines()
        if line.strip() and not line.startswith("#")
    ]
    a = np.asarray(rows)
    assert a.ndim == 2 and a.shape[1] == 8
    assert np.all(np.diff(a[:, 0]) > 0)  # strictly increasing stamps
    np.testing.assert_allclose(np.linalg.norm(a[:, 4:], axis=1), 1.0, atol=1e-9)
    assert np.all(a[:, 3] == 0) and np.all(a[:, 4:6] == 0)  # planar: tz = qx = qy = 0
    return a


def test_the_tum_files_are_what_evo_reads(quickstart_run):
    work, _ = quickstart_run
    n_slam = _same_poses(work / "out/slam.trajectory.csv", work / "out/slam.tum")
    n_loc = _same_poses(work / "out/loc/trajectory.csv", work / "out/loc/trajectory.tum")
    slam, loc = _tum_rows(work / "out/slam.tum"), _tum_rows(work / "out/loc/trajectory.tum")
    # 60 s of a 5 Hz laser; the localization's first 300 scans overlap them
    assert 250 < n_slam < 400 and n_loc > 20
    assert loc[0, 0] >= slam[0, 0] - 1.0 and loc[0, 0] < slam[-1, 0]


def test_localize_tracks_the_slam_trajectory(quickstart_run):
    """The filter, started at the log's first pose in the SLAM map, stays near the SLAM
    trajectory: the reference table's median is centimetres, not metres."""
    work, outputs = quickstart_run
    text = outputs["probmap localize out/slam.yaml"]
    m = re.search(r"position\s*[│|]\s*(\d+)\s*[│|]\s*([\d.]+) m", text)
    assert m, text
    assert int(m.group(1)) > 20 and float(m.group(2)) < 0.3, text
    for name in ("trajectory.csv", "trajectory.tum", "trajectory.png", "config.yaml"):
        assert (work / "out/loc" / name).is_file()


@pytest.mark.skipif(
    shutil.which("evo_ape") is None, reason="evo is not installed (pip install evo)"
)
def test_evo_reads_the_files(quickstart_run):  # pragma: no cover - only where evo is installed
    work, _ = quickstart_run
    for line in quickstart_lines():
        if line.startswith("evo_"):
            done = subprocess.run(shlex.split(line), cwd=work, capture_output=True, text=True)
            assert done.returncode == 0, f"{line}\n{done.stdout}\n{done.stderr}"
