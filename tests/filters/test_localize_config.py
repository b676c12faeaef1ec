"""``probmap localize --config FILE.yaml``: the settings from a file, options over it, and
OUTPUT/config.yaml recording what ran."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.config import load_config
from probmap.pipelines.localize import LocalizeConfig
from probmap.sim.localization import simulate_localization_world

register(app)


def test_localize_config_file_and_record(tmp_path):
    spec = importlib.util.spec_from_file_location(
        "_loc_cli2", Path(__file__).parent / "test_localize_cli.py"
    )
    assert spec is not None and spec.loader is not None
    helpers = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(helpers)
    world = simulate_localization_world(0)
    log = helpers._write_log(tmp_path / "sim.log", world, 60)
    runner = CliRunner()
    res = runner.invoke(app, ["map", str(log), "-o", str(tmp_path / "map"), "--max-range", "8"])
    assert res.exit_code == 0, res.output
    (tmp_path / "loc.yaml").write_text("n_particles: 250\nseed: 4\nbeam_step: 2\n")
    args = [
        "localize",
        str(tmp_path / "map.yaml"),
        str(log),
        "--config",
        str(tmp_path / "loc.yaml"),
    ]
    res = runner.invoke(app, [*args, "-o", str(tmp_path / "a")])
    assert res.exit_code == 0, res.output
    want = LocalizeConfig(n_particles=250, seed=4, beam_step=2)
    assert load_config(LocalizeConfig, tmp_path / "a" / "config.yaml") == want
    res = runner.invoke(app, [*args, "-o", str(tmp_path / "b"), "--particles", "300"])
    assert res.exit_code == 0, res.output
    got = load_config(LocalizeConfig, tmp_path / "b" / "config.yaml")
    assert got == LocalizeConfig(n_particles=300, seed=4, beam_step=2)


def test_kld_sampling_adapts_the_particle_count():
    import numpy as np

    from probmap.pipelines.localize import localize_scans
    from probmap.sim.localization import simulate_localization_world

    with pytest.raises(ValueError, match="kld_min"):
        LocalizeConfig(kld_min=0)
    w = simulate_localization_world(0)
    n = 120
    cfg = LocalizeConfig(n_particles=2000, initial_pose=tuple(w.poses[0]), kld_min=100)
    run = localize_scans(
        w.spec, w.occupied.astype(float), 0.2 * np.arange(n), w.ranges[:n], w.angles,
        w.odometry[:n], w.max_range, cfg,
    )  # fmt: skip
    assert run.particles is not None and 100 <= run.particles.shape[0] < 2000  # tight: fewer
    err = np.hypot(*(run.poses[:, :2] - w.poses[run.scan_index, :2]).T)
    assert np.median(err) < 0.1


@pytest.mark.parametrize(
    ("field", "value"),
    [("converged_see_through", 1.5), ("converged_see_through", -0.1),
     ("see_through_margin", -0.5), ("see_through_margin", float("nan"))],
)  # fmt: skip
def test_see_through_bounds_are_checked(field, value):
    with pytest.raises(ValueError, match=field):
        LocalizeConfig(**{field: value})
