"""``probmap localize --config FILE.yaml``: the settings from a file, options over it, and
OUTPUT/config.yaml recording what ran."""

from __future__ import annotations

import dataclasses
import importlib.util
import math
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

    from probmap.filters.mcl import FreeSpaceSampler
    from probmap.models.likelihood_field import LikelihoodField
    from probmap.pipelines.localize import global_particle_count, localize_scans
    from probmap.sim.localization import simulate_localization_world

    for bad in ({"particle_density": 0.0}, {"particle_density": float("nan")},
                {"max_particles": 0}):  # fmt: skip
        with pytest.raises(ValueError, match=next(iter(bad))):
            LocalizeConfig(**bad)
    cfg = LocalizeConfig(n_particles=100, particle_density=2.0, max_particles=5000)
    assert global_particle_count(cfg, 1000.0) == 2000  # 2 per m2
    assert global_particle_count(cfg, 10.0) == 100  # never fewer than n_particles
    assert global_particle_count(cfg, 1e6) == 5000  # at most max_particles
    assert global_particle_count(dataclasses.replace(cfg, n_particles=9000), 1e6) == 9000

    w = simulate_localization_world(0)
    n = 200
    args = (w.spec, w.occupied.astype(float), 0.2 * np.arange(n), w.ranges[:n], w.angles,
            w.odometry[:n], w.max_range)  # fmt: skip
    # global: the density's count over the map's free space until the claim, then fewer
    g = localize_scans(*args, LocalizeConfig(n_particles=300, global_localization=True))
    lf = LikelihoodField(w.spec, w.occupied.astype(float), max_range=w.max_range)
    area = FreeSpaceSampler(w.spec, ~w.occupied & (lf.distance > 0.15)).cells.size * 0.05**2
    start = global_particle_count(LocalizeConfig(n_particles=300), area)
    assert start == round(30 * area) or start == math.ceil(30 * area)
    c = g.converged_index
    assert g.localized and c is not None
    assert np.all(g.particle_count[: c - 30] == start)  # the search keeps its count
    assert g.particle_count[-1] < start / 3 and g.particle_count.min() >= 300
    err = np.hypot(*(g.poses[c:, :2] - w.poses[g.scan_index[c:], :2]).T)
    assert np.median(err) < 0.1
    # tracking: a tight cloud keeps n_particles, and runs as without KLD-sampling until the
    # cloud spreads over more bins than n_particles covers (Table 8.4's bound)
    cfg = LocalizeConfig(n_particles=500, initial_pose=tuple(w.poses[0]))
    on, off = (localize_scans(*args, dataclasses.replace(cfg, kld=k)) for k in (True, False))
    assert np.median(on.particle_count) == 500 and on.particle_count.max() > 500
    same = int(np.argmax(on.particle_count > 500))  # the first update that drew more
    np.testing.assert_array_equal(on.poses[: same + 1], off.poses[: same + 1])
    assert np.all(off.particle_count == 500)
    for run in (on, off):
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
