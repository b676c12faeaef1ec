"""CLI: ``probmap info BAG`` tables, and one-line errors for missing or corrupt bags."""

from __future__ import annotations

import pytest

pytest.importorskip("rosbags")

from typer.testing import CliRunner  # noqa: E402

from probmap.cli import register  # noqa: E402
from probmap.cli.app import app  # noqa: E402
from probmap.datasets.ros.maps import write_map_to_bag  # noqa: E402
from probmap.grid.occupancy import OccupancyGrid  # noqa: E402

register(app)
runner = CliRunner()


def info(path) -> tuple[int, str]:
    res = runner.invoke(app, ["info", str(path)], env={"COLUMNS": "200"})
    return res.exit_code, res.output


def small_grid() -> OccupancyGrid:
    import numpy as np

    grid = OccupancyGrid(0.1)
    grid.integrate_scans(
        np.zeros((1, 3)), np.full((1, 5), 2.0), np.linspace(-0.5, 0.5, 5), max_range=5.0
    )
    return grid


@pytest.mark.parametrize("name", ["map.bag", "map_ros2"])
def test_info_lists_the_written_map_topic(tmp_path, name):
    out = write_map_to_bag(tmp_path / name, small_grid(), topic="/map", frame_id="world", stamp=3.0)
    code, text = info(out)
    assert code == 0, text
    assert "/map" in text and "nav_msgs/OccupancyGrid" in text and "world" in text
    assert ("ROS 1 bag" if name.endswith(".bag") else "ROS 2 bag") in text
    assert "laser topics  none" in text


def test_info_errors_are_one_line(tmp_path):
    code, text = info(tmp_path / "missing.bag")
    assert code == 1 and text.startswith("error:") and "missing.bag" in text
    bad = tmp_path / "bad.bag"
    bad.write_bytes(b"not a bag at all")
    code, text = info(bad)
    assert code == 1 and "bad.bag" in text and "corrupt or truncated" in text
    assert "Traceback" not in text and len(text.strip().splitlines()) == 1


@pytest.mark.realdata
def test_info_on_the_real_backpack_bag(shared_data):
    code, text = info(shared_data("ros-bags/b0-2014-07-21-12-42-53-short.bag"))
    assert code == 0, text
    for want in (
        "horizontal_laser_2d",
        "sensor_msgs/MultiEchoLaserScan",
        "1,974",
        "345",
        "385",
        "horizontal_laser_link",
        "9.995 s",
    ):
        assert want in text


def test_probmap_map_on_a_simulated_bag_and_to_bag(tmp_path):
    """``probmap map BAG -o PREFIX --to-bag OUT`` maps a bag like the simulator's own poses."""
    from test_rosbag import write_sim_bag

    from probmap.cli import register
    from probmap.cli.app import app
    from probmap.datasets.ros.maps import read_map_from_bag
    from probmap.grid.io import load_npz
    from probmap.sim.floorplan import simulate_laser_world

    register(app)
    world = simulate_laser_world(seed=3, size=(8.0, 12.0), range_noise=0.01)
    bag = write_sim_bag(tmp_path / "sim.bag", world, ros=1, source="odom")
    out = tmp_path / "out.bag"
    res = CliRunner().invoke(
        app,
        ["map", str(bag), "-o", str(tmp_path / "m"), "--resolution", "0.1", "--to-bag", str(out)],
    )
    assert res.exit_code == 0, res.output
    grid = load_npz(tmp_path / "m.npz")
    assert f"{len(world.poses)}" in res.output  # scans in the summary table
    assert (grid.classify() == 1).sum() > 500
    back = read_map_from_bag(out)
    assert back is not None
    res = CliRunner().invoke(
        app, ["map", str(bag), "-o", str(tmp_path / "x"), "--scan-topic", "/nope"]
    )
    assert res.exit_code == 1 and "/nope" in res.output and "Traceback" not in res.output
