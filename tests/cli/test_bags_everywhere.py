"""A ROS 2 bag works wherever a CARMEN log does: every command that reads a laser log, run on
the simulated tour as a CARMEN log and on the same scans written as a ROS 2 bag, prints the same
summary rows and writes the same outputs. Also: dataset names and the missing ``ros`` extra on
the command line.

A bag stores ranges and beam angles as float32, as every ROS laser message does; the CARMEN log
is written with those same float32 numbers (``ROBOTLASER1`` lines carry the beam geometry), so
that the two inputs hold the same scans and every command must give the same answer (graph
SLAM's closure decisions would otherwise flip on differences of 1e-7 m).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")

from typer.testing import CliRunner  # noqa: E402

from bagwriter import write_log_and_bag  # noqa: E402
from probmap.cli import register  # noqa: E402
from probmap.cli.app import app  # noqa: E402
from probmap.cli.common import print_summary as PRINT_SUMMARY  # noqa: E402

register(app)
runner = CliRunner()

#: Rows that hold times, paths or the machine's memory: not the input's doing.
VARYING = {"time", "wrote", "peak memory", "optimization", "map tiles", "recorded"}


@pytest.fixture
def tour(sim_log, tmp_path):
    """``(log, bag)``: the simulated tour as a CARMEN log and as a ROS 2 bag folder holding the
    same numbers (:func:`bagwriter.write_float32_log`)."""
    return write_log_and_bag(sim_log(tmp_path / "sim.log"), tmp_path / "tour.log", ros=2)


def run(monkeypatch, module: str, *args: object) -> list[tuple[str, str]]:
    """Run ``probmap ARGS``; return the summary rows it printed (those of ``module``)."""
    import importlib

    import probmap.cli.common as common

    rows: list[tuple[str, str]] = []

    def capture(title, items, **kw):
        items = list(items)
        rows.extend(items)
        PRINT_SUMMARY(title, items, **kw)

    # commands import print_summary at the top of their module or inside the command
    monkeypatch.setattr(importlib.import_module(module), "print_summary", capture, raising=False)
    monkeypatch.setattr(common, "print_summary", capture)
    res = runner.invoke(app, [str(a) for a in args])
    assert res.exit_code == 0, res.output
    return rows


def same_rows(a: list[tuple[str, str]], b: list[tuple[str, str]], readings: bool = True) -> None:
    keep_a = [r for r in a if r[0] not in VARYING]
    keep_b = [r for r in b if r[0] not in VARYING]
    assert keep_a == keep_b
    assert len(keep_a) >= 3
    assert not readings or any(name == "readings" for name, _ in keep_a)


def same_map(a: Path, b: Path, *, cells: float = 0.0) -> None:
    """Two maps' probabilities agree everywhere but in at most a fraction ``cells`` of cells."""
    from probmap.grid.io import load_npz

    ga, gb = load_npz(a), load_npz(b)
    assert ga.spec == gb.spec
    pa, pb = ga.probability(), gb.probability()
    differ = np.count_nonzero(~np.isclose(pa, pb, atol=1e-6, equal_nan=True))
    assert differ <= cells * pa.size, (differ, pa.size)


def test_map(monkeypatch, tour, tmp_path):
    log, bag = tour
    a = run(monkeypatch, "probmap.cli.mapping", "map", log, "-o", tmp_path / "a", "-r", "0.1")
    b = run(monkeypatch, "probmap.cli.mapping", "map", bag, "-o", tmp_path / "b", "-r", "0.1")
    same_rows(a, b)
    same_map(tmp_path / "a.npz", tmp_path / "b.npz")
    assert (tmp_path / "b.plot.png").is_file()


def test_map_with_workers(monkeypatch, tour, tmp_path):
    pytest.importorskip("distributed")
    log, bag = tour
    args = ("-r", "0.1", "--workers", "1", "--chunks", "1")
    a = run(monkeypatch, "probmap.cli.distributed", "map", log, log, "-o", tmp_path / "a", *args)
    b = run(monkeypatch, "probmap.cli.distributed", "map", bag, bag, "-o", tmp_path / "b", *args)
    # (the distributed summary has no readings row: its tasks return counts, not reports)
    same_rows(a, b, readings=False)
    same_map(tmp_path / "a.npz", tmp_path / "b.npz")


def test_map_method_map(monkeypatch, tour, tmp_path):
    log, bag = tour
    args = ("-r", "0.2", "--method", "map")
    a = run(monkeypatch, "probmap.cli.map_mapping", "map", log, "-o", tmp_path / "a", *args)
    b = run(monkeypatch, "probmap.cli.map_mapping", "map", bag, "-o", tmp_path / "b", *args)
    same_rows(a, b)
    same_map(tmp_path / "a.npz", tmp_path / "b.npz")


def test_fit_sensor_model(monkeypatch, tour, tmp_path):
    import yaml

    log, bag = tour
    args = ("-r", "0.1", "--every", "4")
    a = run(monkeypatch, "probmap.cli.map_mapping", "fit-sensor-model", log, "-o", tmp_path / "a.yaml", *args)  # fmt: skip
    b = run(monkeypatch, "probmap.cli.map_mapping", "fit-sensor-model", bag, "-o", tmp_path / "b.yaml", *args)  # fmt: skip
    assert [r[0] for r in a] == [r[0] for r in b]
    fit_a = yaml.safe_load((tmp_path / "a.yaml").read_text())["beam_model"]
    fit_b = yaml.safe_load((tmp_path / "b.yaml").read_text())["beam_model"]
    assert fit_a == pytest.approx(fit_b, rel=1e-4, abs=1e-6)
    assert dict(a)["readings"] == dict(b)["readings"]


