"""The Monte Carlo localization demo (probmap.pipelines.demo): converges and writes its files."""

from __future__ import annotations

from probmap.pipelines.demo import run_localize_demo


def test_demo_writes_trajectory(tmp_path):
    res = run_localize_demo(tmp_path)
    assert (tmp_path / "trajectory.csv").exists()
    assert 0 < res["converged_at"] <= 20 and res["median_error_m"] < 0.1
    rows = (tmp_path / "trajectory.csv").read_text().splitlines()
    assert rows[0].startswith("step,x,y,theta,spread") and len(rows) == res["steps"] + 1
