"""CLI: ``--config FILE.yaml`` on semantic, optimize, slam seif, slam compare,
fit-sensor-model and match.

For each command: a file changes the result exactly as the equivalent option does, an option
given on the command line overrides the file, a bad key is one line naming the file and the key
(and nothing is written), and the configuration the command records loads back and reproduces
the run."""

from __future__ import annotations

import importlib.metadata
import json
import re

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.config import load_config

register(app)
runner = CliRunner()


def run(*args):
    # wide enough that rich prints every table cell in full
    return runner.invoke(app, [str(a) for a in args], env={"COLUMNS": "200"})


def ok(*args):
    res = run(*args)
    assert res.exit_code == 0, res.output
    return res


def one_line_error(res, *words):
    assert res.exit_code == 1, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    for w in words:
        assert w in lines[0], (w, lines[0])


def recorded(path, cls):
    """The configuration a command wrote, checked for its provenance lines."""
    text = path.read_text()
    first = text.splitlines()[0]
    assert first.startswith("# command: "), first
    doc = yaml.safe_load(text)
    assert doc["probmap_version"] == importlib.metadata.version("probmap")
    assert doc["config_class"] == cls.__name__
    return load_config(cls, path)


# ----------------------------------------------------------------------------- semantic
@pytest.fixture(scope="module")
def labelled_scans(tmp_path_factory):
    from probmap.grid.semantic_io import LabelledScans, write_labelled_scans
    from probmap.sim.semantic import simulate_labelled_world

    w = simulate_labelled_world(seed=2, size=(8.0, 12.0), step=0.6)
    sc = LabelledScans(w.poses, w.ranges, w.angles, w.max_range, w.classes, labels=w.labels)
    return write_labelled_scans(tmp_path_factory.mktemp("sem") / "scans.npz", sc)


def _semantic_map(prefix):
    from probmap.grid.semantic_io import load_semantic

    return load_semantic(f"{prefix}.npz")


def test_semantic_config(labelled_scans, tmp_path):
    from probmap.pipelines.semantic import SemanticMappingConfig

    ok("semantic", labelled_scans, "-o", tmp_path / "default")
    assert recorded(tmp_path / "default.config.yaml", SemanticMappingConfig) == (
        SemanticMappingConfig()
    )
    ok("semantic", labelled_scans, "-o", tmp_path / "opt", "--p-correct", "0.6", "-r", "0.1")
    cfg_file = tmp_path / "c.yaml"
    cfg_file.write_text("p_correct: 0.6\nresolution: 0.1\n")
    ok("semantic", labelled_scans, "-o", tmp_path / "file", "--config", cfg_file)
    default, by_opt, by_file = (_semantic_map(tmp_path / n) for n in ("default", "opt", "file"))
    assert by_opt.spec.resolution == 0.1 and default.spec.resolution == 0.05
    np.testing.assert_array_equal(by_file.log_odds, by_opt.log_odds)
    # an option overrides the file: back to 5 cm cells, p_correct from the file
    ok("semantic", labelled_scans, "-o", tmp_path / "over", "--config", cfg_file, "-r", "0.05")
    cfg = recorded(tmp_path / "over.config.yaml", SemanticMappingConfig)
    assert cfg == SemanticMappingConfig(p_correct=0.6, resolution=0.05)
    over = _semantic_map(tmp_path / "over")
    assert over.spec.resolution == 0.05
    assert not np.array_equal(over.log_odds, default.log_odds)  # p_correct changed the labels
    # the recorded file reproduces the run
    ok(
        "semantic",
        labelled_scans,
        "-o",
        tmp_path / "again",
        "--config",
        tmp_path / "over.config.yaml",
    )
    np.testing.assert_array_equal(_semantic_map(tmp_path / "again").log_odds, over.log_odds)


