"""ScanBatch.pose_source: whether a log's scans are placed by raw odometry (a map of them
smears) or by a SLAM system's corrections; and probmap map's one warning line."""

from __future__ import annotations

import math

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.datasets.carmen import load_scans


def _log(path, *, drift: float, odom_lines: bool = False, neff: bool = False, offset=0.0):
    """A CARMEN log of 40 FLASER scans along a 4 m line; the odometry fields drift from the
    laser pose by up to ``drift`` metres (0: the laser pose is the odometry, moved ``offset``
    ahead), with ODOM lines (the odometry) between the scans when asked, NEFF lines when
    ``neff`` (GMapping's output)."""
    lines = [f"PARAM robot_frontlaser_offset {offset}", "PARAM robot_front_laser_max 8.0"]
    ranges = " ".join(["3.0"] * 30)
    for k in range(40):
        t = 10.0 + 0.5 * k
        ox, oy, oth = 0.1 * k, 0.0, 0.0  # odometry
        lx = ox + offset + drift * k / 39
        ly = oy + drift * k / 39
        if odom_lines:
            lines.append(f"ODOM {ox:.4f} {oy:.4f} {oth:.4f} 0.2 0 0 {t - 0.01:.3f} h {t:.3f}")
        if neff:
            lines.append("NEFF 15.0")
        lines.append(
            f"FLASER 30 {ranges} {lx:.4f} {ly:.4f} {oth:.4f} {ox:.4f} {oy:.4f} {oth:.4f} "
            f"{t:.3f} h {t:.3f}"
        )
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    ("kw", "poses", "want"),
    [
        ({"drift": 0.0}, "corrected", "odometry"),  # the laser pose is the odometry field
        ({"drift": 0.0, "offset": 0.2}, "corrected", "odometry"),  # ... moved by the mount
        ({"drift": 2.0}, "corrected", ""),  # a different pose, no ODOM line to tell
        ({"drift": 0.0, "odom_lines": True}, "corrected", "odometry"),
        ({"drift": 2.0, "odom_lines": True}, "corrected", "corrected"),
        ({"drift": 0.0, "odom_lines": True, "neff": True}, "corrected", "corrected"),
        ({"drift": 2.0}, "odometry", "odometry"),
    ],
)
def test_pose_source_of_carmen_logs(tmp_path, kw, poses, want):
    batch = load_scans(_log(tmp_path / "a.log", **kw), poses=poses)
    assert batch.pose_source == want


def test_map_of_raw_odometry_warns_once_and_names_slam_grid(tmp_path):
    from probmap.cli import register
    from probmap.cli.app import app

    register(app)
    runner = CliRunner()
    raw = _log(tmp_path / "raw.log", drift=0.0)
    res = runner.invoke(app, ["map", str(raw), "-o", str(tmp_path / "m")])
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("warning:")]
    assert lines == [
        "warning: the map of raw.log is built from raw odometry (its poses are uncorrected), "
        "so it drifts and smears; 'probmap slam grid raw.log -o PREFIX' corrects the poses first"
    ]
    fixed = _log(tmp_path / "fixed.log", drift=0.0, odom_lines=True, neff=True)
    res = runner.invoke(app, ["map", str(fixed), "-o", str(tmp_path / "n")])
    assert res.exit_code == 0 and "warning:" not in res.output
    res = runner.invoke(app, ["map", str(raw), "-o", str(tmp_path / "o"), "--poses", "odometry"])
    assert res.exit_code == 0 and "warning:" not in res.output  # asked for: no surprise
    assert math.isfinite(float(np.load(tmp_path / "m.npz")["log_odds"].sum()))
