"""Sessions of graph SLAM are data: a zip of a JSON header, a JSON state tree and ``.npy``
arrays (docs/sessions.md). The oracles: a run split anywhere, saved, loaded and resumed is
exactly the uninterrupted run; crafted files (pickles with a payload, foreign classes, object
arrays, lying array headers) are refused with one line before anything in them is used; a
resume that would duplicate or skip scans is refused or warned about; an interrupted save
leaves the old session as it was."""

from __future__ import annotations

import io
import json
import pickle
import signal
import warnings
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.pipelines.laser_slam import load_laser_log, run_submap_slam
from probmap.pipelines.sessions import (
    NotASessionError,
    SessionGapWarning,
    load_session,
    read_session_info,
    resume_batch,
    save_session,
)

register(app)


def _part(batch, lo: int, hi: int):
    return replace(
        batch, times=batch.times[lo:hi], ranges=batch.ranges[lo:hi],
        laser_poses=batch.laser_poses[lo:hi], robot_poses=batch.robot_poses[lo:hi],
        angles=batch.angles if np.ndim(batch.angles) == 1 else batch.angles[lo:hi],
        beams=batch.beams[lo:hi],
    )  # fmt: skip


@pytest.fixture(scope="module")
def tour(tmp_path_factory):
    """The simulated tour's batch and its uninterrupted run."""
    from probmap.sim.floorplan import simulate_laser_world

    folder = tmp_path_factory.mktemp("tour")
    w = simulate_laser_world(seed=1, size=(12.0, 8.0), step=0.2, range_noise=0.01)
    lines = [f"PARAM robot_front_laser_max {w.max_range}"]
    for i, (p, r) in enumerate(zip(w.poses, w.ranges, strict=True)):
        rs = " ".join(f"{v:.3f}" for v in r)
        pose = f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}"
        lines.append(f"FLASER {len(r)} {rs} {pose} {pose} {i * 0.2:.3f} sim {i * 0.2:.3f}")
    log = folder / "tour.log"
    log.write_text("\n".join(lines) + "\n")
    batch = load_laser_log(log)
    return log, batch, run_submap_slam(batch)


def _assert_same_run(got, whole) -> None:
    np.testing.assert_array_equal(got.times, whole.times)
    np.testing.assert_array_equal(got.poses, whole.poses)
    np.testing.assert_array_equal(got.node_poses, whole.node_poses)
    np.testing.assert_array_equal(got.closures, whole.closures)
    np.testing.assert_array_equal(got.closure_weights, whole.closure_weights)
    np.testing.assert_array_equal(got.grid.log_odds, whole.grid.log_odds)


@pytest.mark.parametrize("share", [0.05, 0.5, 0.8])
def test_split_anywhere_resumes_to_exactly_the_whole_run(tour, tmp_path, share):
    """Splits early (one active submap), half way and late (finished submaps, closures)."""
    _, batch, whole = tour
    n = len(batch.times)
    h = int(share * n)
    path = tmp_path / "s.session"
    run_submap_slam(_part(batch, 0, h), save_session=path)
    slam = load_session(path)
    assert len(slam.scan_times) == h
    second = run_submap_slam(_part(batch, h, n), resume=slam)
    _assert_same_run(second, whole)
    if share == 0.8:  # the late split saved closures and finished submaps
        assert len(whole.closures) and any(sm.finished for sm in load_session(path).submaps)


def test_saving_twice_writes_the_same_bytes_and_a_header_says_what_it_covers(tour, tmp_path):
    log, batch, _ = tour
    from probmap.pipelines.sessions import SessionLog

    h = 50
    a, b = tmp_path / "a.session", tmp_path / "b.session"
    run_submap_slam(_part(batch, 0, h), save_session=a, log=SessionLog.of(log, batch))
    save_session(load_session(a), b, log=SessionLog.of(log, batch), log_used=h)
    assert a.read_bytes() == b.read_bytes()  # the loaded state is the saved one, to the bit
    info = read_session_info(a)
    assert (info.scans, info.first_time, info.last_time) == (h, batch.times[0], batch.times[h - 1])
    assert info.log_name == "tour.log" and info.log_scans == len(batch.times)
    with zipfile.ZipFile(a) as z:
        assert z.namelist()[:2] == ["header.json", "state.json"]
        header = json.loads(z.read("header.json"))
    assert header["config"]["submaps"]["scans"] == 40 and header["version"] == 5


