"""Fault injection (issue 38): SIGINT and SIGTERM at a seeded schedule of moments during
``optimize``, ``map``, ``slam grid`` with a session, ``localize`` and ``slam ekf``, through the
console entry point (``probmap.cli.app.main``), so that a moment may fall anywhere: while the
arguments are read, while the input is read, mid-computation, while the outputs are written or
the summary printed.

A moment is the n-th Python function call of the command (a profile hook raises the signal
there), drawn from the calls of an uninterrupted run. Afterwards: exit code 130 and exactly one
``interrupted: ...`` line, the last one, never a traceback; no temporary file; the outputs all
or none (the uninterrupted run's set of files, or nothing); a session saved by an interrupted
run resumes to exactly the uninterrupted trajectory.
"""

from __future__ import annotations

import contextlib
import io
import os
import random
import signal
import sys
from pathlib import Path

import pytest

from probmap.cli.app import main

#: moments per command (half SIGINT, half SIGTERM); PROBMAP_FAULTS raises it for a longer run
MOMENTS = int(os.environ.get("PROBMAP_FAULTS", "4"))


class _SignalAt:
    """A profile hook that raises ``sig`` at the ``n``-th Python call (counting only)."""

    def __init__(self, n: int, sig: int) -> None:
        self.n, self.sig, self.calls, self.fired = n, sig, 0, False

    def __call__(self, frame, event, arg) -> None:
        if event != "call":
            return
        self.calls += 1
        if not self.fired and self.calls >= self.n:
            self.fired = True
            signal.raise_signal(self.sig)


def _run(args: list[str], hook: _SignalAt | None = None) -> tuple[int, str]:
    out = io.StringIO()
    code: int = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        sys.setprofile(hook)
        try:
            main([str(a) for a in args])
        except SystemExit as exc:
            code = int(exc.code or 0)
        finally:
            sys.setprofile(None)
    return code, out.getvalue()


def _files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob("*")) if folder.exists() else []


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, sim_log_module):
    folder = tmp_path_factory.mktemp("inputs")
    log = sim_log_module(folder / "tour.log")
    graph = folder / "ring.g2o"
    lines = []
    for i in range(60):
        lines.append(f"VERTEX_SE2 {i} {float(i) * 1.01!r} {0.01 * (i % 3)!r} 0.0")
    for i in range(59):
        lines.append(f"EDGE_SE2 {i} {i + 1} 1.0 0.0 0.0 100 0 0 100 0 400")
    lines.append("EDGE_SE2 0 59 59.0 0.0 0.0 10 0 0 10 0 40")
    graph.write_text("\n".join(lines) + "\n")
    session = folder / "map.session"
    code, text = _run(["slam", "grid", log, "-o", folder / "map", "--save-session", session])
    assert code == 0, text
    return {"log": log, "graph": graph, "session": session}


@pytest.fixture(scope="module")
def sim_log_module():
    """``write(path)``: the simulated tour as a CARMEN log (as the ``sim_log`` fixture)."""

    def write(path: Path) -> Path:
        from probmap.sim.floorplan import simulate_laser_world

        w = simulate_laser_world(seed=1, size=(12.0, 8.0), step=0.2, range_noise=0.01)
        lines = [f"PARAM robot_front_laser_max {w.max_range}"]
        for i, (p, r) in enumerate(zip(w.poses, w.ranges, strict=True)):
            rs = " ".join(f"{v:.3f}" for v in r)
            pose = f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}"
            lines.append(f"FLASER {len(r)} {rs} {pose} {pose} {i * 0.2:.3f} sim {i * 0.2:.3f}")
        path.write_text("\n".join(lines) + "\n")
        return path

    return write


COMMANDS = {
    "optimize": lambda i, out: ["optimize", i["graph"], "-o", out / "o.g2o"],
    "map": lambda i, out: ["map", i["log"], "-o", out / "m"],
    "slam-grid": lambda i, out: [
        "slam",
        "grid",
        i["log"],
        "-o",
        out / "s",
        "--save-session",
        out / "s.session",
    ],  # fmt: skip
    "localize": lambda i, out: ["localize", i["session"], i["log"], "-o", out, "-n", "200"],
    "slam-ekf": lambda i, out: ["slam", "ekf", "simulation", "-o", out, "--no-plot"],
}


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_signals_at_seeded_moments(command, inputs, tmp_path):
    make = COMMANDS[command]
    # the uninterrupted run, twice: the second counts the calls of a warm process
    for k in range(2):
        base = tmp_path / f"base{k}"
        hook = _SignalAt(10**15, signal.SIGINT)
        code, text = _run(make(inputs, base), hook)
        assert code == 0, text
    expected = _files(base)
    rng = random.Random(f"issue 38 {command}")
    for k in range(MOMENTS):
        sig = (signal.SIGINT, signal.SIGTERM)[k % 2]
        at = rng.randrange(1, int(0.98 * hook.calls))
        out = tmp_path / f"run{k}"
        fault = _SignalAt(at, sig)
        code, text = _run(make(inputs, out), fault)
        where = f"{command}: {sig.name} at call {at:,} of {hook.calls:,}\n{text}"
        assert fault.fired, where
        lines = [x.strip() for x in text.splitlines() if x.strip()]
        said = [x for x in lines if x.startswith("interrupted:")]
        assert code == 130 and len(said) == 1 and lines[-1] == said[0], where
        assert "Traceback" not in text, where
        got = _files(out)
        assert not [n for n in got if n.startswith(".")], where  # no temporary left
        if said[0] == "interrupted: nothing written":
            assert got == [], where
        else:  # the outputs of the scans (steps) it got to: every file of a whole run
            assert got == expected, where
        if command == "slam-grid" and (out / "s.session").exists():
            _resumes_to_the_whole_run(inputs, out, base)


def _resumes_to_the_whole_run(inputs, out: Path, base: Path) -> None:
    """The session an interrupted run saved, resumed with the same log: exactly the
    uninterrupted trajectory (or nothing to resume when the run had got to the end)."""
    from probmap.pipelines.sessions import read_session_info

    info = read_session_info(out / "s.session")
    code, text = _run(
        ["slam", "grid", inputs["log"], "-o", out / "r", "--resume", out / "s.session"]
    )
    if info.complete:
        assert code == 1 and "holds every scan of tour.log already" in text, text
        return
    assert code == 0, text
    assert (out / "r.trajectory.csv").read_text() == (base / "s.trajectory.csv").read_text()
