"""Progress where the output is not a terminal: one line about every 10 %, with an ETA from
the recent pace."""

from __future__ import annotations

import io
import re

import pytest
from rich.console import Console

import probmap.cli.common as common
from probmap.cli.common import LineProgress, progress_bar


@pytest.fixture(autouse=True)
def _lines_after_two_seconds(monkeypatch):
    monkeypatch.setattr(common, "QUIET_S", 2.0)  # conftest silences them elsewhere


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_not_a_terminal_gets_lines():
    out = io.StringIO()
    bar = progress_bar("x", console=Console(file=out, force_terminal=False))
    assert isinstance(bar, LineProgress)
    terminal = progress_bar("x", console=Console(file=io.StringIO(), force_terminal=True))
    assert not isinstance(terminal, LineProgress)


def test_a_line_per_tenth_with_the_time_left():
    out, clock = io.StringIO(), Clock()
    with LineProgress("slam intel", unit="scans", file=out, clock=clock) as bar:
        task = bar.add_task("ignored", total=1000)
        for i in range(1, 1001):
            clock.t = i * 0.5  # 2 scans a second: 1000 scans take 500 s
            bar.update(task, completed=i)
    lines = out.getvalue().splitlines()
    assert len(lines) == 10
    for k, line in enumerate(lines, start=1):
        m = re.fullmatch(
            r"slam intel: (\d+)% \(([\d,]+)/1,000 scans\), (.+) so far, eta (.+)", line
        )
        assert m, line
        assert int(m[1]) == 10 * k and int(m[2].replace(",", "")) == 100 * k
        left = (1000 - 100 * k) / 2.0  # seconds at 2 scans a second
        want = f"{int(left)} s" if left < 60 else f"{int(left) // 60} min {int(left) % 60:02d} s"
        assert m[4] == want, line
    assert lines[-1].endswith("eta 0 s")


def test_the_eta_follows_the_recent_pace_and_one_step_tasks_are_silent():
    out, clock = io.StringIO(), Clock()
    bar = LineProgress(unit="steps", file=out, clock=clock)
    bar.add_task("writing", total=1)
    bar.advance(0)
    assert out.getvalue() == ""
    task = bar.add_task("run", total=100)
    for i in range(1, 51):  # slow start: 1 step a second for 50 s
        clock.t = float(i)
        bar.update(task, completed=i)
    for i in range(51, 61):  # then 10 steps a second
        clock.t = 50.0 + (i - 50) * 0.1
        bar.update(task, completed=i)
    clock.t += 61.0  # 61 s later, 10 more steps: the earlier pace has left the 60 s window
    bar.update(task, completed=70)
    last = out.getvalue().splitlines()[-1]
    # the rate is over the window's oldest sample (51 s, 60 steps) to (112 s, 70 steps):
    # 10 steps in 61 s, 30 steps left: 183 s (the rate since the start would say 48 s)
    assert last == "run: 70% (70/100 steps), 1 min 52 s so far, eta 3 min 03 s", last


def test_a_quick_task_prints_nothing():
    out, clock = io.StringIO(), Clock()
    bar = LineProgress(file=out, clock=clock)
    task = bar.add_task("download", total=8)
    for i in range(1, 9):
        clock.t = 0.1 * i  # done in under QUIET_S
        bar.update(task, completed=i)
    assert out.getvalue() == ""
