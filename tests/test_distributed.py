"""Distributed mapping: increments, tree sums and a 2-worker LocalCluster against sequential maps."""

from __future__ import annotations

import math
import os
import signal
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from probmap.grid.increments import (
    IncrementGrid,
    clamping_bound,
    integrate_increments,
    tree_sum,
)
from probmap.grid.logodds import logit
from probmap.grid.occupancy import OccupancyGrid
from probmap.pipelines import MappingConfig, map_log
from probmap.pipelines.distributed import (
    DistributedMappingError,
    DistributedOptions,
    local_cluster,
    map_logs_distributed,
)
from probmap.sim.floorplan import simulate_laser_world

distributed = pytest.importorskip("distributed")

# wide clamps: logit(1 - 1e-15) = 34.5, so no cell of the small logs below reaches them
NO_CLAMP = MappingConfig(
    resolution=0.1, max_range=8.0, clamp=(1e-15, 1 - 1e-15), max_clear_range=None
)
CLAMPED = MappingConfig(resolution=0.1, max_range=8.0, max_clear_range=None)


def world(seed: int, **kw: object):
    """A simulated tour whose poses are moved off the cell boundaries.

    The simulator places poses on multiples of 0.25 m, exactly on cell boundaries; there the
    cell of a pose depends on the rounding of ``(x - origin) / r``, i.e. on the grid's origin
    (see the notes of :mod:`probmap.grid.increments`). Real logs do not sit on boundaries.
    """
    from dataclasses import replace

    w = simulate_laser_world(seed=seed, **kw)  # type: ignore[arg-type]
    return replace(w, poses=w.poses + np.array([0.0123, 0.0077, 0.0]))


def write_carmen(path: Path, poses: np.ndarray, ranges: np.ndarray, max_range: float) -> Path:
    """A minimal CARMEN log: one PARAM line and FLASER lines (laser pose = odometry pose)."""
    lines = [f"PARAM robot_front_laser_max {max_range}"]
    for i, (p, r) in enumerate(zip(poses, ranges, strict=True)):
        rs = " ".join("nan" if not np.isfinite(v) else f"{v:.3f}" for v in r)
        pose = f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}"
        lines.append(f"FLASER {len(r)} {rs} {pose} {pose} {i * 0.1:.3f} sim {i * 0.1:.3f}")
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Three robots' logs in the same building (different seeds), 20-25 scans each."""
    folder = tmp_path_factory.mktemp("fleet")
    out = []
    for seed in range(3):
        w = world(seed, size=(8.0, 12.0), step=0.5, n_beams=91, range_noise=0.02, dropout=0.02)
        k = slice(seed * 8, seed * 8 + 20 + seed * 2)
        out.append(write_carmen(folder / f"robot{seed}.log", w.poses[k], w.ranges[k], 8.0))
    return out


@pytest.fixture(scope="module")
def client():
    """A LocalCluster of 2 single-threaded worker processes, closed after the module."""
    from distributed import Client

    cluster = local_cluster(2)
    c = Client(cluster)
    try:
        yield c
    finally:
        c.close()
        cluster.close()


def sequential(paths: list[Path], cfg: MappingConfig) -> OccupancyGrid:
    """Reference: one grid integrating all logs in order, clamping after every update."""
    from probmap.datasets.carmen import load_scans

    grid = cfg.make_grid()
    for p in paths:
        b = load_scans(p, max_range=cfg.max_range)
        grid.integrate_scans(b.laser_poses, b.ranges, b.angles, max_range=cfg.max_range or 8.0)
    return grid.cropped()


def aligned(a: OccupancyGrid, b: OccupancyGrid) -> tuple[np.ndarray, ...]:
    """``(lo_b, seen_b, lo_a, seen_a)``: log odds and observed masks on the union window."""
    r = a.spec.resolution
    ax = round(a.spec.origin[0] / r)
    ay = round(a.spec.origin[1] / r)
    bx = round(b.spec.origin[0] / r)
    by = round(b.spec.origin[1] / r)
    x0, y0 = min(ax, bx), min(ay, by)
    x1 = max(ax + a.spec.width, bx + b.spec.width)
    y1 = max(ay + a.spec.height, by + b.spec.height)
    out = []
    for g, gx, gy in ((b, bx, by), (a, ax, ay)):
        lo = np.full((y1 - y0, x1 - x0), np.float32(logit(g.p0)), dtype=np.float32)
        seen = np.zeros(lo.shape, dtype=bool)
        h, w = g.spec.shape
        lo[gy - y0 : gy - y0 + h, gx - x0 : gx - x0 + w] = g.log_odds
        seen[gy - y0 : gy - y0 + h, gx - x0 : gx - x0 + w] = g.observed
        out += [lo, seen]
    return out[0], out[1], out[2], out[3]


