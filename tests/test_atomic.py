"""Atomic writes: all or nothing, the old file intact until the rename, errors naming the path."""

from __future__ import annotations

import os
import stat

import pytest

from probmap._atomic import atomic_files, atomic_outputs, atomic_path, atomic_save, atomic_write


def test_write_creates_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "out.bin"
    with atomic_write(target) as f:
        f.write(b"abc")
        f.write(b"def")
        assert not target.exists()  # nothing visible before the rename
    assert target.read_bytes() == b"abcdef"
    assert os.listdir(tmp_path) == ["out.bin"]


def test_old_content_survives_until_commit_and_on_failure(tmp_path):
    target = tmp_path / "map.yaml"
    target.write_text("old\n")
    with pytest.raises(RuntimeError, match="midway"):
        with atomic_write(target, "w") as f:
            f.write("new, half written")
            assert target.read_text() == "old\n"
            raise RuntimeError("writer failed midway")
    assert target.read_text() == "old\n"
    assert os.listdir(tmp_path) == ["map.yaml"]
    with atomic_write(target, "w") as f:
        f.write("new\n")
        assert target.read_text() == "old\n"
    assert target.read_text() == "new\n"


def test_failed_first_write_leaves_no_file(tmp_path):
    target = tmp_path / "never.npz"

    def writer(f):
        f.write(b"x" * 1000)
        raise KeyboardInterrupt  # even an interrupt must not leave a truncated file

    with pytest.raises(KeyboardInterrupt):
        atomic_save(target, writer)
    assert os.listdir(tmp_path) == []


def test_text_mode_and_encoding(tmp_path):
    target = tmp_path / "t.txt"
    with atomic_write(target, "w", encoding="latin-1") as f:
        f.write("d\u00e9j\u00e0 vu\n")
    assert target.read_bytes() == "d\u00e9j\u00e0 vu\n".encode("latin-1")
    assert atomic_save(tmp_path / "u.txt", lambda f: f.write("\u00e9"), mode="w").read_bytes() == (
        "\u00e9".encode()
    )


def test_permissions_follow_the_umask_like_open(tmp_path):
    plain = tmp_path / "plain"
    plain.write_bytes(b"")
    target = atomic_save(tmp_path / "atomic", lambda f: f.write(b""))
    assert stat.S_IMODE(target.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode)


def test_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="mode"):
        with atomic_write(tmp_path / "a", "a"):
            pass
    with pytest.raises(ValueError, match="encoding"):
        with atomic_write(tmp_path / "a", "wb", encoding="utf-8"):
            pass
    with pytest.raises(ValueError, match="duplicate"):
        with atomic_files([tmp_path / "a", tmp_path / "a"]):
            pass
    assert os.listdir(tmp_path) == []


def test_missing_or_unusable_folder_names_the_path(tmp_path):
    target = tmp_path / "no" / "such" / "folder" / "m.pgm"
    with pytest.raises(FileNotFoundError) as info:
        atomic_save(target, lambda f: f.write(b"x"))
    assert str(target) in str(info.value)
    afile = tmp_path / "afile"
    afile.write_bytes(b"")
    with pytest.raises(NotADirectoryError, match="afile"):
        atomic_save(afile / "m.pgm", lambda f: f.write(b"x"))


def test_unwritable_folder_names_the_path(read_only_dir):
    with pytest.raises(PermissionError, match="ro/m.pgm"):
        atomic_save(read_only_dir / "m.pgm", lambda f: f.write(b"x"))


