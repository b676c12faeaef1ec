"""The output rule every command shares (probmap.pipelines.outputs): check, create nothing."""

from __future__ import annotations

import os

import pytest

from probmap.pipelines.outputs import check_output_folder, check_output_prefix


def test_prefix_in_an_existing_folder_is_kept(tmp_path):
    assert check_output_prefix(tmp_path / "intel") == tmp_path / "intel"


def test_existing_folder_or_trailing_separator_means_default_name(tmp_path):
    assert check_output_prefix(tmp_path, "map") == tmp_path / "map"
    missing = os.fspath(tmp_path / "new") + os.sep
    assert check_output_prefix(missing, "map") == tmp_path / "new" / "map"
    assert not (tmp_path / "new").exists()  # nothing is created


def test_folder_without_default_name_is_refused(tmp_path):
    with pytest.raises(ValueError, match="needs a file name part"):
        check_output_prefix(tmp_path)


def test_missing_parents_are_fine_and_not_created(tmp_path):
    p = tmp_path / "a" / "b" / "map"
    assert check_output_prefix(p) == p
    assert check_output_folder(tmp_path / "x" / "y") == tmp_path / "x" / "y"
    assert list(tmp_path.iterdir()) == []


def test_a_file_in_the_way_is_named(tmp_path):
    f = tmp_path / "file.txt"
    f.write_text("x")
    with pytest.raises(NotADirectoryError, match="file.txt exists and is not a folder"):
        check_output_folder(f)
    with pytest.raises(NotADirectoryError, match="file.txt exists and is not a folder"):
        check_output_prefix(f / "sub" / "map")


def test_unwritable_folder_is_refused(read_only_dir):
    with pytest.raises(PermissionError, match="is not writable"):
        check_output_prefix(read_only_dir / "map")
    with pytest.raises(PermissionError, match="is not writable"):
        check_output_folder(read_only_dir / "out")