def rounding_tol(n_updates: np.ndarray | int, level: float) -> np.ndarray:
    """Float32 rounding of the sequential sum: half an ulp of the running value per update."""
    return (n_updates + 1) * level * np.finfo(np.float32).eps


# ------------------------------------------------------------------ increments without a cluster
def test_increments_match_sequential_grid_without_clamping() -> None:
    w = world(4, size=(8.0, 12.0), step=0.5, n_beams=61, dropout=0.05)
    inc = integrate_increments(w.poses, w.ranges, w.angles, w.max_range, NO_CLAMP, tile=16)
    assert inc.cell0[0] % 16 == 0 and inc.cell0[1] % 16 == 0
    assert inc.hits.shape[0] % 16 == 0 and inc.hits.shape[1] % 16 == 0
    assert np.all(clamping_bound(inc, NO_CLAMP) == 0)
    ref = NO_CLAMP.make_grid()
    ref_stats = ref.integrate_scans(w.poses, w.ranges, w.angles, max_range=w.max_range)
    assert inc.stats == ref_stats
    got = inc.to_grid(NO_CLAMP)
    lo_ref, seen_ref, lo, seen = aligned(got, ref.cropped())
    np.testing.assert_array_equal(seen, seen_ref)
    n = (inc.hits + inc.frees).max()
    assert np.abs(lo - lo_ref).max() <= rounding_tol(n, 35.0)
    assert int((inc.hits + inc.frees).sum()) == ref_stats.cell_updates


def test_increment_counts_against_python_reference() -> None:
    """A few beams on a coarse grid: hits/frees counted by hand with the once-per-scan rule."""
    cfg = MappingConfig(resolution=1.0, max_clear_range=None)
    poses = np.array([[0.5, 0.5, 0.0], [0.5, 0.5, 0.0], [0.5, 0.5, math.pi / 2]])
    ranges = np.array([[3.0, 3.0], [2.0, np.nan], [2.0, 9.0]])
    angles = np.array([0.0, 1e-3])
    inc = integrate_increments(poses, ranges, angles, 9.0, cfg, tile=4)

    def count(ix: int, iy: int) -> tuple[int, int]:
        j, i = iy - inc.cell0[1], ix - inc.cell0[0]
        return int(inc.hits[j, i]), int(inc.frees[j, i])

    # scan 0: both beams end in cell (3, 0) -> one hit; cells 0..2 crossed once
    # scan 1: beam ends in (2, 0) -> hit; (0, 0), (1, 0) crossed
    # scan 2: up the y axis, hit at (0, 2); the max-range beam at angle 1e-3 (heading pi/2)
    # clears up to 9 m along x = 0.5 - 9e-3 .. cells (0, 0..8) but (0, 2) is the hit (hit wins)
    assert count(3, 0) == (1, 0)
    assert count(2, 0) == (1, 1)
    assert count(1, 0) == (0, 2)
    assert count(0, 0) == (0, 3)
    assert count(0, 2) == (1, 0)
    assert count(0, 1) == (0, 1)
    assert count(0, 8) == (0, 1)
    assert int(inc.hits.sum()) == 3 and inc.stats.dropped == 1 and inc.stats.max_range == 1


def test_counts_switch_to_int32_beyond_uint16_scans() -> None:
    """70,000 identical one-beam scans: closed-form counts, exact past 65,535 (int32 path)."""
    cfg = MappingConfig(resolution=1.0, max_clear_range=None)
    n = 70_000
    poses = np.tile([0.5, 0.5, 0.0], (n, 1))
    inc = integrate_increments(poses, np.full((n, 1), 3.0), np.zeros(1), 9.0, cfg, tile=4)
    assert inc.hits.dtype == np.int32 and inc.frees.dtype == np.int32
    j, i = -inc.cell0[1], -inc.cell0[0]
    assert int(inc.hits[j, i + 3]) == n and int(inc.frees[j, i + 3]) == 0
    assert [int(inc.frees[j, i + k]) for k in range(3)] == [n, n, n]
    assert int(inc.hits.sum()) == n and int(inc.frees.sum()) == 3 * n
    small = integrate_increments(poses[:10], np.full((10, 1), 3.0), np.zeros(1), 9.0, cfg, tile=4)
    assert small.hits.dtype == np.uint16 and int(small.frees.sum()) == 30


def test_reused_stamp_buffer_gives_fresh_results(monkeypatch) -> None:
    """Tasks share a per-thread stamp buffer: results do not depend on what ran before, also
    across the int32 wrap-around of the stamp ids."""
    import probmap.grid.increments as dist

    a = world(6, size=(8.0, 12.0), step=0.5, n_beams=61)
    b = world(7, size=(20.0, 6.0), step=0.5, n_beams=61)

    def run(w: Any) -> IncrementGrid:
        return integrate_increments(w.poses, w.ranges, w.angles, w.max_range, NO_CLAMP, tile=8)

    monkeypatch.setattr(dist, "_STAMPS", dist.threading.local())
    first = run(a)
    run(b)  # another window shape in between
    again = run(a)
    np.testing.assert_array_equal(again.hits, first.hits)
    np.testing.assert_array_equal(again.frees, first.frees)
    # ids about to overflow: the buffer is cleared and ids restart
    dist._STAMPS.next = np.iinfo(np.int32).max - 3
    wrapped = run(a)
    assert dist._STAMPS.next == len(a.poses) + 1
    np.testing.assert_array_equal(wrapped.hits, first.hits)
    np.testing.assert_array_equal(wrapped.frees, first.frees)