def test_semantic_bad_config(labelled_scans, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("p_corect: 0.6\n")
    res = run("semantic", labelled_scans, "-o", tmp_path / "out", "--config", bad)
    one_line_error(res, "bad.yaml", "p_corect", "p_correct?")
    bad.write_text("p_hit: 1.5\n")
    res = run("semantic", labelled_scans, "-o", tmp_path / "out", "--config", bad)
    one_line_error(res, "bad.yaml", "p_hit")
    assert not list(tmp_path.glob("out*"))


# ----------------------------------------------------------------------------- optimize
@pytest.fixture(scope="module")
def square_graph(tmp_path_factory):
    """A square loop of 17 poses with noisy starting poses, one true and one false closure."""
    from probmap.geometry.se2 import between, compose

    truth = np.zeros((17, 3))
    for i in range(16):
        truth[i + 1] = compose(truth[i], [1.0, 0.0, np.pi / 2 if i % 4 == 3 else 0.0])
    edges = [(i, i + 1) for i in range(16)] + [(0, 16), (2, 10)]
    z = [between(truth[i], truth[j]).tolist() for i, j in edges[:-1]] + [[1.0, 0.0, 0.0]]
    start = truth + np.random.default_rng(0).normal(0, 0.1, truth.shape)
    start[0] = truth[0]
    lines = [f"VERTEX_SE2 {n} {p[0]!r} {p[1]!r} {p[2]!r}" for n, p in enumerate(start.tolist())]
    for (i, j), zz in zip(edges, z, strict=True):
        lines.append(f"EDGE_SE2 {i} {j} {zz[0]!r} {zz[1]!r} {zz[2]!r} 100 0 0 100 0 400")
    path = tmp_path_factory.mktemp("graph") / "square.g2o"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_optimize_config(square_graph, tmp_path):
    from probmap.pipelines.optimize import PoseGraphConfig
    from probmap.slam.posegraph.optimize import OptimizerConfig

    ok("optimize", square_graph, "-o", tmp_path / "default.g2o")
    assert recorded(tmp_path / "default.config.yaml", PoseGraphConfig) == PoseGraphConfig()
    ok(
        "optimize", square_graph, "-o", tmp_path / "opt.g2o",
        "--robust", "cauchy", "--robust-edges", "closures", "--max-iterations", "7",
    )  # fmt: skip
    cfg_file = tmp_path / "c.yaml"
    cfg_file.write_text("robust: cauchy\nmax_iterations: 7\nrobust_edges: closures\n")
    res = ok("optimize", square_graph, "-o", tmp_path / "file.g2o", "--config", cfg_file)
    assert "cauchy (scale 2.3849, closures edges)" in res.output
    by_opt, by_file = ((tmp_path / n).read_text() for n in ("opt.g2o", "file.g2o"))
    assert by_file == by_opt != (tmp_path / "default.g2o").read_text()
    # options override the file, field by field (the nested optimizer's fields too)
    ok(
        "optimize", square_graph, "-o", tmp_path / "over.g2o", "--config", cfg_file,
        "--robust", "huber", "--init", "lago",
    )  # fmt: skip
    cfg = recorded(tmp_path / "over.config.yaml", PoseGraphConfig)
    assert cfg == PoseGraphConfig(
        robust="huber", max_iterations=7, robust_edges="closures", init="lago"
    )
    assert cfg.optimizer() == OptimizerConfig(robust="huber", max_iterations=7)
    assert cfg.optimizer().scale == 1.345  # the Huber default, not Cauchy's
    # the recorded file reproduces the run
    ok(
        "optimize",
        square_graph,
        "-o",
        tmp_path / "again.g2o",
        "--config",
        tmp_path / "over.config.yaml",
    )
    assert (tmp_path / "again.g2o").read_text() == (tmp_path / "over.g2o").read_text()


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("robus: huber\n", ["bad.yaml", "robus", "robust?"]),
        ("robust: tukey\n", ["bad.yaml", "robust", "'tukey'"]),
        ("max_iterations: -1\n", ["bad.yaml", "max_iterations must be >= 0"]),
        ("robust_edges: some\n", ["bad.yaml", "robust_edges"]),
    ],
)
def test_optimize_bad_config(square_graph, tmp_path, text, words):
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    res = run("optimize", square_graph, "-o", tmp_path / "out.g2o", "--config", bad)
    one_line_error(res, *words)
    assert not list(tmp_path.glob("out*"))


