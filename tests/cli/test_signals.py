"""SIGTERM is a Ctrl-C for every command (issue 38): one line, exit 130, all outputs or none;
temporaries of a killed run are removed by the next write of the same output, which says so."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from typer.testing import CliRunner

from probmap import _atomic
from probmap.cli import register
from probmap.cli.app import app

register(app)


def _graph(path: Path) -> Path:
    lines = [f"VERTEX_SE2 {i} {float(i)!r} 0.0 0.0" for i in range(6)]
    lines += [f"EDGE_SE2 {i} {i + 1} 1.0 0.0 0.0 1 0 0 1 0 1" for i in range(5)]
    path.write_text("\n".join(lines) + "\n")
    return path


def _lines(output: str) -> list[str]:
    return [x for x in output.splitlines() if x.strip()]


def test_sigterm_during_optimize_writes_nothing_and_says_so_in_one_line(tmp_path, monkeypatch):
    import probmap.pipelines.optimize as po

    real = po.optimize_graph

    def optimize_graph(*args, **kwargs):
        signal.raise_signal(signal.SIGTERM)  # as `timeout` or systemd would send it
        return real(*args, **kwargs)

    monkeypatch.setattr(po, "optimize_graph", optimize_graph)
    before = signal.getsignal(signal.SIGTERM)
    out = tmp_path / "out" / "o.g2o"
    res = CliRunner().invoke(app, ["optimize", str(_graph(tmp_path / "g.g2o")), "-o", str(out)])
    assert res.exit_code == 130, res.output
    assert _lines(res.output) == ["interrupted: nothing written"]
    assert not out.parent.exists() or not any(out.parent.iterdir())
    assert signal.getsignal(signal.SIGTERM) is before  # the handler is put back


def test_sigterm_during_slam_grid_stops_as_ctrl_c_does(tmp_path, sim_log, monkeypatch):
    """The first SIGTERM asks the run to stop after the scan, as Ctrl-C: the partial map and
    trajectory are written, with the same one-line message as every command."""
    from probmap.slam.laser.submap_slam import SubmapSlam

    log = sim_log(tmp_path / "tour.log")
    real = SubmapSlam.add_scan
    calls = [0]

    def add_scan(self, *args, **kwargs):
        calls[0] += 1
        if calls[0] == 40:
            signal.raise_signal(signal.SIGTERM)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(SubmapSlam, "add_scan", add_scan)
    out = tmp_path / "out" / "part"
    res = CliRunner().invoke(app, ["slam", "grid", str(log), "-o", str(out)])
    assert res.exit_code == 130, res.output
    assert "SIGTERM: stopping after this scan" in res.output
    assert "interrupted: wrote the results of the first 40 of" in res.output
    rows = (out.parent / "part.trajectory.csv").read_text().splitlines()
    assert len(rows) == 1 + 40
    calls[0] = 0
    none = tmp_path / "none" / "part"
    res = CliRunner().invoke(app, ["slam", "grid", str(log), "-o", str(none), "--no-save-partial"])
    assert res.exit_code == 130 and _lines(res.output)[-1] == "interrupted: nothing written"
    assert not none.parent.exists()


def test_leftovers_of_dead_writers_are_removed_by_the_next_write(tmp_path):
    out = tmp_path / "o.g2o"
    dead = 2**22 + 4321  # above Linux's largest pid: no such process
    gone = [
        tmp_path / f".o.g2o.{dead}-deadbeef.tmp",
        tmp_path / f".o.g2o.{dead}-0badcafe.bak",
        tmp_path / f".o.g2o.{dead}-ab_cd12z.tmp",  # atomic_path's folder
        tmp_path / ".o.g2o.0123abcd.tmp",  # an older version's, two days old
    ]
    kept = [
        tmp_path / f".o.g2o.{os.getpid()}-feedface.tmp",  # a running writer's (this one)
        tmp_path / ".o.g2o.4567abcd.tmp",  # an older version's, fresh: may be running
        tmp_path / f".other.g2o.{dead}-deadbeef.tmp",  # another output's
        tmp_path / f"o.g2o.{dead}-deadbeef.tmp",  # not hidden: not ours
    ]
    for p in gone + kept:
        if p.name.endswith("z.tmp"):
            p.mkdir()
            (p / "o.g2o").write_text("partial")
        else:
            p.write_text("partial")
    two_days = time.time() - 2 * 86400
    os.utime(gone[3], (two_days, two_days))
    res = CliRunner().invoke(app, ["optimize", str(_graph(tmp_path / "g.g2o")), "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert out.is_file()
    assert not any(p.exists() for p in gone)
    assert all(p.exists() for p in kept)
    said = [x for x in _lines(res.output) if x.startswith("removed 4 temporary file(s)")]
    assert len(said) == 1 and "left by killed runs" in said[0]


def test_a_sigkilled_writer_leaves_a_temporary_that_the_next_write_removes(tmp_path):
    """A real SIGKILL in the middle of an atomic write: the target is untouched, the
    temporary stays; the next write of the target removes it and reports it."""
    target = tmp_path / "map.yaml"
    target.write_text("old\n")
    code = (
        "import os, signal, sys\n"
        "from probmap._atomic import atomic_write\n"
        "with atomic_write(sys.argv[1], 'w') as f:\n"
        "    f.write('half')\n"
        "    f.flush()\n"
        "    os.kill(os.getpid(), signal.SIGKILL)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(_atomic.__file__).parents[1])}
    done = subprocess.run([sys.executable, "-c", code, str(target)], env=env, check=False)
    assert done.returncode == -signal.SIGKILL
    left = [p for p in tmp_path.iterdir() if p.name != "map.yaml"]
    assert (
        len(left) == 1 and left[0].name.startswith(".map.yaml.") and target.read_text() == "old\n"
    )
    n = len(_atomic.removed_leftovers)
    with _atomic.atomic_write(target, "w") as f:
        f.write("new\n")
    assert target.read_text() == "new\n" and sorted(tmp_path.iterdir()) == [target]
    assert _atomic.removed_leftovers[n:] == left


def test_sweeping_is_once_per_target_and_never_fails_a_write(tmp_path):
    target = tmp_path / "x.csv"
    first = _atomic.sweep_leftovers(target)
    (tmp_path / f".x.csv.{2**22 + 7}-deadbeef.tmp").write_text("")
    assert first == [] and _atomic.sweep_leftovers(target) == []  # swept once per process
    assert _atomic.sweep_leftovers(tmp_path / "missing" / "y.csv") == []
    assert not target.exists()


def test_library_warnings_are_one_line_without_python_source(monkeypatch, capsys):
    """``probmap`` shows a library warning as ``warning: MESSAGE``: no file name and line of
    probmap's source, no second line (issue 39: every bag command printed
    ``rosbag.py:1113: UserWarning ...``). The handler is the CLI's only."""
    import warnings

    import probmap.cli as cli
    from probmap.cli import app as entry

    def command(args: list[str] | None = None, prog_name: str | None = None) -> None:
        warnings.warn("x.bag: dropped 1 scan(s)\n  past the tf buffer", UserWarning, stacklevel=1)

    monkeypatch.setattr(cli, "register", lambda app: None)
    monkeypatch.setattr(entry, "app", command)
    before = warnings.showwarning
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        entry.main([])
    err = capsys.readouterr().err
    assert err == "warning: x.bag: dropped 1 scan(s) past the tf buffer\n"
    assert warnings.showwarning is before