def test_group_is_all_or_nothing(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    b.write_bytes(b"old b")
    with pytest.raises(OSError, match="second writer"):
        with atomic_files([a, b, c]) as (fa, fb, fc):
            fa.write(b"new a")
            fb.write(b"new b")
            raise OSError("second writer failed")
    assert sorted(os.listdir(tmp_path)) == ["b"] and b.read_bytes() == b"old b"
    with atomic_files([a, b, c]) as (fa, fb, fc):
        fa.write(b"1")
        fb.write(b"2")
        fc.write(b"3")
    assert [p.read_bytes() for p in (a, b, c)] == [b"1", b"2", b"3"]
    assert sorted(os.listdir(tmp_path)) == ["a", "b", "c"]


def test_group_into_a_missing_folder_creates_nothing(tmp_path):
    good = tmp_path / "good"
    with pytest.raises(FileNotFoundError, match="missing"):
        with atomic_files([good, tmp_path / "missing" / "x"]):
            pass
    assert os.listdir(tmp_path) == []


def test_path_writer_gets_the_target_name_and_the_old_file_survives_failure(tmp_path):
    target = tmp_path / "plot.png"
    target.write_bytes(b"old")
    with atomic_path(target) as tmp:
        assert tmp.name == "plot.png" and tmp.parent.parent == tmp_path
        tmp.write_bytes(b"new")
        assert target.read_bytes() == b"old"
    assert target.read_bytes() == b"new"
    assert os.listdir(tmp_path) == ["plot.png"]
    with pytest.raises(RuntimeError, match="midway"):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("writer failed midway")
    assert target.read_bytes() == b"new"
    assert os.listdir(tmp_path) == ["plot.png"]


def test_path_writer_may_write_a_folder(tmp_path):
    target = tmp_path / "bag"
    with atomic_path(target) as tmp:
        tmp.mkdir()
        (tmp / "bag.mcap").write_bytes(b"x")
        (tmp / "metadata.yaml").write_text("y")
    assert sorted(os.listdir(target)) == ["bag.mcap", "metadata.yaml"]
    assert os.listdir(tmp_path) == ["bag"]


def test_path_writer_that_writes_nothing_or_cannot_write(tmp_path):
    with pytest.raises(FileNotFoundError, match="created no file"):
        with atomic_path(tmp_path / "x.csv"):
            pass
    assert os.listdir(tmp_path) == []
    target = tmp_path / "missing" / "x.csv"
    with pytest.raises(FileNotFoundError) as info:
        with atomic_path(target):
            pass
    assert str(target) in str(info.value)


def test_path_writer_permissions_follow_the_umask_like_open(tmp_path):
    plain = tmp_path / "plain"
    plain.write_bytes(b"")
    with atomic_path(tmp_path / "atomic") as tmp:
        tmp.write_bytes(b"")
    assert stat.S_IMODE((tmp_path / "atomic").stat().st_mode) == stat.S_IMODE(plain.stat().st_mode)


# ----------------------------------------------------------------------------- output sets
def test_output_set_commits_together_and_creates_the_folder(tmp_path):
    out = tmp_path / "new" / "run"
    with atomic_outputs() as outputs:
        atomic_save(out / "a.csv", lambda f: f.write(b"a"))
        with atomic_path(out / "b.png") as tmp:
            tmp.write_bytes(b"b")
        with atomic_outputs():  # a nested block joins the outer one
            atomic_save(out / "c.json", lambda f: f.write(b"c"))
        assert not (out / "a.csv").exists() and not (out / "b.png").exists()
        assert outputs.targets == [out / "a.csv", out / "b.png", out / "c.json"]
    assert sorted(os.listdir(out)) == ["a.csv", "b.png", "c.json"]
    assert (out / "b.png").read_bytes() == b"b"
    assert stat.S_IMODE(out.stat().st_mode) == 0o777 & ~_umask()
    for name in ("a.csv", "b.png", "c.json"):
        assert stat.S_IMODE((out / name).stat().st_mode) == 0o666 & ~_umask()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@pytest.mark.parametrize("error", [OSError("disk full"), KeyboardInterrupt()])
def test_output_set_failure_leaves_nothing_and_removes_created_folders(tmp_path, error):
    old = tmp_path / "old.csv"
    old.write_bytes(b"old")
    out = tmp_path / "new" / "run"
    with pytest.raises(type(error)):
        with atomic_outputs():
            atomic_save(out / "a.csv", lambda f: f.write(b"a"))
            atomic_save(old, lambda f: f.write(b"new"))
            with atomic_path(out / "b.png") as tmp:
                tmp.write_bytes(b"half")
                raise error
    assert sorted(os.listdir(tmp_path)) == ["old.csv"] and old.read_bytes() == b"old"


def test_output_set_writer_error_names_the_target(tmp_path):
    def full(f):
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match=r"cannot write .*x\.yaml: No space left"):
        with atomic_outputs():
            atomic_save(tmp_path / "x.yaml", full)
    assert os.listdir(tmp_path) == []


def test_output_set_failed_rename_puts_every_target_back(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.png"
    a.write_bytes(b"old a")
    b.mkdir()  # a folder where a file should go: the last rename cannot happen
    (b / "keep").write_bytes(b"k")
    with pytest.raises(IsADirectoryError, match="b.png"):
        with atomic_outputs():
            atomic_save(tmp_path / "new.txt", lambda f: f.write(b"n"))
            atomic_save(a, lambda f: f.write(b"new a"))
            atomic_save(b, lambda f: f.write(b"new b"))
    assert sorted(os.listdir(tmp_path)) == ["a.csv", "b.png"] and a.read_bytes() == b"old a"
    assert os.listdir(b) == ["keep"]


def test_output_set_folder_and_not_a_folder(tmp_path):
    afile = tmp_path / "afile"
    afile.write_bytes(b"")
    with pytest.raises(NotADirectoryError, match="afile is not a folder"):
        with atomic_outputs():
            atomic_save(afile / "sub" / "x", lambda f: f.write(b"x"))
    with pytest.raises(RuntimeError):
        with atomic_outputs() as outputs:
            assert outputs.folder(tmp_path / "d" / "e").is_dir()
            raise RuntimeError
    assert sorted(os.listdir(tmp_path)) == ["afile"]


def test_outside_an_output_set_a_missing_folder_is_still_an_error(tmp_path):
    with pytest.raises(FileNotFoundError):
        atomic_save(tmp_path / "missing" / "x", lambda f: f.write(b"x"))
    assert os.listdir(tmp_path) == []


def test_output_set_rename_failing_midway_is_rolled_back(tmp_path, monkeypatch):
    import probmap._atomic as mod

    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    b.write_bytes(b"old b")
    real = os.replace
    calls = []

    def flaky(src, dst):
        calls.append(dst)
        if len(calls) == 3 and str(dst) == str(c):
            raise OSError(5, "Input/output error")
        return real(src, dst)

    monkeypatch.setattr(mod.os, "replace", flaky)
    with pytest.raises(OSError, match="Input/output"):
        with atomic_outputs():
            for p in (a, b, c):
                atomic_save(p, lambda f: f.write(b"new"))
    assert sorted(os.listdir(tmp_path)) == ["b"] and b.read_bytes() == b"old b"