# ----------------------------------------------------------------------------- fit-sensor-model
@pytest.fixture(scope="module")
def short_log(tmp_path_factory):
    """The first 40 scans of the simulated floor-plan tour as a CARMEN log."""
    from probmap.sim.floorplan import simulate_laser_world

    w = simulate_laser_world(seed=1, size=(12.0, 8.0), step=0.2, range_noise=0.01)
    lines = [f"PARAM robot_front_laser_max {w.max_range}"]
    for i, (p, r) in enumerate(zip(w.poses[:40], w.ranges[:40], strict=True)):
        rs = " ".join(f"{v:.3f}" for v in r)
        pose = f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}"
        lines.append(f"FLASER {len(r)} {rs} {pose} {pose} {i * 0.2:.3f} sim {i * 0.2:.3f}")
    path = tmp_path_factory.mktemp("log") / "short.clf"
    path.write_text("\n".join(lines) + "\n")
    return path


def _fit(path):
    doc = yaml.safe_load(path.read_text())
    assert doc["probmap_version"] == importlib.metadata.version("probmap")
    assert isinstance(doc["command"], str) and doc["command"]
    return doc


def test_fit_sensor_model_config(short_log, tmp_path):
    from probmap.pipelines.fit import FitConfig

    log = short_log
    ok("fit-sensor-model", log, "-o", tmp_path / "default.yaml", "-r", "0.1")
    ok("fit-sensor-model", log, "-o", tmp_path / "opt.yaml", "-r", "0.1", "--every", "3")
    cfg_file = tmp_path / "c.yaml"
    cfg_file.write_text("resolution: 0.1\nevery: 3\n")
    ok("fit-sensor-model", log, "-o", tmp_path / "file.yaml", "--config", cfg_file)
    default, by_opt, by_file = (_fit(tmp_path / f"{n}.yaml") for n in ("default", "opt", "file"))
    assert by_opt["beam_model"] != default["beam_model"]  # every 3rd scan: another fit
    assert by_file["beam_model"] == by_opt["beam_model"]
    assert load_config(FitConfig, yaml.safe_dump(by_file["configuration"])) == FitConfig(
        resolution=0.1, every=3
    )
    # an option overrides the file
    ok("fit-sensor-model", log, "-o", tmp_path / "over.yaml", "--config", cfg_file, "--every", "1")
    over = _fit(tmp_path / "over.yaml")
    assert over["beam_model"] == default["beam_model"]
    assert load_config(FitConfig, yaml.safe_dump(over["configuration"])) == FitConfig(
        resolution=0.1, every=1
    )
    # the recorded configuration reproduces the run
    again = tmp_path / "again.config.yaml"
    again.write_text(yaml.safe_dump(by_file["configuration"]))
    ok("fit-sensor-model", log, "-o", tmp_path / "again.yaml", "--config", again)
    assert _fit(tmp_path / "again.yaml")["beam_model"] == by_file["beam_model"]


def test_fit_sensor_model_bad_config(short_log, tmp_path):
    log = short_log
    bad = tmp_path / "bad.yaml"
    bad.write_text("evry: 3\n")
    res = run("fit-sensor-model", log, "-o", tmp_path / "out.yaml", "--config", bad)
    one_line_error(res, "bad.yaml", "evry", "every?")
    bad.write_text("poses: laser\n")
    res = run("fit-sensor-model", log, "-o", tmp_path / "out.yaml", "--config", bad)
    one_line_error(res, "bad.yaml", "poses", "'laser'")
    assert not list(tmp_path.glob("out*"))


# ----------------------------------------------------------------------------- match
def _matched(res):
    lines = [line for line in res.output.splitlines() if line.strip().startswith("matched")]
    assert len(lines) == 1, res.output
    return lines[0].split()[1:]


def test_match_config(short_log, tmp_path):
    """match writes no file: the file's fields act as the options do, options win."""
    ok("map", short_log, "-o", tmp_path / "m", "-r", "0.05")
    args = ("match", tmp_path / "m.npz", short_log, "--scan", "20", "--x", "1.0", "--theta", "0.1")
    default = _matched(ok(*args))
    by_opt = _matched(ok(*args, "--sigma", "0.2", "--angular-window", "0.02"))
    cfg_file = tmp_path / "c.yaml"
    cfg_file.write_text("sigma: 0.2\nangular_window: 0.02\n")
    res = ok(*args, "--config", cfg_file)
    assert "sigma 0.2 m, window 0.3 m / 0.02 rad" in res.output  # the command's 0.3 m kept
    assert _matched(res) == by_opt != default
    res = ok(*args, "--config", cfg_file, "--sigma", "0.05", "--angular-window", "0.2")
    assert _matched(res) == default


