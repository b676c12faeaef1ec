"""The argument rules every reader shares (``validate.check_end_time``, ``dataset_directory``):
each entry point must give the same verdict and the same message for the same value."""

import math

import pytest

from probmap.datasets.scans import open_scans
from probmap.datasets.utias import MRCLAM
from probmap.datasets.validate import check_end_time, dataset_directory
from probmap.datasets.victoria_park import VictoriaPark
from probmap.errors import DatasetError

BAD_END_TIMES = [0.0, -1.0, math.nan, math.inf, -math.inf]


def _readers(folder):
    """Each reader that takes ``end_time``, called on ``folder`` (which holds no data: the
    arguments are checked before any file is read)."""
    return {
        "open_scans": lambda t: open_scans(folder / "missing.clf", end_time=t),
        "MRCLAM": lambda t: MRCLAM(folder, 1, end_time=t),
        "VictoriaPark": lambda t: VictoriaPark(folder, end_time=t),
    }


@pytest.mark.parametrize("end_time", BAD_END_TIMES)
def test_every_reader_refuses_a_bad_end_time_alike(tmp_path, end_time):
    expected = f"end_time must be a positive number of seconds, got {end_time}"
    with pytest.raises(ValueError) as direct:
        check_end_time(end_time)
    assert str(direct.value) == expected
    for name, read in _readers(tmp_path).items():
        with pytest.raises(ValueError) as err:
            read(end_time)
        assert str(err.value) == expected, name


@pytest.mark.parametrize("end_time", [None, 1e-9, 0.5, 1e9])
def test_a_good_end_time_passes_the_check(tmp_path, end_time):
    check_end_time(end_time)  # returns, raises nothing
    # and the readers go on to the files, which this folder lacks: an error that is no
    # end_time error proves the argument passed
    for name, read in _readers(tmp_path).items():
        with pytest.raises((OSError, DatasetError)) as err:
            read(end_time)
        assert "end_time must" not in str(err.value), name


def test_dataset_directory(tmp_path):
    assert dataset_directory(str(tmp_path)) == tmp_path
    a_file = tmp_path / "log.clf"
    a_file.write_text("")
    for bad in (tmp_path / "missing", a_file):
        with pytest.raises(DatasetError, match="not a directory") as err:
            dataset_directory(bad)
        assert str(bad) in str(err.value)
        with pytest.raises(DatasetError, match="not a directory"):
            MRCLAM(bad, 1)
        with pytest.raises(DatasetError, match="not a directory"):
            VictoriaPark(bad)
