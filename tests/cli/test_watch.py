"""cli.watch: the first Ctrl-C asks the run to stop, the second aborts; the handler is put back;
off the main thread (or disabled) nothing changes; a recording must be FILE.rrd."""

from __future__ import annotations

import signal
import threading
from pathlib import Path

import pytest
import typer

from probmap.cli.watch import interrupted_exit, open_view, stop_on_ctrl_c


def test_first_ctrl_c_asks_to_stop_second_aborts(capsys):
    before = signal.getsignal(signal.SIGINT)
    with stop_on_ctrl_c(True, "scan") as stop:
        assert stop is not None and not stop()
        signal.raise_signal(signal.SIGINT)
        assert stop()
        assert "stopping after this scan" in capsys.readouterr().err
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)
    assert signal.getsignal(signal.SIGINT) is before


def test_disabled_or_off_the_main_thread_changes_nothing():
    before = signal.getsignal(signal.SIGINT)
    with stop_on_ctrl_c(False) as stop:
        assert stop is None and signal.getsignal(signal.SIGINT) is before
    seen = []

    def worker() -> None:
        with stop_on_ctrl_c(True) as s:
            seen.append(s)

    t = threading.Thread(target=worker)
    t.start()
    t.join()
    assert seen == [None]


def test_interrupted_exit_and_view_checks(capsys, tmp_path):
    with pytest.raises(typer.Exit) as e:
        interrupted_exit(40, 1200, "scans", wrote=True)
    assert e.value.exit_code == 130
    assert capsys.readouterr().err.strip() == (
        "interrupted: wrote the results of the first 40 of 1,200 scans"
    )
    assert open_view("t", False, None) is None
    with pytest.raises(ValueError, match="FILE.rrd"):
        open_view("t", False, Path(tmp_path / "x.png"))