def test_match_bad_config(short_log, tmp_path):
    ok("map", short_log, "-o", tmp_path / "m", "-r", "0.1")
    bad = tmp_path / "bad.yaml"
    bad.write_text("window: 0.2\n")
    res = run("match", tmp_path / "m.npz", short_log, "--config", bad)
    one_line_error(res, "bad.yaml", "window", "MatcherConfig")
    bad.write_text("sigma: -1\n")
    res = run("match", tmp_path / "m.npz", short_log, "--config", bad)
    one_line_error(res, "bad.yaml", "sigma")


# ----------------------------------------------------------------------------- slam seif, compare
@pytest.fixture
def small_landmarks(monkeypatch):
    """``slam seif`` and ``slam compare`` on a short simulated run (40 steps, 30 landmarks)
    instead of the registry's 2,000-step simulation."""
    import probmap.cli.landmark_slam
    from probmap.datasets.simulation import simulate_landmarks

    ds = simulate_landmarks(30, 40, seed=3)
    # every landmark command reads its dataset through slam.open_landmark_dataset
    monkeypatch.setattr(probmap.cli.landmark_slam, "open_landmark_dataset", lambda *args: ds)
    return ds


def _csv(path):
    return np.loadtxt(path, delimiter=",", skiprows=1)


def test_seif_config(small_landmarks, tmp_path):
    from probmap.slam.landmark.seif import SeifConfig

    def seif(out, *args):
        return ok("slam", "seif", "simulation", "-o", tmp_path / out, "--no-plot", *args)

    seif("opt", "--max-active", "3")
    cfg_file = tmp_path / "c.yaml"
    cfg_file.write_text("max_active: 3\ncontext_hops: 1\n")
    res = seif("file", "--config", cfg_file, "--context-hops", "0")  # an option over the file
    assert "SEIF SLAM (max_active=3)" in res.output
    by_opt, by_file = (_csv(tmp_path / n / "trajectory.csv") for n in ("opt", "file"))
    np.testing.assert_array_equal(by_file, by_opt)
    assert load_config(SeifConfig, tmp_path / "file" / "config.yaml") == SeifConfig(max_active=3)
    metrics = json.loads((tmp_path / "file" / "metrics.json").read_text())
    assert metrics["probmap_version"] == importlib.metadata.version("probmap")
    assert metrics["command"] and metrics["configuration"]["max_active"] == 3
    res = seif("over", "--config", cfg_file, "--max-active", "0")
    assert "SEIF SLAM (max_active=unbounded, context_hops=1)" in res.output
    assert load_config(SeifConfig, tmp_path / "over" / "config.yaml") == SeifConfig(
        max_active=None, context_hops=1
    )
    assert not np.array_equal(_csv(tmp_path / "over" / "trajectory.csv"), by_opt)
    # the recorded file reproduces the run
    seif("again", "--config", tmp_path / "opt" / "config.yaml")
    np.testing.assert_array_equal(_csv(tmp_path / "again" / "trajectory.csv"), by_opt)


def _seif_row(output):
    rows = [line for line in output.splitlines() if "SEIF-" in line]
    assert len(rows) == 1, output
    cells = [c.strip() for c in rows[0].split("│") if c.strip()]
    return cells[0], cells[4:]  # the name; map size and the errors (not the timings)


def test_compare_config(small_landmarks, tmp_path):
    args = ("slam", "compare", "simulation", "--methods", "seif")
    by_opt = _seif_row(ok(*args, "--max-active", "3", "--context-hops", "1").output)
    assert by_opt[0] == "SEIF-3-ctx1"
    cfg_file = tmp_path / "c.yaml"
    cfg_file.write_text("max_active: 3\ncontext_hops: 1\n")
    res = ok(*args, "--config", cfg_file)
    assert _seif_row(res.output) == by_opt
    assert re.search(r"^time [\d.]+ s \(read [\d.]+ s, compute [\d.]+ s\)$", res.output, re.M)
    over = _seif_row(ok(*args, "--config", cfg_file, "--max-active", "0").output)
    assert over[0] == "SEIF-unbounded-ctx1" and over[1] != by_opt[1]


