"""The CLI's shared helpers: one-line errors and the summary table."""

from __future__ import annotations

import pytest
import typer
from rich.console import Console

from probmap.cli.common import CliError, cli_errors, print_summary


def _render(*args, **kwargs) -> str:
    console = Console(record=True, width=60, color_system=None)
    print_summary(*args, console=console, **kwargs)
    return console.export_text()


def test_summary_table_rows_and_title():
    text = _render("probmap map", [("scans", "910"), ("wrote", "out.pgm")])
    lines = [ln.rstrip() for ln in text.splitlines() if ln.strip()]
    assert lines[0].strip() == "probmap map"
    assert lines[1].split() == ["scans", "910"] and lines[2].split() == ["wrote", "out.pgm"]
    assert not any(ch in text for ch in "┃│─━")  # borderless, no header row


def test_summary_table_justifies_the_values():
    rows = [("a", "1"), ("long name", "12345")]
    right = [ln.rstrip() for ln in _render(None, rows).splitlines() if ln.strip()]
    left = [ln.rstrip() for ln in _render(None, rows, justify="left").splitlines() if ln.strip()]
    assert len(right[0]) == len(right[1])  # "1" ends where "12345" ends
    assert len(left[0]) < len(left[1])


def test_cli_errors_one_line_and_exit_code(capsys):
    with pytest.raises(typer.Exit) as info:
        with cli_errors():
            raise CliError("no scans")
    assert info.value.exit_code == 1
    assert capsys.readouterr().err.strip() == "error: no scans"


def test_first_compile_notice_only_while_the_cache_is_empty(tmp_path, monkeypatch, capsys):
    """The notice appears when a module's kernels have no numba index file beside it (or in
    NUMBA_CACHE_DIR), and not once they do."""
    from probmap.cli.common import kernels_cached, note_first_compile

    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    (tmp_path / "fake_kernels_mod.py").write_text("X = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert not kernels_cached("fake_kernels_mod")
    note_first_compile("fake_kernels_mod")
    assert "compiling numba kernels" in capsys.readouterr().err
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    (cache / "fake_kernels_mod.kernel-12.py311.nbi").write_bytes(b"")
    assert kernels_cached("fake_kernels_mod")
    note_first_compile("fake_kernels_mod")
    assert capsys.readouterr().err == ""
    assert not kernels_cached("fake_kernels_mod", "no_such_module_here")
    elsewhere = tmp_path / "numba-cache"
    (elsewhere / "sub").mkdir(parents=True)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(elsewhere))
    assert not kernels_cached("fake_kernels_mod")
    (elsewhere / "sub" / "fake_kernels_mod.kernel-12.py311.nbi").write_bytes(b"")
    assert kernels_cached("fake_kernels_mod")


def test_progress_bar_eta_follows_the_recent_rate_not_the_average():
    """The ETA divides the work left by the rate over the last ETA_WINDOW_S seconds: after a
    slow start (10 steps in 100 s) and a fast stretch (90 steps in 9 s), 100 steps left take
    about 10 s, where the rate since the start (100 steps in 109 s) would say about 109 s."""
    from probmap.cli.common import ETA_WINDOW_S, progress_bar

    console = Console(file=open(__import__("os").devnull, "w"), width=100, force_terminal=True)  # noqa: SIM115
    clock = [0.0]
    with progress_bar("test", unit="scans", console=console) as bar:
        bar.get_time = lambda: clock[0]
        task = bar.add_task("t", total=200)
        clock[0] = 100.0
        bar.update(task, completed=10)
        for k in range(1, 10):  # 10 steps a second
            clock[0] = 100.0 + k
            bar.update(task, completed=10 + 10 * k)
        state = bar.tasks[0]
        assert ETA_WINDOW_S < 100.0  # the slow start has left the window
        assert state.time_remaining is not None and 8.0 < state.time_remaining < 13.0


def test_stopwatch_row_covers_the_phases():
    import time

    from probmap.cli.common import Stopwatch

    watch = Stopwatch()
    with watch("read"):
        time.sleep(0.01)
    with watch("write"):
        time.sleep(0.01)
    name, value = watch.row()
    assert name == "time" and "read 0.0 s" in value and "write 0.0 s" in value
    assert watch.total >= sum(watch.phases.values()) > 0.015


def test_first_stopwatch_of_a_console_run_counts_the_start_up():
    import time

    from probmap.cli.common import Stopwatch, mark_process_start

    t0 = time.perf_counter()
    time.sleep(0.02)
    mark_process_start(t0)  # as the console script does
    first = Stopwatch()
    assert first.phases["start-up"] >= 0.02 and first.total >= first.phases["start-up"]
    assert "start-up" in first.row()[1]
    second = Stopwatch()  # a later one in the same process times from its own start
    assert "start-up" not in second.phases and second.total < first.total
