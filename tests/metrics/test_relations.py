"""The relation metric: closed forms on synthetic trajectories, the Intel raw-odometry baseline."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.datasets.protocol import DatasetError
from probmap.geometry.se2 import between, compose
from probmap.metrics.relations import (
    Relations,
    read_relations,
    read_trajectory,
    relation_errors,
)


def random_trajectory(rng, n=50):
    steps = np.column_stack([rng.uniform(0, 1, n), rng.normal(0, 0.1, n), rng.normal(0, 0.3, n)])
    poses = [np.zeros(3)]
    for s in steps[1:]:
        poses.append(compose(poses[-1], s))
    return np.arange(n, dtype=float) * 0.5 + 100.0, np.asarray(poses)


def test_exact_trajectory_has_zero_error():
    rng = np.random.default_rng(0)
    t, x = random_trajectory(rng)
    i, j = rng.integers(0, 50, 40), rng.integers(0, 50, 40)
    rel = Relations(t[i], t[j], between(x[i], x[j]))
    e = relation_errors(t, x, rel)
    assert e.translation.max() < 1e-12 and e.rotation.max() < 1e-12
    # the metric is invariant to a rigid motion of the whole estimate
    moved = compose(np.array([3.0, -2.0, 1.1]), x)
    e2 = relation_errors(t, moved, rel)
    assert e2.translation.max() < 1e-9 and e2.rotation.max() < 1e-9


def test_known_perturbation_closed_form():
    t = np.array([0.0, 1.0, 2.0])
    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, np.pi / 2], [1.0, 1.0, np.pi / 2]])
    # reference says the second pose is 0.1 m further ahead and turned 0.05 rad less
    rel = Relations(np.array([0.0]), np.array([1.0]), np.array([[1.1, 0.0, np.pi / 2 - 0.05]]))
    e = relation_errors(t, x, rel)
    # e = ref^-1 (+) est: rotate (-0.1, 0) by -(pi/2 - 0.05): length 0.1, angle 0.05
    assert e.translation[0] == pytest.approx(0.1, abs=1e-12)
    assert e.rotation[0] == pytest.approx(0.05, abs=1e-12)
    s = e.summary()
    assert s["trans_sq_mean_m2"] == pytest.approx(0.01)
    assert s["rot_abs_mean_deg"] == pytest.approx(np.degrees(0.05))


def test_timestamps_out_of_tolerance_are_counted():
    t = np.array([0.0, 1.0, 2.0])
    x = np.zeros((3, 3))
    rel = Relations(np.array([0.0, 0.0]), np.array([1.0005, 1.5]), np.zeros((2, 3)))
    e = relation_errors(t, x, rel, tolerance=1e-3)
    assert e.used.tolist() == [True, False] and e.missing == 1
    with pytest.raises(ValueError, match="no relation timestamp"):
        relation_errors(t + 10, x, rel)


def test_bad_files(tmp_path):
    bad = tmp_path / "bad.relations"
    bad.write_text("1 2 0 0 0 0 0 0\n1 2 x 0 0 0 0 0\n")
    with pytest.raises(DatasetError, match=r"bad.relations, line 2"):
        read_relations(bad)
    (tmp_path / "empty.relations").write_text("# nothing\n")
    with pytest.raises(DatasetError, match="no relations"):
        read_relations(tmp_path / "empty.relations")
    csv = tmp_path / "t.csv"
    csv.write_text("time,x,y\n0,0,0\n")
    with pytest.raises(DatasetError, match="theta"):
        read_trajectory(csv)


def test_cli_on_csv(tmp_path):
    from probmap.cli import register
    from probmap.cli.app import app

    register(app)
    rng = np.random.default_rng(1)
    t, x = random_trajectory(rng, 20)
    csv = tmp_path / "trajectory.csv"
    csv.write_text(
        "time,x,y,theta\n"
        + "".join(f"{a},{b},{c},{d}\n" for a, (b, c, d) in zip(t, x, strict=True))
    )
    ref = between(x[:-1], x[1:]) + np.array([0.0, 0.02, 0.0])
    rel = tmp_path / "r.relations"
    rel.write_text(
        "".join(
            f"{a} {b} {d[0]} {d[1]} 0 0 0 {d[2]}\n"
            for a, b, d in zip(t[:-1], t[1:], ref, strict=True)
        )
    )
    out = tmp_path / "m.json"
    res = CliRunner().invoke(app, ["evaluate", "relations", str(csv), str(rel), "-o", str(out)])
    assert res.exit_code == 0, res.output
    s = json.loads(out.read_text())
    assert s["relations"] == 19 and s["trans_abs_mean_m"] == pytest.approx(0.02, abs=1e-9)


def test_intel_raw_odometry_baseline(shared_data):
    """Reproduces the data README's baseline: 7.370 +/- 14.349 m, 260.2 m^2, 39.17 +/- 53.79 deg."""
    log = shared_data("intel-research-lab/intel.clf.bz2")
    rel = read_relations(shared_data("intel-research-lab/intel.relations"))
    t, x = read_trajectory(log, poses="robot")
    s = relation_errors(t, x, rel).summary()
    print(s)
    assert s["relations"] == 2984 and s["missing"] == 0
    assert s["trans_abs_mean_m"] == pytest.approx(7.370, abs=5e-4)
    assert s["trans_abs_std_m"] == pytest.approx(14.349, abs=5e-4)
    assert s["trans_sq_mean_m2"] == pytest.approx(260.2, abs=0.05)
    assert s["rot_abs_mean_deg"] == pytest.approx(39.17, abs=5e-3)
    assert s["rot_abs_std_deg"] == pytest.approx(53.79, abs=5e-3)
