"""CLI: ``probmap slam grid --method graph`` writes the map, trajectory, pose graph and picture
and prints a summary; the files it writes are read back by probmap's own readers; bad input is
one line and exit code 1."""

from __future__ import annotations

import bz2
import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app

register(app)
runner = CliRunner()

INTEL = "intel-research-lab/intel.clf.bz2"
INTEL_REL = "intel-research-lab/intel.relations"


def run(*args: str):
    # a wide terminal, so the summary table never wraps a label over two lines
    return runner.invoke(app, [str(a) for a in args], env={"COLUMNS": "200"})


def _one_line_error(res, *words: str) -> None:
    assert res.exit_code == 1, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    assert "Traceback" not in res.output
    for w in words:
        assert w in lines[0], (w, lines[0])


def _summary_value(output: str, key: str) -> int:
    m = re.search(rf"^\s*{key}\s+([\d,]+)", output, flags=re.MULTILINE)
    assert m, output
    return int(m.group(1).replace(",", ""))


def test_slam_grid_graph_on_intel_writes_every_file(shared_data, tmp_path):
    from probmap.datasets.g2o import read_g2o
    from probmap.grid.io import load_npz
    from probmap.metrics.relations import read_trajectory

    log = shared_data(INTEL)
    prefix = tmp_path / "intel"
    res = run("slam", "grid", log, "-o", prefix, "--end-time", "200")
    assert res.exit_code == 0, res.output
    suffixes = (".yaml", ".pgm", ".npz", ".png", ".trajectory.csv", ".g2o", ".plot.png")
    suffixes += (".report.json",)  # what the closure search did, the consistency figure
    suffixes += (".config.yaml",)  # the resolved configuration, with the probmap version
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f"intel{s}" for s in suffixes)
    assert len(re.findall(r"^\s*wrote\s", res.output, flags=re.MULTILINE)) == len(suffixes)
    scans = _summary_value(res.output, "scans")
    nodes = _summary_value(res.output, "nodes")
    submaps = _summary_value(res.output, "submaps")
    m = re.search(r"loop closures\s+([\d,]+) accepted of ([\d,]+) searched", res.output)
    assert m, res.output
    accepted, searched = (int(g.replace(",", "")) for g in m.groups())
    assert 900 < scans < 1100 and 100 < nodes < scans and submaps >= nodes // 20
    assert 0 < accepted <= searched
    for word in ("map", "optimization", "real time", "peak memory", "closures rejected"):
        assert word in res.output
    # the report agrees with the summary, and its figures are in their ranges
    report = json.loads((tmp_path / "intel.report.json").read_text())
    closures = report["closures"]
    assert closures["searched"] == searched
    assert closures["accepted"]["near"] + closures["accepted"]["far"] == accepted
    assert 0 <= closures["down_weighted"] <= accepted
    # the pairwise check: closures it left out are rejected, not accepted
    assert 0 <= closures["pairs_inconsistent"] <= closures["pairs_compared"]
    assert closures["rejected"]["inconsistent_with_other_closures"] >= 0
    res_m = closures["residual_m"]
    assert 0 <= res_m["median"] <= res_m["p90"] <= res_m["p99"] <= res_m["max"]
    # Intel's odometry never glitches, but at some nodes the scan refutes it (a match
    # beyond its 3 sigma that no pose within them nearly equals): each such time is reported
    overridden = report["local"]["odometry_overridden_s"]
    assert overridden == sorted(overridden) and all(0 <= t <= 200 for t in overridden)
    assert report["local"]["lidar_only"] is False and report["local"]["untracked_s"] == []
    shown = " ".join(res.output.split())
    assert f"overrode the odometry {len(overridden)} times" in shown
    assert report["doubts"] == [] and "doubtful places none" in shown
    # revisits: pieces of travel that passed a mapped place again, all joined by closures
    revisits = report["revisits"]
    assert revisits["unjoined"] == [] and revisits["unjoined_pieces"] == 0
    if revisits["pieces"]:
        seen = revisits["pieces"] * revisits["piece_m"]
        assert f"revisits {seen:,.0f} m of travel passed mapped places, 0 m" in shown
    else:  # the first 200 s: no place is passed again 30 m of travel later
        assert "revisits none (no place passed again" in shown
    assert "the map may be wrong" not in res.output
    doubt = report["consistency"]
    assert 0.0 <= doubt["share"] < 1.0 and len(doubt["visits"]) >= 3  # 10 m each
    assert all(0 <= v["contradicted"] <= v["occupied"] for v in doubt["visits"])
    shown = re.search(r"consistency\s+([\d.]+)% of the walls", res.output)
    assert shown and abs(float(shown.group(1)) - 100 * doubt["share"]) < 0.006
    # the pose graph reads back: one vertex per node, the chain and every closure as edges
    g = read_g2o(tmp_path / "intel.g2o")
    assert sorted(g.poses) == list(range(nodes))
    assert len(g.pose_edges) >= (nodes - 1) + accepted
    # the trajectory: one robot pose per scan, at the log's timestamps
    t, p = read_trajectory(tmp_path / "intel.trajectory.csv")
    assert len(t) == scans and np.isfinite(p).all()
    assert t[-1] - t[0] <= 200.0 + 1e-6
    grid = load_npz(tmp_path / "intel.npz")
    assert grid.spec.resolution == 0.05 and grid.observed.sum() > 50_000
    # and it scores with probmap evaluate relations
    res = run("evaluate", "relations", tmp_path / "intel.trajectory.csv", shared_data(INTEL_REL))
    assert res.exit_code == 0, res.output
    m = re.search(r"translation\s*│\s*([\d.]+) ± ([\d.]+) m", res.output)
    assert m, res.output
    assert float(m.group(1)) < 0.04  # measured 0.021 m
    m = re.search(r"(\d+) relations evaluated", res.output)
    assert m and int(m.group(1)) > 50, res.output