def test_match(monkeypatch, tour, tmp_path):
    log, bag = tour
    run(monkeypatch, "probmap.cli.mapping", "map", log, "-o", tmp_path / "m", "-r", "0.05")
    args = ("--scan", "40", "--x", "0.05")
    a = run(monkeypatch, "probmap.cli.laser_slam", "match", tmp_path / "m.npz", log, *args)
    b = run(monkeypatch, "probmap.cli.laser_slam", "match", tmp_path / "m.npz", bag, *args)
    same_rows(a, b)


def test_localize(monkeypatch, tour, tmp_path):
    log, bag = tour
    run(monkeypatch, "probmap.cli.mapping", "map", log, "-o", tmp_path / "m", "-r", "0.1")
    args = ("-n", "200", "--stop", "120", "--reference", log)
    m = tmp_path / "m.yaml"
    a = run(monkeypatch, "probmap.cli.localize", "localize", m, log, "-o", tmp_path / "a", *args)
    b = run(monkeypatch, "probmap.cli.localize", "localize", m, bag, "-o", tmp_path / "b", *args)
    same_rows(a, b)
    ta = np.loadtxt(tmp_path / "a" / "trajectory.csv", delimiter=",", skiprows=1)
    tb = np.loadtxt(tmp_path / "b" / "trajectory.csv", delimiter=",", skiprows=1)
    assert ta.shape == tb.shape
    np.testing.assert_allclose(ta[:, :3], tb[:, :3], atol=1e-3)
    # the bag is a reference too
    c = run(
        monkeypatch, "probmap.cli.localize", "localize", m, log, "-o", tmp_path / "c",
        "-n", "200", "--stop", "120", "--reference", bag,
    )  # fmt: skip
    same_rows(a, c)


def test_slam_grid_graph(monkeypatch, tour, tmp_path):
    log, bag = tour
    a = run(monkeypatch, "probmap.cli.laser_slam", "slam", "grid", log, "-o", tmp_path / "a")
    b = run(monkeypatch, "probmap.cli.laser_slam", "slam", "grid", bag, "-o", tmp_path / "b")
    same_rows(a, b)
    ta = np.loadtxt(tmp_path / "a.trajectory.csv", delimiter=",", skiprows=1)
    tb = np.loadtxt(tmp_path / "b.trajectory.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(ta[:, :3], tb[:, :3], atol=1e-3)


def test_slam_grid_rbpf(monkeypatch, tour, tmp_path):
    log, bag = tour
    args = ("--method", "rbpf", "-n", "5")
    a = run(monkeypatch, "probmap.cli.laser_slam", "slam", "grid", log, "-o", tmp_path / "a", *args)
    b = run(monkeypatch, "probmap.cli.laser_slam", "slam", "grid", bag, "-o", tmp_path / "b", *args)
    same_rows(a, b)
    ta = np.loadtxt(tmp_path / "a.trajectory.csv", delimiter=",", skiprows=1)
    tb = np.loadtxt(tmp_path / "b.trajectory.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(ta[:, :3], tb[:, :3], atol=1e-3)


# ------------------------------------------------------------------ names and the missing extra


def test_dataset_names_work_where_paths_do(shared_data, monkeypatch, tmp_path):
    corrected = shared_data("intel-research-lab/intel-corrected.log.gz")
    monkeypatch.setenv("PROBMAP_DATA", str(corrected.parents[1]))
    a = run(monkeypatch, "probmap.cli.mapping", "map", "intel-corrected", "-o", tmp_path / "a")
    b = run(monkeypatch, "probmap.cli.mapping", "map", corrected, "-o", tmp_path / "b")
    same_rows(a, b)
    res = runner.invoke(app, ["map", "intel-corected", "-o", str(tmp_path / "c")])
    assert res.exit_code == 1
    assert res.output.strip().splitlines() == [
        "error: intel-corected: no such file or dataset name (close dataset names: intel-corrected)"
    ]


@pytest.mark.parametrize(
    "args",
    [
        ["info", "{bag}"],
        ["map", "{bag}", "-o", "{out}/m"],
        ["slam", "grid", "{bag}", "-o", "{out}/s"],
        ["fit-sensor-model", "{bag}"],
        ["localize", "{out}/map.yaml", "{bag}", "-o", "{out}/l"],
    ],
    ids=lambda args: args[0],
)
def test_a_bag_without_the_ros_extra_is_one_line(monkeypatch, tour, tmp_path, args):
    log, bag = tour
    if args[0] == "localize":
        run(monkeypatch, "probmap.cli.mapping", "map", log, "-o", tmp_path / "map", "-r", "0.2")
    monkeypatch.setitem(sys.modules, "rosbags", None)  # import rosbags -> ImportError
    res = runner.invoke(app, [a.format(bag=bag, out=tmp_path) for a in args])
    assert res.exit_code == 1, res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.output, res.output
    assert lines[0].startswith("error: ") and "pip install 'probmap[ros]'" in lines[0]
