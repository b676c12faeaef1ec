"""CLI of MAP mapping: ``probmap fit-sensor-model`` (YAML round trip, bad input) and
``run_map_method`` (the body of ``probmap map --method map``) on a small synthetic log."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer
import yaml
from typer.testing import CliRunner

from probmap.cli import register
from probmap.cli.app import app
from probmap.cli.common import cli_errors

register(app)
runner = CliRunner()


def _write_room_log(path: Path, n_scans: int = 30, seed: int = 0) -> None:
    """A 6 x 4 m box room scanned from a line of poses, with a little range noise."""
    from probmap.grid.raycast import cast_rays
    from probmap.grid.spec import GridSpec

    spec = GridSpec(0.05, (-1.0, -1.0), (100, 140))
    occ = np.zeros(spec.shape, bool)
    occ[:4, :] = occ[-4:, :] = occ[:, :4] = occ[:, -4:] = True
    angles = -np.pi / 2 + np.arange(180) * np.pi / 180
    rng = np.random.default_rng(seed)
    lines = ["# synthetic log\n", "PARAM robot_frontlaser_offset 0.0 host 0\n"]
    for k in range(n_scans):
        pose = (0.5 + 0.1 * k, 1.5, 0.3 * k)
        r = cast_rays(occ, spec, pose, angles, 81.9)
        r = np.minimum(r + rng.normal(0, 0.02, r.shape), 81.9)
        x, y, th = pose
        txt = " ".join(f"{v:.3f}" for v in r)
        lines.append(f"FLASER 180 {txt} {x} {y} {th} {x} {y} {th} {100 + k} host {100 + k}\n")
    path.write_text("".join(lines))


def test_fit_sensor_model_writes_yaml(tmp_path):
    from probmap.models.beam import BeamModelParams
    from probmap.pipelines.fit import fit_log

    log = tmp_path / "room.clf"
    _write_room_log(log)
    out = tmp_path / "beam.yaml"
    res = runner.invoke(app, ["fit-sensor-model", str(log), "-o", str(out), "-r", "0.05"])
    assert res.exit_code == 0, res.output
    assert "sigma_hit" in res.output and "wrote" in res.output
    doc = yaml.safe_load(out.read_text())["beam_model"]
    params = BeamModelParams(**doc)  # round trip: a valid model
    direct = fit_log(log, resolution=0.05).params
    for k, v in doc.items():
        assert np.isclose(v, getattr(direct, k), rtol=1e-12), k
    assert params.sigma_hit < 0.1  # 2 cm noise plus discretisation at 5 cm
    assert not list(tmp_path.glob("*.tmp"))


def test_fit_sensor_model_bad_input(tmp_path):
    res = runner.invoke(app, ["fit-sensor-model", str(tmp_path / "missing.clf")])
    assert res.exit_code == 1
    assert "no such file" in res.output and "Traceback" not in res.output
    log = tmp_path / "room.clf"
    _write_room_log(log, n_scans=3)
    res = runner.invoke(app, ["fit-sensor-model", str(log), "-o", str(log / "x.yaml")])
    assert res.exit_code == 1 and "not a folder" in res.output  # a missing folder is created
    res = runner.invoke(app, ["fit-sensor-model", str(log), "--every", "0"])
    assert res.exit_code == 1 and "every" in res.output


def _map_app() -> typer.Typer:
    """A stand-in for ``probmap map LOG --method map`` until the lead wires the option."""
    from probmap.cli.map_mapping import run_map_method

    sub = typer.Typer()

    @sub.command()
    def main(log: Path, output: Path = typer.Option(..., "-o")) -> None:
        with cli_errors():
            from probmap.pipelines import MappingConfig

            run_map_method(log, output, MappingConfig(resolution=0.1))

    return sub


def test_map_method_writes_the_log_odds_files(tmp_path):
    from probmap.grid.io import load_npz

    log = tmp_path / "room.clf"
    _write_room_log(log)
    res = runner.invoke(_map_app(), [str(log), "-o", str(tmp_path / "m")])
    assert res.exit_code == 0, res.output
    assert "converged" in res.output and "objective" in res.output
    for ext in ("yaml", "pgm", "npz", "png"):
        assert (tmp_path / f"m.{ext}").stat().st_size > 0
    grid = load_npz(tmp_path / "m.npz")
    cls = grid.classify()
    # the room's walls are occupied, its middle free
    ix, iy = grid.spec.world_to_cell([5.82, 1.5])
    assert cls[iy - 1 : iy + 2, ix - 1 : ix + 2].max() == 1
    ix, iy = grid.spec.world_to_cell([2.5, 1.5])
    assert cls[iy, ix] == 0


def test_map_method_bad_input(tmp_path):
    res = runner.invoke(_map_app(), [str(tmp_path / "nope.clf"), "-o", str(tmp_path / "m")])
    assert res.exit_code == 1 and "no such file" in res.output
    log = tmp_path / "room.clf"
    _write_room_log(log, n_scans=2)
    res = runner.invoke(_map_app(), [str(log), "-o", str(log / "m")])
    assert res.exit_code == 1 and "not a folder" in res.output  # a missing folder is created
    bad = tmp_path / "bad.clf"
    bad.write_text("FLASER 3 1.0 oops\n")
    res = runner.invoke(_map_app(), [str(bad), "-o", str(tmp_path / "m")])
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert str(bad.name) in res.output or "line" in res.output