def test_final_log_odds_kernel_against_numpy() -> None:
    """The one-pass kernel vs the formula in numpy, clamped and unclamped, both count dtypes."""
    from probmap.grid.increments import _levels
    from probmap.grid.occupancy import ScanStats

    rng = np.random.default_rng(4)
    for dtype in (np.uint16, np.int32):
        hits = rng.integers(0, 40, (37, 53)).astype(dtype)
        frees = rng.integers(0, 40, (37, 53)).astype(dtype)
        hits[:5] = 0
        frees[:5, :7] = 0
        inc = IncrementGrid(0.1, (3, -4), hits, frees, ScanStats(0, 0, 0, 0, 0, 0))
        for cfg in (CLAMPED, NO_CLAMP):
            l0, dh, df, lmin, lmax = _levels(cfg)
            ref = np.clip(l0 + hits.astype(float) * dh + frees.astype(float) * df, lmin, lmax)
            np.testing.assert_array_equal(inc.log_odds(cfg), ref.astype(np.float32))
            grid = inc.to_grid(cfg)
            seen = (hits > 0) | (frees > 0)
            assert int(grid.observed.sum()) == int(seen.sum())


def test_tree_sum_is_exact_and_order_free() -> None:
    w = world(5, size=(8.0, 12.0), step=0.5, n_beams=61)
    whole = integrate_increments(w.poses, w.ranges, w.angles, w.max_range, CLAMPED, tile=8)
    cuts = [0, 7, 8, 30, 31, len(w.poses)]
    parts = [
        integrate_increments(w.poses[a:b], w.ranges[a:b], w.angles, w.max_range, CLAMPED, tile=8)
        for a, b in zip(cuts[:-1], cuts[1:], strict=True)
    ]
    for fan_in in (2, 3):
        for order in (parts, parts[::-1]):
            total = tree_sum(order, fan_in=fan_in)
            assert total.stats == whole.stats
            g1, g2 = total.to_grid(CLAMPED), whole.to_grid(CLAMPED)
            assert g1.spec == g2.spec
            np.testing.assert_array_equal(g1.log_odds, g2.log_odds)
    assert tree_sum([IncrementGrid.empty(0.1), parts[0]]).stats == parts[0].stats


def test_clamping_bound_holds_and_is_tight_where_zero() -> None:
    """Default clamps (0.12, 0.97): cells with bound 0 match the sequential map to rounding,
    the others within l_max - l_min, and some cells really differ."""
    w = world(6, size=(8.0, 12.0), step=0.25, n_beams=91, range_noise=0.05)
    inc = integrate_increments(w.poses, w.ranges, w.angles, w.max_range, CLAMPED, tile=8)
    bound = clamping_bound(inc, CLAMPED)
    ref = CLAMPED.make_grid()
    ref.integrate_scans(w.poses, w.ranges, w.angles, max_range=w.max_range)
    # compare on the increments' own (uncropped) window
    full = OccupancyGrid.from_log_odds(inc.spec, inc.log_odds(CLAMPED), clamp=CLAMPED.clamp)
    lo_ref, _, lo, _ = aligned(full, ref.cropped())
    assert lo.shape == bound.shape
    n = inc.hits + inc.frees
    b = bound
    diff = np.abs(lo.astype(np.float64) - lo_ref)
    tol = rounding_tol(n, 4.0)
    assert (b == 0).sum() > 1000 and (b > 0).sum() > 10
    assert np.all(diff[b == 0] <= tol[b == 0])
    assert np.all(diff <= b + tol)
    assert diff[b > 0].max() > 0.1  # clamping order matters somewhere


def test_options_are_validated() -> None:
    with pytest.raises(ValueError, match="mode"):
        DistributedOptions(mode="fast")
    with pytest.raises(ValueError, match="chunks"):
        DistributedOptions(chunks=0)
    with pytest.raises(ValueError, match="poses must be"):
        integrate_increments(np.zeros((2, 2)), np.zeros((2, 3)), np.zeros(3), 8.0, CLAMPED)


