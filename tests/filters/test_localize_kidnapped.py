"""A kidnapped robot (issue 37): the odometry jumps by 10 m while the robot stays where it
is. Augmented MCL (on by default) finds it again, and the run says when it was lost and when
it recovered: in the Python API (``run.episodes``, a FilterLostWarning) and in the summary of
``probmap localize``."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from typer.testing import CliRunner

from probmap.pipelines.localize import FilterLostWarning, LocalizeConfig, localize_scans
from probmap.sim.localization import simulate_localization_world

JUMP_AT = 100


@pytest.fixture(scope="module")
def world():
    return simulate_localization_world(0)


def _kidnapped(world):
    odo = world.odometry.copy()
    odo[JUMP_AT:, 1] += 10.0  # 10 m in the odometry frame, the robot not moving
    return odo


@pytest.mark.parametrize("seed", [0, 1])
def test_kidnapped_robot_is_found_and_was_lost(world, seed):
    n = world.ranges.shape[0]
    cfg = LocalizeConfig(n_particles=2000, initial_pose=tuple(world.poses[0]), seed=seed)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always", FilterLostWarning)
        run = localize_scans(
            world.spec, world.occupied.astype(float), 0.2 * np.arange(n), world.ranges,
            world.angles, _kidnapped(world), world.max_range, cfg,
        )  # fmt: skip
    err = np.hypot(*(run.poses[:, :2] - world.poses[run.scan_index, :2]).T)
    assert np.median(err[run.scan_index < JUMP_AT]) < 0.1  # tracked before
    jump = int(np.searchsorted(run.scan_index, JUMP_AT))
    # the kidnap is felt: the cloud splits at once (its heavier half may be either place),
    # and within a few updates the estimate is metres off
    assert run.spread[jump] > 3.0 and err[jump : jump + 5].max() > 5.0
    assert err[-50:].max() < 0.15  # and the robot found again
    assert len(run.episodes) >= 1 and not run.ended_lost
    first = run.episodes[0]
    assert JUMP_AT - 1 <= first.scan_index < JUMP_AT + 30  # a jump: the update before
    assert first.recovered and first.recovered_index > first.scan_index
    assert len(rec) == len(run.episodes)  # one warning each time it lost track


def test_tracking_without_kidnap_is_never_lost(world):
    n = world.ranges.shape[0]
    cfg = LocalizeConfig(n_particles=2000, initial_pose=tuple(world.poses[0]))
    run = localize_scans(
        world.spec, world.occupied.astype(float), 0.2 * np.arange(n), world.ranges,
        world.angles, world.odometry, world.max_range, cfg,
    )  # fmt: skip
    assert run.episodes == () and run.lost is None


def test_localize_command_says_lost_and_recovered(world, tmp_path):
    from probmap.cli import register
    from probmap.cli.app import app
    from probmap.grid.io import write_map_server

    register(app)
    n = world.ranges.shape[0]
    odo = _kidnapped(world)
    lines = ["PARAM robot_front_laser_max 8.0"]
    for k in range(n):
        r = " ".join(f"{v:.3f}" for v in world.ranges[k])
        x, y, th = world.poses[k]
        o = odo[k]
        t = 100.0 + 0.2 * k
        lines.append(
            f"FLASER {world.ranges.shape[1]} {r} {x:.4f} {y:.4f} {th:.5f} {o[0]:.4f} {o[1]:.4f} "
            f"{o[2]:.5f} {t:.6f} sim {t:.6f}"
        )
    log = tmp_path / "kidnap.log"
    log.write_text("\n".join(lines) + "\n")
    write_map_server(tmp_path / "map.yaml", _TrueMap(world))
    res = CliRunner().invoke(
        app,
        ["localize", str(tmp_path / "map.yaml"), str(log), "-o", str(tmp_path / "out"),
         "--config", str(_config(tmp_path, world))],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())
    assert "lost track" in text and ("recovered at scan" in text or "relocalized" in text)
    # lost, the cloud spread and KLD-sampling drew more particles than tracking's 2,000
    assert "2,000 after the first update" in text and "(KLD-sampling)" in text


def _config(tmp_path, world):
    x, y, th = (float(v) for v in world.poses[0])
    path = tmp_path / "cfg.yaml"
    path.write_text(f"initial_pose: [{x}, {y}, {th}]\n")
    return path


class _TrueMap:
    """The world's true occupancy, as what the map writer takes of a grid."""

    p0 = 0.5
    clamp = (0.12, 0.97)

    def __init__(self, world):
        self.spec = world.spec
        self.observed = np.ones(world.occupied.shape, dtype=bool)
        self._p = np.where(world.occupied, 0.97, 0.12)
        self.log_odds = np.log(self._p / (1 - self._p)).astype(np.float32)

    def probability(self):
        return self._p


def test_a_searching_filter_skips_the_robust_pass(world, monkeypatch):
    """While lost and searching with random particles, the robust pass (casts along every
    beam, for a cloud KLD-sampling may have grown to the global count) is off; it ran while
    the kidnapped filter still tracked a scan that fit poorly."""
    import probmap.filters.mcl as mcl_module

    calls: list[float] = []
    real = mcl_module._robust

    def spy(mcl, *args):
        calls.append(mcl.random_floor)  # > 0: lost, random particles drawn at resampling
        return real(mcl, *args)

    monkeypatch.setattr(mcl_module, "_robust", spy)
    n = world.ranges.shape[0]
    cfg = LocalizeConfig(n_particles=2000, initial_pose=tuple(world.poses[0]), seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = localize_scans(
            world.spec, world.occupied.astype(float), 0.2 * np.arange(n), world.ranges,
            world.angles, _kidnapped(world), world.max_range, cfg,
        )  # fmt: skip
    assert run.episodes and run.episodes[0].reason != "turn"
    assert calls and all(floor == 0.0 for floor in calls)
    # the lost span was long enough to have called it many times otherwise
    first = run.episodes[0]
    assert np.sum((run.scan_index >= first.scan_index)
                  & (run.scan_index < first.recovered_index)) > 20  # fmt: skip