# ----------------------------------------------------------------------------- hostile files
class _Payload:
    """Unpickling this creates a file: the proof that a loader ran code."""

    def __init__(self, flag: Path) -> None:
        self.flag = flag

    def __reduce__(self):
        return (Path.touch, (self.flag,))


def test_a_pickle_with_a_payload_never_runs_anywhere(tour, tmp_path):
    """load_session, slam grid --resume, localize FILE and localize FOLDER (its slam.session)
    refuse a planted pickle with one line, and its payload never runs."""
    log, _, _ = tour
    flag = tmp_path / "pwned"
    folder = tmp_path / "downloaded_map"
    folder.mkdir()
    planted = folder / "slam.session"
    planted.write_bytes(
        pickle.dumps({"format": "probmap.GraphSlam session", "version": 1, "x": _Payload(flag)})
    )
    with pytest.raises(ValueError, match="pickle, never loaded.*re-run"):
        load_session(planted)
    runner = CliRunner()
    for args in (
        ["slam", "grid", str(log), "-o", str(tmp_path / "o"), "--resume", str(planted)],
        ["slam", "grid", str(log), "-o", str(tmp_path / "o"), "--resume", str(folder)],
        ["localize", str(planted), str(log), "-o", str(tmp_path / "l")],
        ["localize", str(folder), str(log), "-o", str(tmp_path / "l")],
        ["localize", str(log), "--map", str(folder), "-o", str(tmp_path / "l")],
    ):
        res = runner.invoke(app, args)
        assert res.exit_code == 1, (args, res.output)
        lines = [x for x in res.output.splitlines() if x.strip()]
        assert len(lines) == 1 and "never loaded" in lines[0] and str(planted) in lines[0]
        assert "Traceback" not in res.output
    assert not flag.exists()
    assert not (tmp_path / "o.yaml").exists() and not (tmp_path / "l").exists()


def _session_bytes(tour, tmp_path) -> bytes:
    _, batch, _ = tour
    path = tmp_path / "good.session"
    run_submap_slam(_part(batch, 0, 30), save_session=path)
    return path.read_bytes()


def _rewrite(src: bytes, dst: Path, change) -> Path:
    """A copy of the session archive ``src`` with ``change(name, data) -> data | None``
    applied to every member (None drops it), written uncompressed unless it says otherwise."""
    with zipfile.ZipFile(io.BytesIO(src)) as z, zipfile.ZipFile(dst, "w") as out:
        for name in z.namelist():
            got = change(name, z.read(name))
            if got is not None:
                data, method = got if isinstance(got, tuple) else (got, zipfile.ZIP_STORED)
                out.writestr(name, data, compress_type=method)
    return dst


def _edit_state(fn):
    def change(name, data):
        if name != "state.json":
            return data
        tree = json.loads(data)
        fn(tree)
        return json.dumps(tree).encode()

    return change


def _npy(a) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, a, allow_pickle=True)
    return buf.getvalue()