@pytest.mark.parametrize("command", ["seif", "compare"])
def test_seif_bad_config(small_landmarks, tmp_path, command):
    bad = tmp_path / "bad.yaml"
    bad.write_text("max_actives: 3\n")
    out = ["-o", tmp_path / "out"] if command == "seif" else []
    res = run("slam", command, "simulation", *out, "--config", bad)
    one_line_error(res, "bad.yaml", "max_actives", "max_active?")
    bad.write_text("deactivation: newest\n")
    res = run("slam", command, "simulation", *out, "--config", bad)
    one_line_error(res, "bad.yaml", "deactivation")
    assert not (tmp_path / "out").exists()


# ----------------------------------------------------------------------------- evaluate relations
@pytest.fixture(scope="module")
def relations_case(tmp_path_factory):
    """A 20-pose trajectory and its 19 consecutive relations (2 cm off in y); the relations of
    every other pair carry timestamps 5 ms late, so only a tolerance >= 5 ms matches them."""
    from probmap.geometry.se2 import between

    root = tmp_path_factory.mktemp("rel")
    t = np.arange(20) * 0.5
    x = np.stack([0.3 * np.arange(20), 0.01 * np.arange(20) ** 1.5, 0.05 * np.arange(20)], 1)
    csv = root / "traj.csv"
    csv.write_text(
        "time,x,y,theta\n"
        + "".join(f"{a},{b},{c},{d}\n" for a, (b, c, d) in zip(t, x, strict=True))
    )
    ref = between(x[:-1], x[1:]) + np.array([0.0, 0.02, 0.0])
    late = np.where(np.arange(19) % 2 == 1, 0.005, 0.0)
    rel = root / "r.relations"
    rel.write_text(
        "".join(
            f"{a + dt} {b + dt} {d[0]} {d[1]} 0 0 0 {d[2]}\n"
            for a, b, d, dt in zip(t[:-1], t[1:], ref, late, strict=True)
        )
    )
    return csv, rel


def test_evaluate_relations_config(relations_case, tmp_path):
    from probmap.metrics.relations import RelationsConfig

    csv, rel = relations_case

    def evaluate(name, *args):
        ok("evaluate", "relations", csv, rel, "-o", tmp_path / f"{name}.json", *args)
        return json.loads((tmp_path / f"{name}.json").read_text())

    default = evaluate("default")
    assert (default["relations"], default["missing"]) == (10, 9)
    by_opt = evaluate("opt", "--tolerance", "0.01")
    assert (by_opt["relations"], by_opt["missing"]) == (19, 0)
    assert by_opt["trans_abs_mean_m"] == pytest.approx(0.02, abs=1e-9)
    cfg_file = tmp_path / "c.yaml"
    cfg_file.write_text("tolerance: 0.01\n")
    by_file = evaluate("file", "--config", cfg_file)
    figures = [k for k in by_opt if k not in ("command", "configuration")]
    assert {k: by_file[k] for k in figures} == {k: by_opt[k] for k in figures}
    assert by_file["probmap_version"] == importlib.metadata.version("probmap")
    cfg = load_config(RelationsConfig, yaml.safe_dump(by_file["configuration"]))
    assert cfg == RelationsConfig(tolerance=0.01)
    over = evaluate("over", "--config", cfg_file, "--tolerance", "0.001")
    assert (over["relations"], over["missing"]) == (10, 9)
    assert over["configuration"]["tolerance"] == 0.001
    # the recorded configuration reproduces the run
    again_cfg = tmp_path / "again.yaml"
    again_cfg.write_text(yaml.safe_dump(by_file["configuration"]))
    again = evaluate("again", "--config", again_cfg)
    assert {k: again[k] for k in figures} == {k: by_file[k] for k in figures}


def test_evaluate_relations_bad_config(relations_case, tmp_path):
    csv, rel = relations_case
    bad = tmp_path / "bad.yaml"
    bad.write_text("tolerence: 0.01\n")
    res = run("evaluate", "relations", csv, rel, "-o", tmp_path / "out.json", "--config", bad)
    one_line_error(res, "bad.yaml", "tolerence", "tolerance?")
    bad.write_text("tolerance: -1\n")
    res = run("evaluate", "relations", csv, rel, "-o", tmp_path / "out.json", "--config", bad)
    one_line_error(res, "bad.yaml", "tolerance must be")
    assert not (tmp_path / "out.json").exists()
