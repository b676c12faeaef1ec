"""A stalled Dask worker (issue 38): one stopped with SIGSTOP keeps its connection but sends no
heartbeat; the scheduler of probmap's local cluster restarts it after ``worker_ttl`` and its
task runs again, so the run ends, bounded in time, with the same result as without the
stall. Before, ``map A B --workers 2`` hung until an outer timeout killed it."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from probmap.grid.increments import tree_sum
from probmap.pipelines.distributed import DistributedOptions, _connected, local_cluster
from probmap.sim.floorplan import simulate_laser_world

pytest.importorskip("distributed")


def _log(path: Path, seed: int) -> Path:
    w = simulate_laser_world(seed=seed, size=(8.0, 12.0), step=0.5, range_noise=0.02)
    lines = ["PARAM robot_front_laser_max 8.0"]
    for i, (p, r) in enumerate(zip(w.poses[:20], w.ranges[:20], strict=True)):
        rs = " ".join(f"{v:.3f}" for v in r)
        pose = f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}"
        lines.append(f"FLASER {len(r)} {rs} {pose} {pose} {i * 0.5:.3f} sim {i * 0.5:.3f}")
    path.write_text("\n".join(lines) + "\n")
    return path


def _slow_log_task(path: str, delay: float):
    """The mapping task of one log, ``delay`` seconds late (long enough to stop its worker)."""
    from probmap.pipelines import MappingConfig
    from probmap.pipelines.distributed import _log_task

    time.sleep(delay)
    return _log_task(path, MappingConfig(max_range=8.0), 64, None)


def test_the_local_cluster_gets_the_worker_ttl():
    assert DistributedOptions().worker_ttl == 60.0
    with pytest.raises(ValueError, match="worker_ttl"):
        DistributedOptions(worker_ttl=0.0)
    with _connected(None, 1, None, 7.0) as cl:
        assert cl.run_on_scheduler(lambda dask_scheduler: dask_scheduler.worker_ttl) == 7.0


def test_a_stopped_worker_is_restarted_and_its_task_runs_again(tmp_path):
    from distributed import Client, wait

    logs = [_log(tmp_path / f"r{k}.log", k) for k in range(2)]
    stopped: list[int] = []
    cluster = local_cluster(2, scheduler_kwargs={"worker_ttl": "1s"})  # Dask: at least 5 s
    try:
        with Client(cluster) as client:
            futures = [client.submit(_slow_log_task, str(p), 2.0, pure=False) for p in logs]
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:  # a task running on each worker
                if sum(1 for v in client.processing().values() if v) == 2:
                    break
                time.sleep(0.05)
            victim = next(a for a, v in client.processing().items() if v)
            pid = client.run(os.getpid, workers=[victim])[victim]
            os.kill(pid, signal.SIGSTOP)
            stopped.append(pid)
            # a guard against the hang itself (Dask's default ttl is 5 minutes), not a timing
            wait(futures, timeout=240)
            parts = client.gather(futures)
            assert victim not in client.scheduler_info()["workers"], "not restarted"
            total = tree_sum(parts)
            expected = tree_sum([_slow_log_task(str(p), 0.0) for p in logs])
            assert total.stats == expected.stats
            np.testing.assert_array_equal(total.hits, expected.hits)
            np.testing.assert_array_equal(total.frees, expected.frees)
    finally:
        for pid in stopped:  # a stopped process that survived would never exit
            try:
                os.kill(pid, signal.SIGCONT)
            except ProcessLookupError:
                pass
        cluster.close()