def _first_array_key(tree) -> str:
    return tree["attrs"]["_weights"]["key"]


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("foreign class", "class 'Popen', which sessions do not hold"),
        ("foreign method", "method '__init__' that sessions do not hold"),
        ("object array", "of dtype object"),
        ("pickled npy", "of dtype object"),
        ("huge shape", "its header does not match its size"),
        ("compressed", "not a probmap graph-SLAM session"),
        ("no state", "not a probmap graph-SLAM session"),
        ("other version", "session format version 99, this probmap reads version 5"),
        ("extra attribute", "attributes this probmap does not have or lacks: ['planted']"),
        ("wrong type", "SubmapSlam.scan_times is a str"),
        ("short list", "entries in scan_node for"),
        ("dangling ref", "a reference to nothing"),
        ("bad config", "SubmapConfig: resolution"),
        ("deep nesting", "a malformed probmap session"),
    ],
)
def test_crafted_sessions_are_one_line_errors(tour, tmp_path, case, message):
    good = _session_bytes(tour, tmp_path)
    dst = tmp_path / f"{case.replace(' ', '_')}.session"

    def edit(tree):
        a = tree["attrs"]
        if case == "foreign class":
            a["graph"] = {"t": "object", "class": "Popen", "id": 10**6, "attrs": {}}
        elif case == "foreign method":
            a["loops"]["attrs"]["_full_points"]["name"] = "__init__"
        elif case == "extra attribute":
            a["planted"] = 1
        elif case == "wrong type":
            a["scan_times"] = "soon"
        elif case == "short list":
            a["scan_node"] = {"t": "list", "id": 10**6, "items": [0]}
        elif case == "dangling ref":
            a["active"] = {"t": "ref", "id": 10**6}
        elif case == "bad config":
            a["config"]["fields"]["submaps"]["fields"]["resolution"] = -1.0
        elif case == "deep nesting":
            a["failed_matches"] = "DEEP"

    if case in ("object array", "pickled npy", "huge shape"):
        key = _first_array_key(json.loads(zipfile.ZipFile(io.BytesIO(good)).read("state.json")))

        def change(name, data):
            if name != f"arrays/{key}.npy":
                return data
            if case == "huge shape":  # declares 2^40 doubles, holds none
                head = io.BytesIO()
                np.lib.format.write_array_header_1_0(
                    head, {"descr": "<f8", "fortran_order": False, "shape": (2**40,)}
                )
                return head.getvalue()
            return _npy(np.array([_Payload(tmp_path / "pwned")], dtype=object))

        _rewrite(good, dst, change)
    elif case == "compressed":
        _rewrite(good, dst, lambda name, data: (data, zipfile.ZIP_DEFLATED))
    elif case == "no state":
        _rewrite(good, dst, lambda name, data: None if name == "state.json" else data)
    elif case == "other version":

        def change(name, data):
            if name != "header.json":
                return data
            h = json.loads(data)
            h["version"] = 99
            return json.dumps(h).encode()

        _rewrite(good, dst, change)
    elif case == "deep nesting":  # nested past any recursion limit
        deep = '{"t":"tuple","items":[' * 100_000 + "1" + "]}" * 100_000

        def change(name, data):
            data = _edit_state(edit)(name, data)
            return data.replace(b'"DEEP"', deep.encode()) if name == "state.json" else data

        _rewrite(good, dst, change)
    else:
        _rewrite(good, dst, _edit_state(edit))
    with pytest.raises(ValueError) as info:
        load_session(dst)
    msg = str(info.value)
    assert "\n" not in msg and str(dst) in msg and message in msg, msg
    assert not (tmp_path / "pwned").exists()


def test_not_a_session_is_its_own_error(tmp_path):
    for content in (b"", b"hello", b"PK\x03\x04" + bytes(60)):
        p = tmp_path / "x.session"
        p.write_bytes(content)
        with pytest.raises(NotASessionError, match="x.session: not a probmap graph-SLAM session"):
            load_session(p)


def test_saving_a_state_sessions_cannot_hold_names_it(tour, tmp_path):
    _, batch, _ = tour
    run_submap_slam(_part(batch, 0, 20), save_session=tmp_path / "s.session")
    slam = load_session(tmp_path / "s.session")
    slam.loops.planted = object()
    with pytest.raises(TypeError, match="cannot save LoopClosing.planted: a object"):
        save_session(slam, tmp_path / "t.session")
    assert not (tmp_path / "t.session").exists()


