"""The semantic mapping demo (probmap.pipelines.semantic): scores and the map files it writes."""

from __future__ import annotations

from probmap.pipelines.semantic import run_semantic_demo


def test_demo_writes_maps(tmp_path):
    out = run_semantic_demo(tmp_path / "demo")
    assert min(out["iou"].values()) >= 0.95
    assert out["calibration error"] < 0.1
    names = sorted(p.split("/")[-1] for p in out["files"])
    assert names == [
        "semantic.npz",
        "semantic.occupancy.npz",
        "semantic.occupancy.pgm",
        "semantic.occupancy.plot.png",
        "semantic.occupancy.png",
        "semantic.occupancy.yaml",
        "semantic.png",
    ]
    from probmap.grid.io import read_map_server
    from probmap.grid.semantic_io import load_semantic

    grid = load_semantic(tmp_path / "demo" / "semantic.npz")
    occ = read_map_server(tmp_path / "demo" / "semantic.occupancy.yaml")
    assert occ.spec.shape == grid.spec.shape
    # the map_server occupancy agrees with p(occupied) = 1 - p(free)
    cls = occ.classify()
    p_occ = 1.0 - grid.probabilities()[..., 0]
    assert (p_occ[cls == 1] > 0.65).all() and (p_occ[cls == 0] < 0.196).all()
