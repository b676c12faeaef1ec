"""End-to-end mapping with known poses (probmap.pipelines.mapping) on simulated and real data."""

from __future__ import annotations

import numpy as np

from probmap.pipelines import MappingConfig, map_log, run_mapping_demo


def endpoint_hit_rate(grid, poses, ranges, angles, max_range, slack=1):
    """Fraction of scan endpoints whose cell, or a cell within ``slack`` of it, is occupied."""
    occ = grid.classify() == 1
    pad = np.pad(occ, slack)
    near = np.zeros_like(pad)
    for dy in range(-slack, slack + 1):
        for dx in range(-slack, slack + 1):
            near |= np.roll(np.roll(pad, dy, 0), dx, 1)
    ang = poses[:, 2:3] + (angles if angles.ndim == 2 else angles[None, :])
    ok = np.isfinite(ranges) & (ranges > 0) & (ranges < max_range)
    x = poses[:, 0:1] + ranges * np.cos(ang)
    y = poses[:, 1:2] + ranges * np.sin(ang)
    cells = grid.spec.world_to_cell(np.column_stack([x[ok], y[ok]]))
    return float(near[cells[:, 1] + slack, cells[:, 0] + slack].mean()), int(ok.sum())


def test_demo_accuracy(tmp_path):
    demo = run_mapping_demo(tmp_path / "demo")
    print(f"demo accuracy {demo.accuracy:.4f} over {demo.cells_classified} cells")
    assert demo.accuracy >= 0.98 and demo.cells_classified > 50_000
    assert (tmp_path / "demo.yaml").exists()


def test_intel_corrected_map(shared_data, tmp_path):
    from probmap.datasets.carmen import load_scans

    log = shared_data("intel-research-lab/intel-corrected.log.gz")
    cfg = MappingConfig(resolution=0.05)
    result = map_log(log, cfg)
    batch = load_scans(log, poses="corrected")
    assert result.stats.scans == 910
    rate, n = endpoint_hit_rate(
        result.grid,
        np.asarray(batch.laser_poses),
        batch.ranges,
        np.asarray(batch.angles),
        batch.max_range,
    )
    print(f"Intel corrected: {100 * rate:.2f} % of {n} endpoints in occupied cells (1-cell slack)")
    assert n > 100_000
    assert rate >= 0.90
