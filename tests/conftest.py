"""Shared fixtures.

Real data is found through one setting: the ``PROBMAP_DATA`` environment variable, with
``../shared/data`` (beside the repository) as the fallback. When it is absent, tests that need it
skip with a clear reason, except under CI (``CI=true``), where missing data is a failure so that
real-data checks never vanish silently.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def data_root() -> Path:
    env = os.environ.get("PROBMAP_DATA")
    return Path(env) if env else (REPO.parent / "shared" / "data")


def _need(rel: str) -> Path:
    path = data_root() / rel
    if not path.exists():
        msg = f"real data {path} is absent (set PROBMAP_DATA to the shared/data folder)"
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(msg + " -- under CI missing data is a failure")
        pytest.skip(msg)
    return path


@pytest.fixture
def shared_data():
    """Return a function ``need(relative_path) -> Path`` that skips (or fails under CI)."""
    return _need


@pytest.fixture
def sim_log():
    """Return a function ``write(path, seed=1) -> path`` that writes the simulated floor-plan
    tour (12 x 8 m, a scan every 0.2 m, 1 cm range noise) as a CARMEN ``FLASER`` log whose
    laser poses are the odometry: a small real-looking input for laser commands."""

    def write(path: Path, seed: int = 1) -> Path:
        from probmap.sim.floorplan import simulate_laser_world

        w = simulate_laser_world(seed=seed, size=(12.0, 8.0), step=0.2, range_noise=0.01)
        lines = [f"PARAM robot_front_laser_max {w.max_range}"]
        for i, (p, r) in enumerate(zip(w.poses, w.ranges, strict=True)):
            rs = " ".join(f"{v:.3f}" for v in r)
            pose = f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}"
            lines.append(f"FLASER {len(r)} {rs} {pose} {pose} {i * 0.2:.3f} sim {i * 0.2:.3f}")
        path.write_text("\n".join(lines) + "\n")
        return path

    return write


@pytest.fixture
def read_only_dir(tmp_path):
    """A folder ``tmp_path/ro`` that the test user cannot write into (mode 0o500), made writable
    again afterwards; skips where permissions are not enforced (root, a non-POSIX system)."""
    if os.name != "posix" or os.geteuid() == 0:
        pytest.skip("root ignores permissions")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    yield ro
    ro.chmod(0o700)


@pytest.fixture(autouse=True)
def _no_progress_lines(monkeypatch):
    """Commands run in tests write to a non-terminal, where progress is a line every 10 % of
    a task that runs over ``QUIET_S`` seconds: on a loaded machine that would add lines to
    outputs the tests read. tests/cli/test_line_progress.py sets it back."""
    import probmap.cli.common as common

    monkeypatch.setattr(common, "QUIET_S", float("inf"))
