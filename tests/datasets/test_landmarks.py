import numpy as np
import pytest

from probmap.datasets.landmarks import (
    LandmarkSequence,
    LandmarkStep,
    MergedEvents,
    merge_events,
    read_numeric_table,
)
from probmap.datasets.protocol import Dataset, DatasetError


def test_step_is_frozen_and_validated():
    s = LandmarkStep(time=1.0, dt=0.1, control=[1.0, 0.0], z=[[2.0, 0.1]], ids=[3])
    assert s.z.shape == (1, 2) and s.ids.dtype == np.int64
    with pytest.raises(ValueError):
        s.z[0, 0] = 5.0  # read-only
    with pytest.raises(ValueError, match="ids"):
        LandmarkStep(time=0.0, dt=0.0, control=[0, 0], z=[[1.0, 0.0]], ids=[1, 2])
    with pytest.raises(ValueError, match="dt"):
        LandmarkStep(time=0.0, dt=-1.0, control=[0, 0])
    with pytest.raises(ValueError, match="control"):
        LandmarkStep(time=0.0, dt=0.0, control=[0, 0, 0])
    empty = LandmarkStep(time=0.0, dt=0.0, control=[0, 0], z=np.zeros((0, 2)), ids=[])
    assert empty.z.shape == (0, 2)
    seq = LandmarkSequence("x", [s], None, None, np.zeros(3))
    assert isinstance(seq, Dataset) and len(seq) == 1 and seq[0] is s


def merge_reference(ct, c, ot, obs):
    """Obviously-correct event merge: loop over sorted unique times."""
    times = sorted(set(ct) | set(ot))
    out = []
    prev = times[0]
    for t in times:
        before = [k for k in range(len(ct)) if ct[k] <= prev]
        u = c[before[-1]] if before else np.zeros(2)
        zs = [obs[k] for k in range(len(ot)) if ot[k] == t]
        out.append((t, t - prev, tuple(u), zs))
        prev = t
    return out


def _random_events(seed, slots, n_ctrl, n_obs):
    """Control times (distinct) and observation times (repeats allowed) on a 0.1 s grid of
    ``slots`` slots, with random controls and observations."""
    rng = np.random.default_rng(seed)
    ct = np.sort(rng.choice(np.arange(slots) * 0.1, n_ctrl, replace=False))
    ot = np.sort(rng.choice(np.arange(slots) * 0.1, n_obs))
    return rng, ct, rng.normal(size=(n_ctrl, 2)), ot, rng.normal(size=(n_obs, 2))


def test_merge_events_matches_reference():
    _, ct, c, ot, obs = _random_events(0, 100, 30, 25)
    times, dts, ctrl, starts, order = merge_events(ct, c, ot, obs, np.arange(25))
    ref = merge_reference(list(ct), c, list(ot), obs)
    assert len(ref) == times.size
    for e, (t, dt, u, zs) in enumerate(ref):
        assert np.isclose(times[e], t) and np.isclose(dts[e], dt)
        assert np.allclose(ctrl[e], u)
        got = obs[order][starts[e] : starts[e + 1]]
        assert np.allclose(got, np.array(zs).reshape(-1, 2))


class _Events(MergedEvents):
    """A reader in miniature: merge_events' output on the base's attributes."""

    def __init__(self, ct, c, ot, obs, ids):
        self._times, self._dts, self._controls, self._obs_start, order = merge_events(
            ct, c, ot, obs, ids
        )
        self._z, self._ids = obs[order], ids[order]


def test_merged_events_yield_the_reference_steps():
    rng, ct, c, ot, obs = _random_events(1, 80, 20, 30)
    ids = rng.integers(-1, 5, 30)
    steps = list(_Events(ct, c, ot, obs, ids))
    ref = merge_reference(list(ct), c, list(ot), obs)
    assert len(_Events(ct, c, ot, obs, ids)) == len(steps) == len(ref)
    for st, (t, dt, u, zs) in zip(steps, ref, strict=True):
        assert isinstance(st, LandmarkStep)
        assert np.isclose(st.time, t) and np.isclose(st.dt, dt) and np.allclose(st.control, u)
        assert np.allclose(st.z, np.array(zs).reshape(-1, 2))
        # each observation keeps its own id
        want = [int(ids[k]) for k in range(ot.size) if ot[k] == t]
        assert st.ids.tolist() == want


def test_read_numeric_table(tmp_path):
    p = tmp_path / "t.dat"
    p.write_text("# header\n1 2 3\n\n2 nan 4\n3 5 6 extra\n")
    with pytest.raises(DatasetError, match="line 5, field 'd'"):
        read_numeric_table(p, ("a", "b", "c", "d"), min_columns=3)
    table, skipped = read_numeric_table(p, ("a", "b", "c"))
    assert table.tolist() == [[1, 2, 3], [3, 5, 6]] and skipped == 1
    p.write_text("1 2\n0 3\n")
    with pytest.raises(DatasetError, match=r"t.dat, line 2, field 'a'.*backwards"):
        read_numeric_table(p, ("a", "b"))
    p.write_text("1 2\n1 3\n")
    with pytest.raises(DatasetError, match="backwards"):
        read_numeric_table(p, ("a", "b"), allow_equal_times=False)