# ----------------------------------------------------------------------------- continuity
def test_resume_refuses_overlap_and_skips_the_sessions_own_scans(tour, tmp_path):
    _, batch, whole = tour
    n = len(batch.times)
    path = tmp_path / "s.session"
    run_submap_slam(_part(batch, 0, 100), save_session=path)
    info = read_session_info(path)
    slam = load_session(path)
    # the session's own log: its 100 scans are skipped, the rest continues it exactly
    tail, k = resume_batch(slam, batch, info, log_name="tour.log")
    assert k == 100 and len(tail.times) == n - 100
    _assert_same_run(run_submap_slam(tail, resume=slam), whole)
    # a log overlapping it with other scans: refused
    other = replace(batch, laser_poses=batch.laser_poses + 0.01)
    with pytest.raises(ValueError, match="before the session's last scan .* with other scans"):
        resume_batch(load_session(path), other, info, log_name="other.log")
    # a log inside the session: nothing to add
    with pytest.raises(ValueError, match="holds every scan of early.log already"):
        resume_batch(load_session(path), _part(batch, 0, 60), info, log_name="early.log")
    # the pipeline refuses a batch that does not start after the session
    with pytest.raises(ValueError, match="not after the session's last scan"):
        run_submap_slam(_part(batch, 50, n), resume=load_session(path))


def test_a_gap_after_an_interrupted_session_is_warned(tour, tmp_path):
    log, batch, _ = tour
    from probmap.pipelines.sessions import SessionLog

    path = tmp_path / "s.session"
    asked = [0]

    def stop() -> bool:
        asked[0] += 1
        return asked[0] > 40

    src = SessionLog.of(log, _part(batch, 0, 100))
    run = run_submap_slam(_part(batch, 0, 100), save_session=path, stop=stop, log=src)
    assert run.interrupted
    info = read_session_info(path)
    assert not info.complete and info.log_used == len(run.times) and info.log_scans == 100
    with pytest.warns(SessionGapWarning, match="scans between are missing from the result"):
        _, k = resume_batch(load_session(path), _part(batch, 100, 200), info, log_name="b.log")
    assert k == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the same log continues it: no warning
        _, k = resume_batch(load_session(path), batch, info, log_name="tour.log")
    assert k == len(run.times)


def _ctrl_c_at(monkeypatch, scan: int) -> None:
    """SIGINT (Ctrl-C) while the ``scan``-th scan of the command is processed."""
    from probmap.slam.laser.submap_slam import SubmapSlam

    real = SubmapSlam.add_scan
    calls = [0]

    def add_scan(self, *args, **kwargs):
        calls[0] += 1
        if calls[0] == scan:
            signal.raise_signal(signal.SIGINT)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(SubmapSlam, "add_scan", add_scan)


