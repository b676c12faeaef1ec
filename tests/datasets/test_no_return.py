"""The no-return reading of a CARMEN log that states no maximum range is inferred from the data
(a single largest reading repeated exactly, many times), classed as "no return", and named in
every command's summary."""

from __future__ import annotations

import re

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.datasets.carmen import DEFAULT_MAX_RANGE, load_scans
from probmap.datasets.validate import infer_no_return

NO_RETURN = 50.0


def _write(path, *, no_return=True, param=None, n_scans=200, seed=0):
    """FLASER lines of 180 readings printed with 2 decimals, as real logs are: far readings
    spread over 0.3-30 m and, with ``no_return``, a fifth of them written as 50.00."""
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.3, 30.0, (n_scans, 180))
    if no_return:
        ranges[rng.uniform(size=ranges.shape) < 0.2] = NO_RETURN
    lines = [] if param is None else [f"PARAM robot_front_laser_max {param} host 0.0"]
    for k, row in enumerate(ranges):
        r = " ".join(f"{v:.2f}" for v in row)
        x = 0.1 * k
        t = 10.0 + 0.2 * k
        lines.append(f"FLASER 180 {r} {x} 0 0 {x} 0 0 {t:.6f} host {t:.6f}")
    path.write_text("\n".join(lines) + "\n")
    written = np.round(ranges, 2)
    return path, int(np.count_nonzero(written == NO_RETURN))


def test_fifty_metres_without_param_is_no_return(tmp_path):
    log, n_50 = _write(tmp_path / "fifty.log")
    batch = load_scans(log)
    assert batch.max_range == NO_RETURN
    assert batch.readings is not None
    assert batch.readings.no_return == n_50 > 1000
    assert batch.readings.usable == batch.readings.readings - n_50
    rule = batch.readings.no_return_rule
    assert "50.00 m" in rule and "inferred" in rule and f"{n_50:,} times" in rule


def test_a_stated_maximum_range_is_kept(tmp_path):
    log, _ = _write(tmp_path / "param.log", param=60.0)
    batch = load_scans(log)
    assert batch.max_range == 60.0 and batch.readings.no_return == 0
    assert batch.readings.no_return_rule == ""
    log, _ = _write(tmp_path / "given.log")
    assert load_scans(log, max_range=70.0).max_range == 70.0  # the caller's word wins


def test_no_point_mass_no_inference(tmp_path):
    log, _ = _write(tmp_path / "plain.log", no_return=False)
    batch = load_scans(log)
    assert batch.max_range == DEFAULT_MAX_RANGE and batch.readings.no_return_rule == ""


def test_infer_no_return_thresholds():
    far = np.linspace(0.5, 30.0, 1000)
    assert infer_no_return(np.r_[far, np.full(19, 40.0)], 80.0) is None  # too few
    found = infer_no_return(np.r_[far, np.full(20, 40.0)], 80.0)
    assert found is not None and (found.value, found.count) == (40.0, 20)
    assert found.next_value == pytest.approx(30.0) and found.next_count == 1
    # the largest genuine reading repeated as often (a tenth) is no point mass
    assert infer_no_return(np.r_[far, np.full(25, 30.0), np.full(200, 40.0)], 80.0) is None
    assert infer_no_return(np.r_[far, np.full(25, 90.0)], 80.0) is None  # beyond: no return
    assert infer_no_return(np.full(5, np.nan), 80.0) is None
    # one value throughout: nothing shows it to be a cap rather than a wall at that distance
    assert infer_no_return(np.full(30, 9.0), 80.0) is None


def test_every_command_says_which_value(tmp_path):
    from probmap.cli import register
    from probmap.cli.app import app

    register(app)
    log, n_50 = _write(tmp_path / "fifty.log")
    res = CliRunner().invoke(app, ["map", str(log), "-o", str(tmp_path / "m")])
    assert res.exit_code == 0, res.output
    text = re.sub(r"\s+", " ", res.output)
    assert "no return = 50.00 m" in text and f"{n_50:,} no return" in text
