"""A full disk (issue 38): every command's error is one line that names the output it could
not write, and nothing is left on the full file system (no temporary, no partial output).
Needs a small tmpfs: run as root where mounting is allowed, skipped otherwise."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app

register(app)


@pytest.fixture
def full_disk(tmp_path):
    """A 64 KiB tmpfs at ``tmp_path/full`` (unmounted afterwards)."""
    folder = tmp_path / "full"
    folder.mkdir()
    if os.name != "posix" or os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(folder)],
        capture_output=True,
        check=False,
    )
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=False)


def _one_error_line(res, target: Path) -> None:
    lines = [x for x in res.output.splitlines() if x.strip()]
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output
    assert lines[-1].startswith("error: ") and f"cannot write {target}" in lines[-1], lines
    assert "No space left on device" in lines[-1]


def test_full_disk_errors_name_the_output(full_disk, tmp_path, sim_log):
    log = sim_log(tmp_path / "tour.log")
    runner = CliRunner()
    res = runner.invoke(app, ["slam", "grid", str(log), "-o", str(full_disk / "s")])
    _one_error_line(res, full_disk / "s.")
    res = runner.invoke(app, ["slam", "grid", str(log), "-o", str(tmp_path / "elsewhere" / "s"),
                              "--save-session", str(full_disk / "x.session")])  # fmt: skip
    _one_error_line(res, full_disk / "x.session")
    assert not (tmp_path / "elsewhere").exists()  # all outputs or none
    graph = tmp_path / "g.g2o"
    vertices = "".join(f"VERTEX_SE2 {i} {float(i)!r} 0.0 0.0\n" for i in range(4000))
    edges = "".join(f"EDGE_SE2 {i} {i + 1} 1.0 0.0 0.0 1 0 0 1 0 1\n" for i in range(3999))
    graph.write_text(vertices + edges)  # its g2o output is larger than the disk
    res = runner.invoke(app, ["optimize", str(graph), "-o", str(full_disk / "o.g2o")])
    _one_error_line(res, full_disk / "o.g2o")
    assert list(full_disk.iterdir()) == []  # no temporary left on the full disk