def test_ctrl_c_during_resume_into_the_same_session_loses_and_duplicates_nothing(
    tour, tmp_path, monkeypatch
):
    """The issue's case: --resume S --save-session S stopped by Ctrl-C, then resumed again
    with the same log: the trajectory is the whole log's, row for row (before, 116 scans
    came twice)."""
    log, _, _ = tour
    lines = log.read_text().splitlines()
    head, scans = lines[:1], lines[1:]
    h = len(scans) // 2
    a, b = tmp_path / "a.log", tmp_path / "b.log"
    a.write_text("\n".join(head + scans[:h]) + "\n")
    b.write_text("\n".join(head + scans[h:]) + "\n")
    runner = CliRunner()
    assert runner.invoke(app, ["slam", "grid", str(log), "-o", str(tmp_path / "w")]).exit_code == 0
    s = tmp_path / "s.session"
    first = runner.invoke(app, ["slam", "grid", str(a), "-o", str(tmp_path / "a"),
                                "--save-session", str(s)])  # fmt: skip
    assert first.exit_code == 0, first.output
    with monkeypatch.context() as m:
        _ctrl_c_at(m, 30)
        cut = runner.invoke(app, ["slam", "grid", str(b), "-o", str(tmp_path / "b1"),
                                  "--resume", str(s), "--save-session", str(s)])  # fmt: skip
    assert cut.exit_code == 130, cut.output
    info = read_session_info(s)
    assert not info.complete and info.scans == h + 30 and info.log_used == 30
    again = runner.invoke(app, ["slam", "grid", str(b), "-o", str(tmp_path / "b2"),
                                "--resume", str(s)])  # fmt: skip
    assert again.exit_code == 0, again.output
    assert "the first 30 of this log among them" in again.output
    assert (tmp_path / "b2.trajectory.csv").read_text() == (
        tmp_path / "w.trajectory.csv"
    ).read_text()
    # a later log after the interrupted session: the scans between them are missing, said so
    c = tmp_path / "c.log"
    c.write_text("\n".join(head + scans[h + 60 :]) + "\n")
    gap = runner.invoke(app, ["slam", "grid", str(c), "-o", str(tmp_path / "c"),
                              "--resume", str(s)])  # fmt: skip
    assert gap.exit_code == 0, gap.output
    warned = [x for x in gap.output.splitlines() if x.startswith("warning:")]
    assert len(warned) == 1 and "84 scans before the end of its log b.log" in warned[0], warned
    assert "c.log starts at t = 34.800 s: the scans between are missing" in warned[0]


def test_an_interrupted_save_leaves_the_old_session_as_it_was(tour, tmp_path, monkeypatch):
    _, batch, _ = tour
    path = tmp_path / "s.session"
    run_submap_slam(_part(batch, 0, 40), save_session=path)
    before = path.read_bytes()
    slam = load_session(path)
    for i in range(40, 60):
        slam.add_scan(batch.times[i], batch.ranges[i], batch.angles, batch.laser_poses[i])
    real = np.lib.format.write_array
    calls = [0]

    def write_array(*args, **kwargs):
        calls[0] += 1
        if calls[0] == 5:
            raise KeyboardInterrupt  # Ctrl-C in the middle of the archive
        return real(*args, **kwargs)

    monkeypatch.setattr(np.lib.format, "write_array", write_array)
    with pytest.raises(KeyboardInterrupt):
        save_session(slam, path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.session"]  # no temporary left


def test_localize_in_a_folder_names_the_session_it_read(tour, tmp_path):
    """``localize FOLDER``: the folder's slam.session is data (nothing in it runs), and the
    summary names the file that was read, not only the folder."""
    log, batch, _ = tour
    folder = tmp_path / "maps"
    folder.mkdir()
    run_submap_slam(batch, save_session=folder / "slam.session")
    res = CliRunner().invoke(
        app,
        ["localize", str(folder), str(log), "-o", str(tmp_path / "loc"), "-n", "200"],
        env={"COLUMNS": "400"},  # the whole path in the summary table
    )
    assert res.exit_code == 0, res.output
    assert f"{folder / 'slam.session'} (session" in " ".join(res.output.split())


def test_a_lidar_only_session_resumes_to_exactly_the_whole_run(tour, tmp_path):
    """Without odometry the run's motion model (last pose, velocity, step, score level) is
    state too; a resume continues without odometry, and refuses a request for it."""
    _, batch, _ = tour
    n = len(batch.times)
    whole = run_submap_slam(batch, odometry=False)
    path = tmp_path / "s.session"
    run_submap_slam(_part(batch, 0, n // 2), save_session=path, odometry=False)
    slam = load_session(path)
    assert slam.lidar_only
    with pytest.raises(ValueError, match="ran without odometry"):
        run_submap_slam(_part(batch, n // 2, n), resume=load_session(path), odometry=True)
    _assert_same_run(run_submap_slam(_part(batch, n // 2, n), resume=slam), whole)
