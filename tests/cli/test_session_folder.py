"""``slam grid --save-session`` and ``--resume`` take a folder as ``-o`` does: the session is
``FOLDER/slam.session`` (issue 21: "--save-session S.npz (or a directory)")."""

from __future__ import annotations

from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app

register(app)


def test_a_folder_holds_the_session_and_resumes_it(tmp_path, sim_log):
    lines = sim_log(tmp_path / "tour.log").read_text().splitlines()
    head, scans = lines[:1], lines[1:]
    h = len(scans) // 2
    (tmp_path / "a.log").write_text("\n".join(head + scans[:h]) + "\n")
    (tmp_path / "b.log").write_text("\n".join(head + scans[h:]) + "\n")
    folder = tmp_path / "sessions"
    folder.mkdir()
    runner = CliRunner()
    first = runner.invoke(
        app, ["slam", "grid", str(tmp_path / "a.log"), "-o", str(tmp_path / "a"),
              "--save-session", str(folder)],
    )  # fmt: skip
    assert first.exit_code == 0, first.output
    assert [p.name for p in folder.iterdir()] == ["slam.session"]
    from probmap.pipelines.localize import load_localization_map

    loc = load_localization_map(folder)  # localize --map FOLDER reads the same file
    assert loc.kind == "session" and loc.source == folder / "slam.session"
    second = runner.invoke(
        app, ["slam", "grid", str(tmp_path / "b.log"), "-o", str(tmp_path / "b"),
              "--resume", str(folder)],
    )  # fmt: skip
    assert second.exit_code == 0, second.output
    assert f"{h:,} scans before this log" in second.output


def test_localize_map_takes_the_session_folder(tmp_path):
    from probmap.pipelines.localize import load_localization_map

    folder = tmp_path / "empty"
    folder.mkdir()
    try:
        load_localization_map(folder)
    except FileNotFoundError as exc:  # the folder's session file is named, not the folder
        assert str(folder / "slam.session") in str(exc)
    else:
        raise AssertionError("an empty folder is not a session")