# ------------------------------------------------------------------ on a 2-worker LocalCluster
def test_cluster_fleet_equals_sequential_without_clamping(client, fleet) -> None:
    res = map_logs_distributed(fleet, NO_CLAMP, client=client, progress=False)
    assert res.mode == "increments" and res.mapped == tuple(fleet) and not res.failed
    ref = sequential(fleet, NO_CLAMP)
    assert res.increments is not None and np.all(clamping_bound(res.increments, NO_CLAMP) == 0)
    lo_ref, seen_ref, lo, seen = aligned(res.grid, ref)
    np.testing.assert_array_equal(seen, seen_ref)
    assert np.abs(lo - lo_ref).max() <= rounding_tol(200, 35.0)
    assert res.stats.scans == sum(1 for p in fleet for line in p.open() if line[:6] == "FLASER")


def test_cluster_chunks_of_one_log_equal_whole_log(client, fleet) -> None:
    opts = DistributedOptions(chunks=4, fan_in=2)
    res = map_logs_distributed([fleet[2]], CLAMPED, client=client, progress=False, options=opts)
    assert res.mode == "increments" and res.tasks > 4
    seq = map_logs_distributed([fleet[2]], CLAMPED, client=client, progress=False)
    assert seq.mode == "sequential" and seq.increments is None
    # the sequential default is map_log itself
    direct = map_log(fleet[2], CLAMPED).grid
    np.testing.assert_array_equal(seq.grid.log_odds, direct.log_odds)
    # chunked: within the clamping bound of the sequential map
    assert res.increments is not None
    bound = clamping_bound(res.increments, CLAMPED)
    lo_ref, seen_ref, lo, seen = aligned(res.grid, direct)
    np.testing.assert_array_equal(seen, seen_ref)
    assert np.abs(lo - lo_ref).max() <= bound.max() + 1e-4
    progress: list[tuple[int, int]] = []
    again = map_logs_distributed(
        [fleet[2]], CLAMPED, client=client, progress=lambda d, t: progress.append((d, t)),
        options=opts,
    )  # fmt: skip
    np.testing.assert_array_equal(again.grid.log_odds, res.grid.log_odds)
    assert progress[-1] == (9, 9)  # a read task, 4 parse tasks and 4 integrating tasks


def test_cluster_chunks_parse_in_parallel_like_the_whole_log(client, fleet, tmp_path) -> None:
    """Chunks of a gzipped log, max range from its PARAM (config leaves it unset): the same
    counts as the whole log in one task; a bad line in a later share is named by file and line."""
    import gzip

    cfg = MappingConfig(resolution=0.1, clamp=(1e-15, 1 - 1e-15), max_clear_range=None)
    text = fleet[1].read_text()
    gz = tmp_path / "robot1.log.gz"
    gz.write_bytes(gzip.compress(text.encode()))
    whole = map_logs_distributed([gz], cfg, client=client, progress=False,
                                 options=DistributedOptions(mode="increments"))  # fmt: skip
    for chunks in (3, 50):  # 50 > scans: the extra shares are empty
        res = map_logs_distributed([gz], cfg, client=client, progress=False,
                                   options=DistributedOptions(chunks=chunks))  # fmt: skip
        assert res.increments is not None and whole.increments is not None
        assert res.stats == whole.stats
        np.testing.assert_array_equal(res.increments.hits, whole.increments.hits)
        np.testing.assert_array_equal(res.increments.frees, whole.increments.frees)
    lines = text.splitlines()
    lines[15] = lines[15].replace("FLASER 91", "FLASER 90")  # wrong count, line 16
    bad = tmp_path / "bad.log"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(DistributedMappingError) as info:
        map_logs_distributed([bad], cfg, client=client, progress=False,
                             options=DistributedOptions(chunks=4))  # fmt: skip
    msg = str(info.value)
    assert "bad.log" in msg and "line 16" in msg


def test_cluster_reports_unreadable_log(client, fleet, tmp_path: Path) -> None:
    bad = tmp_path / "broken.log"
    bad.write_text("FLASER 3 1.0 2.0\n")
    with pytest.raises(DistributedMappingError, match="broken.log") as info:
        map_logs_distributed([fleet[0], bad], NO_CLAMP, client=client, progress=False)
    partial = info.value.result
    assert partial is not None and partial.mapped == (fleet[0],)
    assert partial.failed[0][0] == bad and "line 1" in partial.failed[0][1]
    res = map_logs_distributed(
        [fleet[0], bad], NO_CLAMP, client=client, progress=False, allow_partial=True
    )
    alone = map_logs_distributed([fleet[0]], NO_CLAMP, client=client, progress=False,
                                 options=DistributedOptions(mode="increments"))  # fmt: skip
    np.testing.assert_array_equal(res.grid.log_odds, alone.grid.log_odds)
    with pytest.raises(FileNotFoundError, match="missing.log"):
        map_logs_distributed([tmp_path / "missing.log"], NO_CLAMP, client=client)
    with pytest.raises(DistributedMappingError, match="no input could be mapped"):
        map_logs_distributed([bad, bad], NO_CLAMP, client=client, progress=False)


