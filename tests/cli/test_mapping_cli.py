"""CLI: probmap demo / map / --version, errors as one line and non-zero exits, no partial files."""

from __future__ import annotations

import bz2
import gzip
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app

register(app)
runner = CliRunner()


def run(*args: str):
    return runner.invoke(app, list(args))


def test_version():
    res = run("--version")
    assert res.exit_code == 0 and res.output.startswith("probmap 0.")


def test_help_imports_no_heavy_modules():
    code = (
        "import sys; from probmap.cli.app import app; from probmap.cli import register; "
        "register(app); heavy = [m for m in ('numba', 'scipy', 'matplotlib', 'numpy') "
        "if m in sys.modules]; print(','.join(heavy))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    heavy = out.stdout.strip()
    assert "numba" not in heavy and "scipy" not in heavy and "matplotlib" not in heavy, heavy


def test_demo_writes_map_and_reports_accuracy(tmp_path):
    res = run("demo", "-o", str(tmp_path / "d"))
    assert res.exit_code == 0, res.output
    assert "accuracy" in res.output
    for ext in ("yaml", "pgm", "npz", "png"):
        assert (tmp_path / "d" / f"map.{ext}").stat().st_size > 0


def _flaser(ranges, pose, t):
    r = " ".join(f"{v:.3f}" for v in ranges)
    x, y, th = pose
    return f"FLASER {len(ranges)} {r} {x} {y} {th} {x} {y} {th} {t} host {t}\n"


def _write_log(path: Path, n_scans=20, opener=open):
    angles = -np.pi / 2 + np.arange(180) * np.pi / 180
    lines = ["# synthetic log\n", "PARAM robot_frontlaser_offset 0.0 host 0\n"]
    for k in range(n_scans):
        pose = (0.1 * k, 0.0, 0.0)
        # a wall at x = 5: range = (5 - x) / cos(angle) where it faces the wall, else max range
        c = np.cos(angles)
        r = np.where(c > 0.2, (5.0 - pose[0]) / np.maximum(c, 1e-9), 81.9)
        lines.append(_flaser(np.minimum(r, 81.9), pose, 100.0 + k))
    with opener(path, "wt") as f:
        f.writelines(lines)


@pytest.mark.parametrize("suffix,opener", [("", open), (".gz", gzip.open), (".bz2", bz2.open)])
def test_map_command_on_a_small_log(tmp_path, suffix, opener):
    log = tmp_path / f"wall.clf{suffix}"
    _write_log(log, opener=opener)
    res = run("map", str(log), "-o", str(tmp_path / "m"), "--resolution", "0.1")
    assert res.exit_code == 0, res.output
    assert "scans" in res.output and "20" in res.output
    from probmap.grid.io import load_npz

    grid = load_npz(tmp_path / "m.npz")
    c = grid.classify()
    wall = grid.spec.world_to_cell([5.02, 0.0])
    assert c[wall[1], wall[0]] == 1
    mid = grid.spec.world_to_cell([3.0, 0.0])
    assert c[mid[1], mid[0]] == 0


def _assert_one_line_error(res, *needles):
    assert res.exit_code != 0
    assert "Traceback" not in res.output
    err = res.output.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:"), res.output
    for n in needles:
        assert n in err[0], err[0]


def test_map_errors(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("")
    out = afile / "m"  # a missing output folder is created, a file in its place is an error
    _assert_one_line_error(
        run("map", str(tmp_path / "missing.clf"), "-o", str(tmp_path / "m")), "missing.clf"
    )
    log = tmp_path / "ok.clf"
    _write_log(log)
    _assert_one_line_error(run("map", str(log), "-o", str(out)), "afile", "not a folder")
    bad = tmp_path / "bad.clf"
    text = log.read_text().splitlines(keepends=True)
    text.insert(5, "FLASER 180 1.0 2.0 oops\n")
    bad.write_text("".join(text))
    _assert_one_line_error(run("map", str(bad), "-o", str(tmp_path / "b")), "bad.clf", "line 6")
    assert not list(tmp_path.glob("b.*"))
    res = run("map", str(bad), "-o", str(tmp_path / "b"), "--skip-bad-lines")
    assert res.exit_code == 0, res.output
    assert "skipped bad lines" in res.output
    empty = tmp_path / "empty.clf.gz"
    empty.write_bytes(b"")
    _assert_one_line_error(run("map", str(empty), "-o", str(tmp_path / "e")), "empty.clf.gz")
    trunc = tmp_path / "trunc.clf.bz2"
    _write_log(tmp_path / "full.clf.bz2", n_scans=200, opener=bz2.open)
    data = (tmp_path / "full.clf.bz2").read_bytes()
    trunc.write_bytes(data[: len(data) // 2])
    _assert_one_line_error(run("map", str(trunc), "-o", str(tmp_path / "t")), "trunc.clf.bz2")
    assert not list(tmp_path.glob("t.*")) and not list(tmp_path.glob("e.*"))


def test_unwritable_output(tmp_path, monkeypatch):
    log = tmp_path / "ok.clf"
    _write_log(log)
    ro = tmp_path / "ro"
    ro.mkdir()
    real_access = os.access
    monkeypatch.setattr(
        os, "access", lambda p, mode: False if Path(p) == ro else real_access(p, mode)
    )
    _assert_one_line_error(run("map", str(log), "-o", str(ro / "m")), "not writable")
    assert not list(ro.iterdir())


def test_map_method_map(tmp_path):
    log = tmp_path / "wall.clf"
    _write_log(log)
    res = run("map", str(log), "-o", str(tmp_path / "m"), "--resolution", "0.1", "--method", "map")
    assert res.exit_code == 0, res.output
    assert "objective" in res.output
    from probmap.grid.io import load_npz

    grid = load_npz(tmp_path / "m.npz")
    wall = grid.spec.world_to_cell([5.02, 0.0])
    assert grid.classify()[wall[1], wall[0]] == 1
    _assert_one_line_error(
        run("map", str(log), "-o", str(tmp_path / "x"), "--method", "nope"), "--method"
    )


def test_map_several_logs_on_a_local_dask_cluster(tmp_path):
    pytest.importorskip("distributed")
    a, b = tmp_path / "a.clf", tmp_path / "b.clf"
    _write_log(a)
    _write_log(b, n_scans=10)
    res = run(
        "map", str(a), str(b), "-o", str(tmp_path / "m"), "--resolution", "0.1", "--workers", "1"
    )
    assert res.exit_code == 0, res.output
    from probmap.grid.io import load_npz

    grid = load_npz(tmp_path / "m.npz")
    wall = grid.spec.world_to_cell([5.02, 0.0])
    assert grid.classify()[wall[1], wall[0]] == 1
    bad = tmp_path / "bad.clf"
    bad.write_text("FLASER 180 1.0 oops\n")
    res = run("map", str(a), str(bad), "-o", str(tmp_path / "n"), "--workers", "1")
    assert res.exit_code == 1 and "bad.clf" in res.output
    assert not list(tmp_path.glob("n.*"))


def test_demo_semantic_and_localize_flags(tmp_path):
    res = run("demo", "--semantic", "-o", str(tmp_path / "s"))
    assert res.exit_code == 0, res.output
    assert "IoU" in res.output and (tmp_path / "s" / "semantic.png").exists()
    res = run("demo", "--semantic", "--localize", "-o", str(tmp_path / "x"))
    assert res.exit_code == 1 and "choose one" in res.output


def test_to_bag_is_refused_with_a_cluster_before_any_work(tmp_path, shared_data):
    """``--to-bag`` writes one bag's map; with --workers (or several logs, or --chunks) it is a
    one-line error up front, not an option silently ignored."""
    bag = shared_data("intel-research-lab/intel.orig.bag")
    for extra in (["--chunks", "2"], [str(bag)]):
        res = run("map", str(bag), *extra, "-o", str(tmp_path / "out"), "--to-bag",
                  str(tmp_path / "m.bag"))  # fmt: skip
        assert res.exit_code == 1, res.output
        assert "--to-bag writes the map of one bag" in res.output and "Traceback" not in res.output
    assert list(tmp_path.iterdir()) == []


def test_map_config_file_options_over_it_and_the_recorded_configuration(tmp_path):
    """--config FILE.yaml sets MappingConfig's fields, options given override them, and
    PREFIX.config.yaml records the configuration the map was built with (it loads back equal);
    a bad file is one line naming the file and the field, before any work."""
    from probmap.config import load_config
    from probmap.grid.io import load_npz
    from probmap.pipelines import MappingConfig

    log = tmp_path / "a.log"
    _write_log(log)
    (tmp_path / "c.yaml").write_text("resolution: 0.2\np_hit: 0.8\n")
    res = run("map", str(log), "-o", str(tmp_path / "one"), "--config", str(tmp_path / "c.yaml"))
    assert res.exit_code == 0, res.output
    assert load_npz(tmp_path / "one.npz").spec.resolution == 0.2
    recorded = load_config(MappingConfig, tmp_path / "one.config.yaml")
    assert recorded == MappingConfig(resolution=0.2, p_hit=0.8)
    res = run("map", str(log), "-o", str(tmp_path / "two"), "--config", str(tmp_path / "c.yaml"),
              "-r", "0.1")  # fmt: skip
    assert res.exit_code == 0, res.output
    assert load_config(MappingConfig, tmp_path / "two.config.yaml") == MappingConfig(
        resolution=0.1, p_hit=0.8
    )
    (tmp_path / "bad.yaml").write_text("resolution: fine\n")
    res = run(
        "map", str(log), "-o", str(tmp_path / "three"), "--config", str(tmp_path / "bad.yaml")
    )
    assert res.exit_code == 1 and "bad.yaml" in res.output and "resolution" in res.output
    assert len(res.output.strip().splitlines()) == 1
    assert not list(tmp_path.glob("three*"))