def _flaser_log(path, poses):
    r = " ".join(["2.0"] * 180)
    lines = []
    for i, pose in enumerate(poses):
        p = " ".join(f"{v:.6f}" for v in pose)
        lines.append(f"FLASER 180 {r} {p} {p} {100.0 + i:.6f} host {100.0 + i:.6f}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_log_without_odometry(tmp_path):
    log = _flaser_log(tmp_path / "still.clf", [(1.0, 2.0, 0.5)] * 5)
    res = run("slam", "grid", log, "-o", tmp_path / "out")
    _one_line_error(res, "still.clf", "needs at least 2 scans a second")
    assert not list(tmp_path.glob("out*"))


@pytest.mark.parametrize("value", ["0.0", "-1.0", "nan", "80.0", "90.0"])
@pytest.mark.parametrize("method", ["graph", "rbpf"])
def test_log_without_one_usable_reading(tmp_path, value, method):
    # every range NaN, zero, negative or at/over max range: an error, not an empty map
    log = _flaser_log(tmp_path / "blind.clf", [(0.3 * i, 0.0, 0.0) for i in range(20)])
    log.write_text(log.read_text().replace(" 2.0", f" {value}"))
    res = run("slam", "grid", log, "-o", tmp_path / "out", "--method", method)
    _one_line_error(res, "blind.clf", "no usable laser reading")
    assert not list(tmp_path.glob("out*"))


def test_truncated_log(tmp_path):
    full = _flaser_log(tmp_path / "full.clf", [(0.3 * i, 0.0, 0.0) for i in range(400)])
    data = bz2.compress(full.read_bytes())
    cut = tmp_path / "cut.clf.bz2"
    cut.write_bytes(data[: len(data) // 2])
    _one_line_error(run("slam", "grid", cut, "-o", tmp_path / "out"), "cut.clf.bz2", "truncated")


def _odometry_only_bag(path):
    """A ROS 1 bag with a few nav_msgs/Odometry messages and no scans."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    vec = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    cov = np.zeros(36)
    with Writer(path) as writer:
        conn = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
        for i in range(5):
            stamp = T["builtin_interfaces/msg/Time"](sec=100 + i, nanosec=0)
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=0.1 * i, y=0.0, z=0.0),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            )
            msg = T["nav_msgs/msg/Odometry"](
                header=T["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id="odom"),
                child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](linear=vec, angular=vec), covariance=cov
                ),
            )
            writer.write(
                conn, (100 + i) * 10**9, store.serialize_ros1(msg, "nav_msgs/msg/Odometry")
            )
    return path


def test_bag_without_a_scan_topic(tmp_path):
    pytest.importorskip("rosbags")
    bag = _odometry_only_bag(tmp_path / "odom.bag")
    _one_line_error(run("slam", "grid", bag, "-o", tmp_path / "out"), "odom.bag", "LaserScan")


def test_bag_with_two_scan_topics_and_no_odometry(shared_data, tmp_path):
    """The Cartographer backpack bag: two MultiEchoLaserScan topics, no odometry, no tf."""
    pytest.importorskip("rosbags")
    bag = shared_data("ros-bags/b0-2014-07-21-12-42-53-short.bag")
    out = tmp_path / "out"
    _one_line_error(run("slam", "grid", bag, "-o", out), "2 scan topics", "scan_topic")
    # no tf and no odometry: read in the laser's own frame, mapped by lidar-only SLAM
    res = run("slam", "grid", bag, "-o", out, "--scan-topic", "horizontal_laser_2d")
    assert res.exit_code == 0, res.output
    assert "no odometry: lidar only, 0 scans matched nothing" in " ".join(res.output.split())
    assert (tmp_path / "out.yaml").exists()
    # asking for the odometry it does not have is one line
    res = run(
        "slam", "grid", bag, "-o", out, "--scan-topic", "horizontal_laser_2d", "--odometry",
    )  # fmt: skip
    _one_line_error(res, "no odometry")


def test_bad_method_missing_file_and_bad_options(tmp_path):
    log = _flaser_log(tmp_path / "ok.clf", [(0.3 * i, 0.0, 0.0) for i in range(5)])
    _one_line_error(
        run("slam", "grid", log, "-o", tmp_path / "o", "--method", "nonsense"), "nonsense"
    )
    _one_line_error(run("slam", "grid", tmp_path / "nope.clf", "-o", tmp_path / "o"), "nope.clf")
    _one_line_error(
        run("slam", "grid", log, "-o", tmp_path / "o", "--scan-topic", "/scan"), "ROS bags only"
    )
    _one_line_error(  # the RBPF reads bags too: the options are refused for a CARMEN log
        run("slam", "grid", log, "-o", tmp_path / "o", "--method", "rbpf", "--scan-topic", "/s"),
        "ok.clf",
        "ROS bags only",
    )
    _one_line_error(run("slam", "grid", log, "-o", tmp_path / "o", "--end-time", "-3"), "end_time")
    _one_line_error(run("slam", "grid", log, "-o", log / "o"), "ok.clf", "not a folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ok.clf"]


@pytest.mark.parametrize(
    ("args", "named"),
    [(["--particles", "30"], "--particles is"), (["--seed", "1", "--no-guard"], "--seed, --guard")],
)
def test_rbpf_options_without_the_rbpf_are_refused(tmp_path, args, named):
    """Graph SLAM has no particles: an RBPF option without ``--method rbpf`` is one line,
    not silently ignored."""
    log = _flaser_log(tmp_path / "ok.clf", [(0.3 * i, 0.0, 0.0) for i in range(5)])
    res = run("slam", "grid", log, "-o", tmp_path / "o", *args)
    _one_line_error(res, named, "--method rbpf")