def _slow_chunk(path: str, delay: float) -> IncrementGrid:
    """A task that takes a while, so a worker can be killed while it runs."""
    import time

    from probmap.pipelines.distributed import _log_task

    time.sleep(delay)
    return _log_task(path, NO_CLAMP, 64, None)


def test_killed_worker_does_not_change_the_result(client, fleet) -> None:
    futures = [client.submit(_slow_chunk, str(p), 1.0, pure=False) for p in fleet * 2]
    # wait until tasks run on both workers, then kill the process of one of them
    import time

    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        processing = client.processing()
        if sum(1 for v in processing.values() if v) == 2:
            break
        time.sleep(0.05)
    victim = next(a for a, v in client.processing().items() if v)
    pid = client.run(os.getpid, workers=[victim])[victim]
    os.kill(pid, signal.SIGKILL)  # the nanny starts a new worker; its tasks are rescheduled
    total = tree_sum(client.gather(futures))
    assert victim not in client.scheduler_info()["workers"]  # it really died mid-run
    expected = tree_sum([_slow_chunk(str(p), 0.0) for p in fleet * 2])
    assert total.stats == expected.stats
    np.testing.assert_array_equal(total.hits, expected.hits)
    np.testing.assert_array_equal(total.frees, expected.frees)
    client.wait_for_workers(2, timeout=30)


def test_cli_helper_writes_map_and_lists_inputs(client, fleet, tmp_path: Path, capsys) -> None:
    from probmap.cli.common import CliError
    from probmap.cli.distributed import run_map_distributed

    address = client.scheduler.address
    res = run_map_distributed(fleet, tmp_path / "fleet", NO_CLAMP, scheduler=address, chunks=2)
    names = ["fleet.config.yaml", "fleet.npz", "fleet.pgm", "fleet.plot.png", "fleet.png"]
    names.append("fleet.yaml")
    assert sorted(p.name for p in tmp_path.iterdir()) == names
    from probmap.grid.io import load_npz

    back = load_npz(tmp_path / "fleet.npz")
    np.testing.assert_allclose(back.log_odds, res.grid.log_odds, atol=1e-6)
    out = capsys.readouterr().out
    assert "robot2.log" in out and "mapped" in out and "distributed" in out
    bad = tmp_path / "broken.log"
    bad.write_text("FLASER 3 1.0 2.0\n")
    with pytest.raises(CliError, match="broken.log"):
        run_map_distributed([fleet[0], bad], tmp_path / "x", NO_CLAMP, scheduler=address)
    assert not (tmp_path / "x.yaml").exists()
    with pytest.raises(CliError, match="not both"):
        run_map_distributed(fleet, tmp_path / "x", NO_CLAMP, workers=2, scheduler=address)


def test_local_cluster_workers_keep_glibc_adaptive_malloc(client) -> None:
    """``local_cluster`` spawns workers without Dask's MALLOC_TRIM_THRESHOLD_ (see its notes)."""
    envs = client.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_"))
    assert len(envs) == 2 and set(envs.values()) == {None}
    threads = client.run(lambda dask_worker: dask_worker.state.nthreads)
    assert set(threads.values()) == {1}
    with pytest.raises(ValueError, match="n_workers"):
        local_cluster(0)


def test_local_cluster_started_and_closed(fleet) -> None:
    """``workers=1`` starts a LocalCluster for the run and closes it afterwards."""
    import multiprocessing

    before = {p.pid for p in multiprocessing.active_children()}
    res = map_logs_distributed([fleet[1]], NO_CLAMP, workers=1, progress=False)
    assert res.workers == 1 and res.mode == "sequential"
    np.testing.assert_array_equal(res.grid.log_odds, map_log(fleet[1], NO_CLAMP).grid.log_odds)
    after = {p.pid for p in multiprocessing.active_children() if p.is_alive()}
    assert after <= before


# ------------------------------------------------------------------ semantic grids
from probmap.grid.semantic import LabelledInverseModel  # noqa: E402


def _labelled(seed: int, soft: bool = False):
    from dataclasses import replace

    from probmap.grid.semantic_io import LabelledScans
    from probmap.sim.semantic import simulate_labelled_world

    w = simulate_labelled_world(seed=seed, size=(8.0, 12.0), step=0.5, n_beams=61, soft=soft)
    w = replace(w, poses=w.poses + np.array([0.0123, 0.0077, 0.0]))
    k = slice(seed * 4, seed * 4 + 12)  # a short stretch: sums stay below the widest clamps
    return LabelledScans(
        w.poses[k], w.ranges[k], w.angles, w.max_range, w.classes,
        labels=None if soft else w.labels[k],
        probabilities=None if w.probabilities is None else w.probabilities[k],
    )  # fmt: skip


