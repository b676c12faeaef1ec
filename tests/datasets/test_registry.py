import numpy as np
import pytest

from probmap.datasets import registry
from probmap.datasets.protocol import DatasetError
from probmap.datasets.simulation import LandmarkSimulation


def test_guess_format(tmp_path):
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "Barcodes.dat").write_text("")
    (tmp_path / "v").mkdir()
    for f in ("measurements.dat", "inputs.dat"):
        (tmp_path / "v" / f).write_text("")
    for name in ("a.g2o", "b.clf.bz2", "c.log.gz", "d.txt"):
        (tmp_path / name).write_text("")
    assert registry.guess_format(tmp_path / "m") == "mrclam"
    assert registry.guess_format(tmp_path / "v") == "victoria-park"
    assert registry.guess_format(tmp_path / "a.g2o") == "g2o"
    assert registry.guess_format(tmp_path / "b.clf.bz2") == "carmen"
    assert registry.guess_format(tmp_path / "c.log.gz") == "carmen"
    with pytest.raises(DatasetError, match="d.txt"):
        registry.guess_format(tmp_path / "d.txt")
    with pytest.raises(DatasetError, match="no such file"):
        registry.guess_format(tmp_path / "nope")


def test_names_need_a_data_dir(monkeypatch, tmp_path):
    monkeypatch.delenv("PROBMAP_DATA", raising=False)
    monkeypatch.chdir(tmp_path)  # no ../shared/data beside it
    assert registry.data_dir() is None
    with pytest.raises(DatasetError, match="PROBMAP_DATA"):
        registry.load("victoria-park")
    with pytest.raises(DatasetError, match="not found"):
        registry.load("victoria-park", data_directory=tmp_path)
    assert registry.data_dir(tmp_path) == tmp_path
    monkeypatch.setenv("PROBMAP_DATA", str(tmp_path))
    assert registry.data_dir() == tmp_path


def test_every_entry_has_a_loader():
    for info in registry.DATASETS.values():
        assert info.format in registry.FORMATS
    assert "carmen" in registry.FORMATS and "intel" in registry.DATASETS


def test_simulation_by_name():
    sim = registry.load("simulation", n_landmarks=10, n_steps=5, seed=3)
    assert isinstance(sim, LandmarkSimulation) and len(sim) == 5
    again = registry.load("simulation", n_landmarks=10, n_steps=5, seed=3)
    assert np.array_equal(sim.landmarks_xy, again.landmarks_xy)


@pytest.mark.realdata
def test_load_real_by_name_and_path(shared_data):
    root = shared_data("victoria-park").parent
    g = registry.load("victoria-park-g2o", data_directory=root)
    assert len(g.landmarks) == 151
    ds = registry.load(str(root / "utias-mrclam" / "MRCLAM_Dataset7"), robot=2, end_time=5.0)
    assert ds.robot == 2 and len(ds) > 0
    log = registry.load("intel-corrected", data_directory=root)
    assert len(log) > 0


def test_the_data_dir_falls_back_to_shared_data(monkeypatch, tmp_path):
    """Without PROBMAP_DATA: ../shared/data relative to the working directory, if present."""
    monkeypatch.delenv("PROBMAP_DATA", raising=False)
    (tmp_path / "shared" / "data").mkdir(parents=True)
    (tmp_path / "clone").mkdir()
    monkeypatch.chdir(tmp_path / "clone")
    assert registry.data_dir() == registry.DEFAULT_DATA
    assert registry.data_dir().resolve() == (tmp_path / "shared" / "data").resolve()
    monkeypatch.setenv("PROBMAP_DATA", str(tmp_path))
    assert registry.data_dir() == tmp_path  # the variable wins
