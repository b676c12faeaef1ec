"""The README's Python API example runs as printed and builds the map ``probmap map`` builds."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parents[1] / "README.md"


def api_block() -> str:
    text = README.read_text(encoding="utf-8")
    section = text.split("## Python API in ten lines", 1)[1]
    m = re.search(r"```python\n(.*?)```", section, flags=re.DOTALL)
    assert m, "no python block under 'Python API in ten lines'"
    return m.group(1)


def test_api_example_runs_and_matches_the_cli(shared_data, tmp_path, monkeypatch):
    from probmap.grid.io import load_npz
    from probmap.pipelines import MappingConfig, map_log

    log = shared_data("intel-research-lab/intel-corrected.log.gz")
    shutil.copy(log, tmp_path / "intel-corrected.log.gz")
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(api_block(), "README.md", "exec"), namespace)  # noqa: S102 - our own README
    grid = load_npz(tmp_path / "intel.npz")
    cli = map_log(log, MappingConfig(resolution=0.05)).grid
    # the same cells, the same values (the CLI's grid is cropped to what it observed)
    assert grid.spec.shape[0] < 1000 and grid.spec.shape[1] < 1000  # no 181 m starburst
    crop = grid.cropped()
    assert crop.spec.shape == cli.spec.shape
    np.testing.assert_allclose(crop.spec.origin, cli.spec.origin)
    np.testing.assert_array_equal(crop.log_odds, cli.log_odds)
    assert namespace["p"].shape == grid.spec.shape