def _semantic_reference(scans_list, clamp, **kw):  # type: ignore[no-untyped-def]
    from probmap.grid.semantic import SemanticGrid

    grid = SemanticGrid(scans_list[0].classes, resolution=0.1, clamp=clamp, **kw)
    for s in scans_list:
        s.integrate_into(grid)
    return grid


def _on(grid, spec):  # type: ignore[no-untyped-def]
    """``grid``'s log odds and observed mask on the window ``spec`` (same lattice); cells of
    ``grid`` outside ``spec`` must be unobserved."""
    r = spec.resolution
    dx = round((grid.spec.origin[0] - spec.origin[0]) / r)
    dy = round((grid.spec.origin[1] - spec.origin[1]) / r)
    h, w = grid.spec.shape
    lo = np.broadcast_to(grid.l_prior, (*spec.shape, grid.n_classes)).astype(np.float32)
    seen = np.zeros(spec.shape, dtype=bool)
    y0, y1 = max(dy, 0), min(dy + h, spec.height)
    x0, x1 = max(dx, 0), min(dx + w, spec.width)
    inside = np.zeros(grid.spec.shape, dtype=bool)
    inside[y0 - dy : y1 - dy, x0 - dx : x1 - dx] = True
    assert not (grid.observed & ~inside).any()
    lo[y0:y1, x0:x1] = grid.log_odds[y0 - dy : y1 - dy, x0 - dx : x1 - dx]
    seen[y0:y1, x0:x1] = grid.observed[y0 - dy : y1 - dy, x0 - dx : x1 - dx]
    return lo, seen


@pytest.mark.parametrize("soft", [False, True])
def test_semantic_increments_match_sequential(soft: bool) -> None:
    from probmap.grid.increments import integrate_semantic_increments

    scans = [_labelled(1, soft), _labelled(2, soft)]
    wide = (1e-15, 1 - 1e-15)
    # weak free-space evidence so that no cell reaches even the wide clamps
    kw: dict[str, Any] = {
        "model": LabelledInverseModel(p_miss=0.7, p_correct=0.9, label_floor=0.05)
    }
    parts = [
        integrate_semantic_increments(s, resolution=0.1, tile=16, start=a, stop=b, **kw)
        for s in scans
        for a, b in ((0, 5), (5, None))
    ]
    total: Any = tree_sum(parts, fan_in=3)  # type: ignore[arg-type]
    ref = _semantic_reference(scans, wide, **kw)
    assert total.stats.cell_updates == sum(
        integrate_semantic_increments(s, resolution=0.1, **kw).stats.cell_updates for s in scans
    )
    got = total.to_grid(scans[0].classes, clamp=wide, **kw)
    lo, seen = _on(got, ref.spec)
    np.testing.assert_array_equal(ref.observed, seen)
    assert np.abs(ref.log_odds - lo).max() < 1e-3
    # tight clamps (0.2, 0.8): within l_max - l_min per class, and clamping matters
    ref = _semantic_reference(scans, (0.2, 0.8), **kw)
    got = total.to_grid(scans[0].classes, clamp=(0.2, 0.8), **kw)
    lo, _ = _on(got, ref.spec)
    diff = np.abs(ref.log_odds - lo)
    assert diff.max() <= 2 * logit(0.8) + 1e-4
    assert diff.max() > 0.1  # the clamping order matters somewhere


def test_semantic_on_cluster(client, tmp_path: Path) -> None:
    from probmap.grid.semantic_io import write_labelled_scans
    from probmap.pipelines.distributed import map_labelled_distributed

    scans = [_labelled(3), _labelled(4)]
    paths = [write_labelled_scans(tmp_path / f"r{i}.npz", s) for i, s in enumerate(scans)]
    wide = (1e-15, 1 - 1e-15)
    kw: dict[str, Any] = {
        "model": LabelledInverseModel(p_miss=0.7, p_correct=0.9, label_floor=0.05),
        "clamp": wide,
    }
    res = map_labelled_distributed(paths, resolution=0.1, client=client, chunks=2, **kw)
    assert res.mapped == tuple(paths) and res.tasks >= 5
    ref = _semantic_reference(scans, **kw)
    lo, seen = _on(res.grid, ref.spec)
    np.testing.assert_array_equal(ref.observed, seen)
    assert np.abs(ref.log_odds - lo).max() < 1e-3
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(DistributedMappingError, match="bad.npz"):
        map_labelled_distributed([paths[0], bad], resolution=0.1, client=client, clamp=wide)


