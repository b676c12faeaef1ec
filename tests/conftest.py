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
