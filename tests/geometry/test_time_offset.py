"""find_time_offset: two recordings of one run, on different clocks, in different frames, at
different rates, lined up by their motion."""

from __future__ import annotations

import numpy as np
import pytest

from probmap.geometry.timesync import find_time_offset


def run_of_a_robot(seed: int, seconds: float = 600.0, rate: float = 10.0):
    """Stop-and-go driving with turns: speed and turn rate vary on a scale of seconds."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate)
    v = np.repeat(rng.uniform(0.0, 1.0, t.size // 50 + 1), 50)[: t.size]
    w = np.repeat(rng.normal(0.0, 0.4, t.size // 30 + 1), 30)[: t.size]
    th = np.cumsum(w) / rate
    x = np.cumsum(v * np.cos(th)) / rate
    y = np.cumsum(v * np.sin(th)) / rate
    return t, np.column_stack([x, y, th])


@pytest.mark.parametrize("seed", range(4))
def test_offset_of_a_subsampled_noisy_copy_in_another_frame(seed):
    t, p = run_of_a_robot(seed)
    rng = np.random.default_rng(100 + seed)
    shift = float(rng.uniform(-5e8, 5e8))
    keep = np.sort(rng.choice(np.arange(500, 5000), 400, replace=False))  # part of the run
    c, s = np.cos(1.1), np.sin(1.1)
    q = p[keep].copy()
    q[:, :2] = q[:, :2] @ np.array([[c, s], [-s, c]]) + [30.0, -7.0]  # another frame
    q[:, :2] += rng.normal(0.0, 0.01, (len(q), 2))
    q[:, 2] += 1.1
    found = find_time_offset(t, p, t[keep] - shift, q)
    assert found.offset == pytest.approx(shift, abs=1e-6)  # its stamps are the log's
    assert found.matched == 1.0 and found.correlation > 0.5
    jittered = t[keep] - shift + rng.normal(0.0, 0.004, keep.size)  # stamps of its own
    found = find_time_offset(t, p, jittered, q)
    assert found.offset == pytest.approx(shift, abs=0.02)


def test_unrelated_runs_correlate_poorly_and_bad_input_is_refused():
    t, p = run_of_a_robot(0)
    u, q = run_of_a_robot(1)
    same = find_time_offset(t, p, t[::7] + 3.0, p[::7])
    other = find_time_offset(t, p, u, q)
    assert same.correlation > 0.8 > other.correlation
    with pytest.raises(ValueError, match="two distinct times"):
        find_time_offset(t, p, np.zeros(5), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="one pose per time"):
        find_time_offset(t, p[:-1], t, p)