def test_increments_clear_no_further_than_the_sequential_grid():
    """Max-range readings clear min(max_clear_range, max_range), as OccupancyGrid does."""
    from probmap.grid.increments import integrate_increments
    from probmap.pipelines import MappingConfig

    rng = np.random.default_rng(5)
    poses = np.column_stack([rng.uniform(-1, 1, 6), rng.uniform(-1, 1, 6), rng.uniform(-3, 3, 6)])
    ranges = rng.uniform(0.3, 3.0, (6, 30))
    ranges[:, ::3] = 4.0  # no return
    angles = np.linspace(-1.5, 1.5, 30)
    cfg = MappingConfig(resolution=0.1, max_clear_range=20.0)
    inc = integrate_increments(poses, ranges, angles, 4.0, cfg)
    grid = cfg.make_grid()
    grid.integrate_scans(poses, ranges, angles, max_range=4.0)
    a = inc.to_grid(cfg)
    assert a.observed.sum() == grid.observed.sum()
    iy, ix = np.nonzero(grid.observed)
    c = a.spec.world_to_cell(grid.spec.cell_to_world(np.column_stack([ix, iy])))
    np.testing.assert_allclose(a.log_odds[c[:, 1], c[:, 0]], grid.log_odds[iy, ix], atol=1e-6)


# ------------------------------------------------------------------ errors once, bags, blind logs
def test_task_guard_returns_deterministic_errors_and_raises_the_rest() -> None:
    """A bad input fails every try the same way: the task returns its message (no retry, no
    worker traceback); anything else raises so that Dask retries it; a failure is passed on."""
    from probmap.errors import DatasetError
    from probmap.pipelines.distributed import _Failed, _task

    def body(kind: str) -> str:
        if kind == "dataset":
            raise DatasetError("bad field", path="x.log", line=3)
        if kind == "missing":
            raise FileNotFoundError(2, "No such file or directory", "gone.log")
        if kind == "memory":
            raise MemoryError("out of memory")
        return "ok"

    guarded = _task(body)
    assert guarded("fine") == "ok"
    failed = guarded("dataset")
    assert isinstance(failed, _Failed) and "x.log" in failed.message and "3" in failed.message
    assert "gone.log" in guarded("missing").message
    with pytest.raises(MemoryError):
        guarded("memory")
    upstream = _Failed("earlier task")
    assert guarded(upstream) is upstream


def test_bad_log_is_reported_once_without_retries_or_worker_tracebacks(
    client, fleet, tmp_path: Path, capfd
) -> None:
    """A malformed log on the cluster: one clear error naming the file, the task run once (its
    future holds the message, it did not error), and no 'Compute Failed' banner from a worker."""
    from probmap.pipelines.distributed import _Failed, _log_task

    bad = tmp_path / "garbled.log"
    bad.write_text("FLASER 3 1.0 2.0\n")
    fut = client.submit(_log_task, str(bad), NO_CLAMP, 64, None, retries=2, pure=False)
    out = fut.result()
    assert fut.status == "finished" and isinstance(out, _Failed) and "garbled.log" in out.message
    with pytest.raises(DistributedMappingError, match="garbled.log") as info:
        map_logs_distributed([fleet[0], bad], NO_CLAMP, client=client, progress=False)
    assert str(info.value).count("garbled.log") == 1
    import time

    time.sleep(0.5)  # worker log lines travel asynchronously
    err = capfd.readouterr().err
    assert "Compute Failed" not in err and "Traceback" not in err


def test_log_without_a_usable_reading_fails_on_the_cluster(client, fleet, tmp_path: Path) -> None:
    """A log whose every range is NaN maps to nothing: an error naming it, not an empty map."""
    w = world(11, size=(8.0, 12.0), step=0.5, n_beams=31)
    blind = write_carmen(tmp_path / "blind.log", w.poses[:5], np.full((5, 31), np.nan), 8.0)
    with pytest.raises(DistributedMappingError, match="blind.log"):
        map_logs_distributed([fleet[0], blind], NO_CLAMP, client=client, progress=False)
    with pytest.raises(DistributedMappingError, match="blind.log"):
        map_logs_distributed([blind], NO_CLAMP, client=client, progress=False)
    with pytest.raises(DistributedMappingError, match="blind.log.*no usable laser reading"):
        map_logs_distributed([blind], NO_CLAMP, client=client, progress=False,
                             options=DistributedOptions(chunks=2))  # fmt: skip


