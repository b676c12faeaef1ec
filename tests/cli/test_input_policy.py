"""CLI bad-input matrix (issue 20): the same bad log gets the same verdict from every command
that reads laser logs -- exit code 1, one line naming the file (and the line where there is
one), no traceback, no file written -- and ``--skip-bad-lines`` means the same everywhere."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app

register(app)
runner = CliRunner()


def run(*args: object):
    return runner.invoke(app, [str(a) for a in args])


# --------------------------------------------------------------------------- inputs


def flaser(ranges, pose, t):
    r = " ".join(repr(float(v)) for v in ranges)
    p = " ".join(repr(float(v)) for v in (*pose, *pose))
    return f"FLASER {len(ranges)} {r} {p} {t!r} host {t - 50.0!r}\n"


def robotlaser(ranges, pose, t, res=0.0174533):
    r = " ".join(repr(float(v)) for v in ranges)
    p = " ".join(repr(float(v)) for v in (*pose, *pose))
    return (
        f"ROBOTLASER1 0 -1.5664 3.141593 {res!r} 81.9 0.01 0 {len(ranges)} {r} 0 {p} "
        f"0.3 0.05 0.6 0.3 0.25 {t!r} host {t - 7.0!r}\n"
    )


def room_ranges(x: float, beams: int = 90) -> list[float]:
    """Ranges from (x, 0) heading +x to the walls of a 10 m x 4 m room, beams over 180 deg."""
    out = []
    for a in np.linspace(-np.pi / 2, np.pi / 2, beams, endpoint=False):
        c, s = np.cos(a), np.sin(a)
        t = [(10.0 - x) / c if c > 1e-9 else np.inf, 2.0 / abs(s) if abs(s) > 1e-9 else np.inf]
        out.append(round(float(min(t)), 3))
    return out


def good_lines(n: int = 40) -> list[str]:
    return [
        flaser(room_ranges(1.0 + 0.05 * i), (1.0 + 0.05 * i, 0.0, 0.0), 100.0 + 0.1 * i)
        for i in range(n)
    ]


def _with(lines: list[str], k: int, line: str) -> list[str]:
    out = list(lines)
    out[k] = line
    return out


def bad_logs() -> dict[str, tuple[list[str], tuple[str, ...]]]:
    """case -> (lines, words the error line must hold besides the file name)."""
    n = 40

    def every(value: float) -> list[str]:
        return [flaser([value] * 90, (1.0 + 0.05 * i, 0.0, 0.0), 100.0 + 0.1 * i) for i in range(n)]

    good = good_lines(n)
    return {
        "all-zero": (every(0.0), ("no usable laser reading", "zero")),
        "all-nan": (every(float("nan")), ("no usable laser reading",)),
        "all-negative": (every(-1.0), ("no usable laser reading",)),
        "all-max-range": (every(81.9), ("no usable laser reading", "no return")),
        "pose-1e7": (
            _with(good, 20, flaser(room_ranges(2.0), (1e7, 0.0, 0.0), 102.0)),
            ("line 21", "field 'x'", "implausible"),
        ),
        "jump-1km": (
            _with(good, 20, flaser(room_ranges(2.0), (2.0, 1000.0, 0.0), 102.0)),
            ("line 21", "field 'y'", "jumps"),
        ),
        "rl-resolution-0": (
            [robotlaser(room_ranges(1.0), (1.0, 0.0, 0.0), 100.0, res=0.0)],
            ("line 1", "angular_resolution"),
        ),
    }


@pytest.fixture(scope="module")
def maps(tmp_path_factory) -> dict[str, Path]:
    """A map of the room (npz for match, map_server yaml for localize)."""
    d = tmp_path_factory.mktemp("maps")
    log = d / "room.clf"
    log.write_text("".join(good_lines()))
    res = run("map", log, "-o", d / "room", "-r", "0.1")
    assert res.exit_code == 0, res.output
    return {"npz": d / "room.npz", "yaml": d / "room.yaml"}


COMMANDS = {
    "map": lambda log, out, m: ["map", log, "-o", out / "m", "-r", "0.1"],
    "map --method map": lambda log, out, m: [
        "map", log, "-o", out / "mm", "-r", "0.2", "--method", "map",
    ],
    "fit-sensor-model": lambda log, out, m: [
        "fit-sensor-model", log, "-o", out / "fit.yaml", "-r", "0.1",
    ],
    "match": lambda log, out, m: ["match", m["npz"], log, "--scan", "0"],
    "localize": lambda log, out, m: ["localize", m["yaml"], log, "-o", out / "loc", "-n", "50"],
    "slam grid": lambda log, out, m: ["slam", "grid", log, "-o", out / "s"],
    "slam grid --method rbpf": lambda log, out, m: [
        "slam", "grid", log, "-o", out / "r", "--method", "rbpf", "-n", "3",
    ],
}  # fmt: skip


def _one_line_error(res, *words: str) -> str:
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


@pytest.mark.parametrize("case", list(bad_logs()))
@pytest.mark.parametrize("command", list(COMMANDS))
def test_bad_log_same_verdict_in_every_command(tmp_path, maps, command, case):
    lines, words = bad_logs()[case]
    log = tmp_path / f"{case}.clf"
    log.write_text("".join(lines))
    out = tmp_path / "out"
    out.mkdir()
    res = run(*COMMANDS[command](log, out, maps))
    _one_line_error(res, str(log), *words)
    assert not any(out.iterdir()), sorted(p.name for p in out.rglob("*"))  # nothing written


SKIPPABLE = ("pose-1e7", "jump-1km")


@pytest.mark.parametrize("command", list(COMMANDS))
def test_skip_bad_lines_means_the_same_in_every_command(tmp_path, maps, command):
    lines = bad_logs()["pose-1e7"][0]
    log = tmp_path / "glitch.clf"
    log.write_text("".join(lines))
    out = tmp_path / "out"
    out.mkdir()
    res = run(*COMMANDS[command](log, out, maps), "--skip-bad-lines")
    assert res.exit_code == 0, res.output
    assert "Traceback" not in res.output and "Warning" not in res.output, res.output
    m = re.search(r"skipped bad lines\s+(\d+)", res.output)
    assert m and int(m.group(1)) == 1, res.output
    m = re.search(r"readings\s+([\d,]+) in ([\d,]+) scans", res.output)
    assert m, res.output
    assert int(m.group(2).replace(",", "")) == len(lines) - 1


def test_mixed_beam_counts_are_reported_not_dropped(tmp_path):
    lines = good_lines(40)
    lines.insert(10, flaser(room_ranges(1.5, beams=91), (1.5, 0.0, 0.0), 100.95))
    log = tmp_path / "mixed.clf"
    log.write_text("".join(lines))
    res = run("map", log, "-o", tmp_path / "m", "-r", "0.1")
    assert res.exit_code == 0, res.output
    flat = " ".join(res.output.split())
    assert "0 dropped" in flat and "90 beams x 40 scans, 91 beams x 1 scan" in flat, res.output


def _labelled(path: Path, ranges: np.ndarray) -> Path:
    s, b = ranges.shape
    np.savez(
        path,
        poses=np.column_stack([np.linspace(0, 1, s), np.zeros(s), np.zeros(s)]),
        ranges=ranges,
        angles=np.linspace(-1.5, 1.5, b),
        max_range=np.array(30.0),
        classes=np.array(["free", "wall"]),
        labels=np.ones((s, b), dtype=np.int64),
    )
    return path


@pytest.mark.parametrize("value", [0.0, np.nan, -1.0, np.inf, 40.0])
def test_semantic_without_usable_reading_is_one_line(tmp_path, value):
    scans = _labelled(tmp_path / "blind.npz", np.full((5, 8), value))
    out = tmp_path / "out"
    out.mkdir()
    res = run("semantic", scans, "-o", out / "sem")
    _one_line_error(res, str(scans), "no usable laser reading")
    assert not any(out.iterdir())


def test_semantic_prints_the_readings_row(tmp_path):
    r = np.full((5, 8), 3.0)
    r[0, :2] = 0.0
    r[1, 0] = np.inf
    scans = _labelled(tmp_path / "ok.npz", r)
    res = run("semantic", scans, "-o", tmp_path / "sem")
    assert res.exit_code == 0, res.output
    flat = " ".join(res.output.split())
    assert "40 in 5 scans: 37 usable, 1 no return, 2 dropped (2 zero" in flat, res.output


def test_match_npz_with_nan_log_odds_is_one_line(tmp_path, maps):
    with np.load(maps["npz"]) as z:
        data = dict(z)
    data["log_odds"] = np.full_like(data["log_odds"], np.nan)
    bad = tmp_path / "nan.npz"
    np.savez(bad, **data)
    log = tmp_path / "room.clf"
    log.write_text("".join(good_lines()))
    _one_line_error(run("match", bad, log), str(bad), "log_odds")