def test_bags_on_the_cluster_map_like_map_log(client, tmp_path: Path) -> None:
    """ROS bags with their topic options: the same map as ``map_log``, sequential and as
    increments; bag options with a CARMEN log, or chunks of a bag, are refused up front."""
    pytest.importorskip("rosbags")
    import importlib.util

    # the bag writer of the reader's tests (a module of tests, not of the package)
    spec = importlib.util.spec_from_file_location(
        "_bag_writer", Path(__file__).parent / "datasets" / "test_rosbag.py"
    )
    assert spec is not None and spec.loader is not None
    helpers = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(helpers)
    write_sim_bag = helpers.write_sim_bag

    w = simulate_laser_world(seed=3, size=(8.0, 12.0), range_noise=0.01, dropout=0.01)
    bag = write_sim_bag(tmp_path / "tour.bag", w, ros=1, source="odom")
    opts = {"scan_topic": "/scan", "odom_topic": "/odom"}
    cfg = MappingConfig(resolution=0.1, max_clear_range=None)
    ref = map_log(bag, cfg, bag_options=opts)
    seq = map_logs_distributed([bag], cfg, client=client, progress=False, bag_options=opts)
    np.testing.assert_array_equal(seq.grid.log_odds, ref.grid.log_odds)
    inc = map_logs_distributed([bag], cfg, client=client, progress=False, bag_options=opts,
                               options=DistributedOptions(mode="increments"))  # fmt: skip
    assert inc.stats.hits == ref.stats.hits and inc.stats.scans == ref.stats.scans
    wrong = {"scan_topic": "/nope"}
    with pytest.raises(DistributedMappingError, match="/nope"):
        map_logs_distributed([bag], cfg, client=client, progress=False, bag_options=wrong)
    log = write_carmen(tmp_path / "plain.log", w.poses[:5], w.ranges[:5], w.max_range)
    with pytest.raises(ValueError, match="plain.log: topic/frame options apply to ROS bags"):
        map_logs_distributed([bag, log], cfg, client=client, bag_options=opts)
    with pytest.raises(ValueError, match="tour.bag: a ROS bag is read by one task"):
        map_logs_distributed([bag], cfg, client=client, options=DistributedOptions(chunks=2))


def test_every_single_log_option_of_map_works_on_the_cluster(client, tmp_path, sim_log):
    """--method map and --to-bag with --scheduler (or --workers): the same map as without a
    cluster; with several logs or --chunks they are one-line errors before any work."""
    pytest.importorskip("rosbags")
    from typer.testing import CliRunner

    from bagwriter import write_batch_bag
    from probmap.cli import register
    from probmap.cli.app import app
    from probmap.datasets import open_scans
    from probmap.grid.io import load_npz

    register(app)
    runner = CliRunner()
    log = sim_log(tmp_path / "tour.log")
    bag = write_batch_bag(open_scans(log), tmp_path / "tour.bag", ros=1)
    address = ["--scheduler", client.scheduler.address]
    res = runner.invoke(app, ["map", str(log), "-o", str(tmp_path / "m1"), "-r", "0.2",
                              "--method", "map", *address])  # fmt: skip
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["map", str(log), "-o", str(tmp_path / "m0"), "-r", "0.2",
                              "--method", "map"])  # fmt: skip
    assert res.exit_code == 0, res.output
    a, b = load_npz(tmp_path / "m1.npz"), load_npz(tmp_path / "m0.npz")
    np.testing.assert_array_equal(a.log_odds, b.log_odds)
    res = runner.invoke(app, ["map", str(bag), "-o", str(tmp_path / "b1"), "-r", "0.2",
                              "--to-bag", str(tmp_path / "out" / "map.bag"), *address])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert (tmp_path / "out" / "map.bag").is_file() and (tmp_path / "b1.yaml").is_file()
    for source, extra, words in (
        (log, ["--method", "map", str(log)], "--method map maps one log"),
        (bag, ["--to-bag", str(tmp_path / "x.bag"), "--chunks", "2"], "--to-bag writes the map"),
    ):
        res = runner.invoke(app, ["map", str(source), "-o", str(tmp_path / "no"), *extra, *address])
        assert res.exit_code == 1 and words in res.output and "Traceback" not in res.output
    assert not list(tmp_path.glob("no*"))


def test_cluster_chunks_infer_the_no_return_reading(client, tmp_path) -> None:
    """A log writing no return as 50.00 m without a PARAM line: its shares, parsed apart, find
    the same no-return reading as the whole log (issue 37), and count the same max-range
    readings."""
    rng = np.random.default_rng(0)
    ranges = rng.uniform(0.3, 6.0, (60, 90))
    ranges[rng.uniform(size=ranges.shape) < 0.2] = 50.0
    lines = []
    for k, row in enumerate(ranges):
        r = " ".join(f"{v:.2f}" for v in row)
        x, t = 0.05 * k, 10.0 + 0.2 * k
        lines.append(f"FLASER 90 {r} {x} 0 0 {x} 0 0 {t:.6f} host {t:.6f}")
    log = tmp_path / "fifty.log"
    log.write_text("\n".join(lines) + "\n")
    cfg = MappingConfig(resolution=0.1, clamp=(1e-15, 1 - 1e-15), max_clear_range=None)
    n_50 = int(np.count_nonzero(np.round(ranges, 2) == 50.0))
    direct = map_log(log, cfg)
    assert direct.stats.max_range == n_50  # the whole log: 50.00 m is no return
    for chunks in (1, 3):
        res = map_logs_distributed([log], cfg, client=client, progress=False,
                                   options=DistributedOptions(chunks=chunks, mode="increments"))  # fmt: skip
        assert res.stats.max_range == n_50 and res.stats.hits == direct.stats.hits
