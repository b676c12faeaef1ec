"""ROS bag reader: tf buffer against hand-composed poses, simulated ROS 1/ROS 2 bags mapped like the
CARMEN-style path, MultiEchoLaserScan fast path against rosbags' own decoder, map round trips,
bad input, and the real Cartographer backpack bag."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from bagwriter import BagBuilder  # noqa: E402
from probmap.datasets.records import LaserScan  # noqa: E402
from probmap.datasets.ros._reader import require_rosbags  # noqa: E402
from probmap.datasets.ros.maps import (  # noqa: E402
    occupancy_percent,
    read_map_from_bag,
    write_map_to_bag,
)
from probmap.datasets.ros.scans import RosBag, is_bag, load_bag_scans  # noqa: E402
from probmap.datasets.ros.summary import summarize_bag  # noqa: E402
from probmap.datasets.ros.tf import TfBuffer, yaw_from_quaternion  # noqa: E402
from probmap.errors import BagError  # noqa: E402
from probmap.pipelines import MappingConfig  # noqa: E402
from probmap.sim.floorplan import simulate_laser_world  # noqa: E402

REAL_BAG = "ros-bags/b0-2014-07-21-12-42-53-short.bag"
OFFSET = np.array([0.20, 0.05, 0.10])  # base_link -> laser mounting (m, m, rad)
T0 = 1_600_000_000.0  # absolute stamps, as real bags have


# ---------------------------------------------------------------------------- helpers


def se2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Reference ``a (+) b`` for one pose, written out."""
    c, s = math.cos(a[2]), math.sin(a[2])
    th = math.atan2(math.sin(a[2] + b[2]), math.cos(a[2] + b[2]))
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], th])


def se2_inv(a: np.ndarray) -> np.ndarray:
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([-c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2]])


@pytest.fixture(scope="module")
def world():
    return simulate_laser_world(seed=3, size=(8.0, 12.0), range_noise=0.01, dropout=0.01)


def write_sim_bag(path: Path, world, *, ros: int, source: str, storage: str = "sqlite3") -> Path:
    """The simulator's tour as a bag: /scan in frame ``laser``, ``odom -> base_link`` from
    /odom (``source="odom"``) or /tf (``"tf"``), a static ``base_link -> laser`` offset."""
    b = BagBuilder(path, ros, storage)
    base = np.array([se2(p, se2_inv(OFFSET)) for p in world.poses])
    b.tf("/tf_static", T0, [("base_link", "laser", OFFSET)])
    amin = float(world.angles[0])
    ainc = float(world.angles[1] - world.angles[0])
    for k, t in enumerate(world.times):
        stamp = T0 + float(t)
        if source == "odom":
            b.odom("/odom", stamp, "odom", "base_link", base[k])
        else:
            b.tf("/tf", stamp, [("odom", "base_link", base[k])])
        b.scan("/scan", stamp, "laser", world.ranges[k], amin, ainc, 0.0, world.max_range)
    b.close()
    return path


def wrapped(p: np.ndarray) -> np.ndarray:
    """Poses with headings in (-pi, pi] (the simulator leaves them unwrapped)."""
    q = np.array(p, dtype=np.float64)
    q[..., 2] = np.arctan2(np.sin(q[..., 2]), np.cos(q[..., 2]))
    return q


def map_of(poses: np.ndarray, ranges: np.ndarray, angles: np.ndarray, max_range: float):
    grid = MappingConfig(resolution=0.1).make_grid()
    grid.integrate_scans(poses, ranges, angles, max_range=max_range)
    return grid


# ---------------------------------------------------------------------------- planar tf


def test_yaw_from_quaternion_matches_rotation_about_z_and_ignores_sign():
    rng = np.random.default_rng(0)
    for th in rng.uniform(-math.pi, math.pi, 50):
        q = (0.0, 0.0, math.sin(th / 2), math.cos(th / 2))
        assert yaw_from_quaternion(*q) == pytest.approx(th, abs=1e-12)
        assert yaw_from_quaternion(*(-v for v in q)) == pytest.approx(th, abs=1e-12)


def test_tf_chain_moving_odom_and_static_laser_interpolates_at_scan_time():
    tf = TfBuffer()
    a, b = np.array([1.0, 2.0, 0.3]), np.array([3.0, 1.0, 0.9])
    tf.add("odom", "base_link", 10.0, a)
    tf.add("odom", "base_link", 12.0, b)
    tf.add("base_link", "laser", 0.0, OFFSET, static=True)
    tf.add("base_link", "camera", 0.0, (-0.1, 0.3, -0.5), static=True)
    for t, w in ((10.0, 0.0), (10.5, 0.25), (11.0, 0.5), (12.0, 1.0)):
        base = (1 - w) * a + w * b
        np.testing.assert_allclose(
            tf.lookup("odom", "laser", [t])[0], se2(base, OFFSET), atol=1e-12
        )
    # siblings meet at base_link: laser in camera = inv(camera) (+) laser, at any time
    want = se2(se2_inv(np.array([-0.1, 0.3, -0.5])), OFFSET)
    np.testing.assert_allclose(tf.lookup("camera", "laser", [11.0])[0], want, atol=1e-12)
    # the inverse direction composes to the identity
    fwd = tf.lookup("odom", "laser", [10.7])[0]
    back = tf.lookup("laser", "odom", [10.7])[0]
    np.testing.assert_allclose(se2(fwd, back), [0, 0, 0], atol=1e-12)
    assert tf.time_range("laser") == (10.0, 12.0)
    assert tf.frames == ["base_link", "camera", "laser", "odom"]


def test_tf_yaw_interpolates_along_the_short_arc():
    tf = TfBuffer()
    tf.add("odom", "base", 0.0, (0.0, 0.0, math.pi - 0.1))
    tf.add("odom", "base", 1.0, (0.0, 0.0, -math.pi + 0.1))
    th = tf.lookup("odom", "base", [0.5])[0, 2]
    assert abs(abs(th) - math.pi) < 1e-12  # through +-pi, not through 0


def test_tf_errors_name_time_link_and_frames():
    tf = TfBuffer()
    tf.add("odom", "base_link", 5.0, (0, 0, 0))
    tf.add("odom", "base_link", 6.0, (1, 0, 0))
    tf.add("base_link", "laser", 0.0, OFFSET, static=True)
    with pytest.raises(ValueError, match=r"time 7\.0+ s .*odom -> base_link"):
        tf.lookup("odom", "laser", [5.5, 7.0])
    with pytest.raises(ValueError, match="'laser' cannot be connected to frame 'map'"):
        tf.lookup("map", "laser", [5.5])
    with pytest.raises(ValueError, match="two parents"):
        tf.add("map", "base_link", 5.0, (0, 0, 0))
    with pytest.raises(ValueError, match="not finite"):
        tf.add("odom", "base_link", 5.5, (math.nan, 0, 0))


# ---------------------------------------------------------------------------- simulated bags


@pytest.mark.parametrize(
    ("ros", "source", "name", "storage"),
    [
        (1, "odom", "sim.bag", "sqlite3"),
        (1, "tf", "sim_tf.bag", "sqlite3"),
        (2, "tf", "sim_db3", "sqlite3"),
        (2, "odom", "sim_mcap", "mcap"),
    ],
)
def test_simulated_bag_maps_like_the_simulator(tmp_path, world, ros, source, name, storage):
    path = write_sim_bag(tmp_path / name, world, ros=ros, source=source, storage=storage)
    batch = load_bag_scans(path)
    assert len(batch) == len(world.poses)
    np.testing.assert_allclose(batch.times, T0 + world.times, atol=1e-6)
    # the laser pose is odom -> base_link (+) base_link -> laser: the simulator's sensor pose
    np.testing.assert_allclose(batch.laser_poses, wrapped(world.poses), atol=1e-9)
    base = np.array([se2(p, se2_inv(OFFSET)) for p in world.poses])
    np.testing.assert_allclose(batch.robot_poses, wrapped(base), atol=1e-9)
    np.testing.assert_allclose(batch.angles, world.angles, atol=1e-6)
    f32 = world.ranges.astype(np.float32).astype(np.float64)
    np.testing.assert_array_equal(batch.ranges, f32)  # NaN dropouts stay NaN
    assert batch.max_range == world.max_range
    ours = map_of(batch.laser_poses, batch.ranges, batch.angles, batch.max_range)
    ref = map_of(world.poses, f32, world.angles, world.max_range)
    assert ours.spec == ref.spec
    same = ours.log_odds == ref.log_odds
    assert same.mean() > 0.999  # angles differ by float32 rounding (< 1e-7 rad) only
    assert (ours.classify(0.5, 0.5) == ref.classify(0.5, 0.5)).mean() > 0.999


def test_storage_file_and_folder_read_alike(tmp_path, world):
    path = write_sim_bag(tmp_path / "b2", world, ros=2, source="tf")
    db3 = next(path.glob("*.db3"))
    a, b = load_bag_scans(path), load_bag_scans(db3)
    np.testing.assert_array_equal(a.laser_poses, b.laser_poses)


def test_records_iteration_length_and_odometry(tmp_path, world):
    path = write_sim_bag(tmp_path / "s.bag", world, ros=1, source="odom")
    bag = RosBag(path)
    assert len(bag) == len(world.poses)
    scans = list(bag)
    assert all(isinstance(s, LaserScan) for s in scans)
    batch = bag.batch()
    np.testing.assert_array_equal(np.array([s.laser_pose for s in scans]), batch.laser_poses)
    assert [s.line for s in scans[:3]] == [1, 2, 3]
    assert scans[0].source == "LaserScan" and scans[0].max_range == world.max_range
    assert scans[5].logger_time == pytest.approx(world.times[5], abs=1e-6)
    # endpoints of a scan land on the true walls' side of the world (inside its bounds)
    ep = scans[10].endpoints()
    assert ((ep >= -0.5) & (ep <= 12.5)).all()
    odo = list(bag.odometry())
    assert len(odo) == len(world.poses)
    base = se2(world.poses[7], se2_inv(OFFSET))
    np.testing.assert_allclose(odo[7].pose, wrapped(base), atol=1e-12)
    assert (odo[7].tv, odo[7].rv) == (0.5, 0.1)
    links = bag.tf_buffer().links()
    assert ("base_link", "laser", True, 1) in links
    assert ("odom", "base_link", False, len(world.poses)) in links


def test_interpolated_tf_between_scans(tmp_path):
    """tf at 10 Hz on a circle, scans in between: poses equal hand interpolation (+) offset."""
    b = BagBuilder(tmp_path / "i.bag", 1)
    b.tf("/tf_static", T0, [("base_link", "laser", OFFSET)])
    ts = np.arange(0.0, 2.01, 0.1)
    base = np.column_stack((np.cos(ts), np.sin(ts), ts + math.pi / 2))
    for t, p in zip(ts, base, strict=True):
        b.tf("/tf", T0 + t, [("odom", "base_link", p)])
    scan_t = np.array([0.05, 0.33, 1.27, 1.99])
    for t in scan_t:
        b.scan("/scan", T0 + t, "laser", np.ones(5), -0.2, 0.1, 0.05, 10.0)
    b.close()
    batch = load_bag_scans(tmp_path / "i.bag")
    for k, t in enumerate(scan_t):
        j = int(np.searchsorted(ts, t)) - 1
        w = (t - ts[j]) / (ts[j + 1] - ts[j])
        p = (1 - w) * base[j] + w * base[j + 1]
        np.testing.assert_allclose(batch.robot_poses[k], se2(p, np.zeros(3)), atol=1e-6)
        np.testing.assert_allclose(batch.laser_poses[k], se2(p, OFFSET), atol=1e-6)


def test_range_limits_respected(tmp_path):
    b = BagBuilder(tmp_path / "r.bag", 1)
    b.scan("/scan", T0, "laser", [0.01, 0.5, np.inf, 12.0, np.nan, -np.inf, 9.5], -1, 0.5, 0.1, 10)
    b.close()
    batch = load_bag_scans(tmp_path / "r.bag", fixed_frame="laser")
    np.testing.assert_array_equal(batch.ranges[0], [np.nan, 0.5, 10, 10, np.nan, np.nan, 9.5])
    np.testing.assert_allclose(batch.angles, -1 + 0.5 * np.arange(7))
    np.testing.assert_array_equal(batch.laser_poses, np.zeros((1, 3)))


def test_multiecho_fast_path_matches_rosbags_decoder(tmp_path):
    rng = np.random.default_rng(1)
    b = BagBuilder(tmp_path / "m.bag", 1)
    regular = [[float(x)] for x in rng.uniform(0.5, 20, 40)]
    ragged = [list(rng.uniform(0.5, 20, k)) for k in rng.integers(0, 4, 40)]
    b.multiecho("/echo", T0, "laser", regular, -0.2)
    b.multiecho("/echo", T0 + 0.1, "laser", ragged, -0.2)
    b.close()

    def reference(echo: int) -> list[np.ndarray]:
        out = []
        with AnyReader([tmp_path / "m.bag"]) as r:
            for c, _, raw in r.messages():
                m = r.deserialize(raw, c.msgtype)
                out.append(
                    np.array(
                        [e.echoes[echo] if len(e.echoes) > echo else np.nan for e in m.ranges],
                        dtype=np.float64,
                    )
                )
        return out

    for echo in (0, 1):
        batch = load_bag_scans(tmp_path / "m.bag", fixed_frame="laser", echo=echo)
        ref = reference(echo)
        for k in range(2):
            np.testing.assert_array_equal(batch.ranges[k], ref[k])
    assert np.isnan(load_bag_scans(tmp_path / "m.bag", fixed_frame="laser").ranges[0]).sum() == 0


def test_multiecho_ros2_reads_the_chosen_echo(tmp_path):
    b = BagBuilder(tmp_path / "m2", 2)
    b.multiecho("/echo", T0, "laser", [[1.0, 2.0], [3.0], []], 0.0)
    b.close()
    np.testing.assert_array_equal(
        load_bag_scans(tmp_path / "m2", fixed_frame="laser", echo=1).ranges[0],
        [2.0, np.nan, np.nan],
    )


# ---------------------------------------------------------------------------- discovery


def test_summary_lists_topics_counts_frames_and_times(tmp_path, world):
    path = write_sim_bag(tmp_path / "s.bag", world, ros=1, source="odom")
    s = summarize_bag(path)
    by = {t.topic: t for t in s.topics}
    assert by["/scan"].msgtype == "sensor_msgs/msg/LaserScan"
    assert by["/scan"].count == by["/odom"].count == len(world.poses)
    assert by["/scan"].frames == ("laser",) and by["/odom"].frames == ("odom",)
    assert by["/tf_static"].frames == ("laser",)
    assert by["/scan"].end == pytest.approx(T0 + world.times[-1], abs=1e-6)
    assert s.duration == pytest.approx(world.times[-1], abs=1e-6)
    assert s.frames == ("base_link", "laser", "odom")
    assert s.ros_version == 1


# ---------------------------------------------------------------------------- writing maps


@pytest.mark.parametrize(("name", "storage"), [("m.bag", "sqlite3"), ("m2", "mcap")])
def test_map_round_trip_through_a_bag(tmp_path, world, name, storage):
    grid = map_of(world.poses, world.ranges, world.angles, world.max_range).cropped()
    out = write_map_to_bag(tmp_path / name, grid, topic="/map", stamp=T0 + 1.5, storage=storage)
    got = read_map_from_bag(out)
    want = occupancy_percent(grid)
    np.testing.assert_array_equal(got.data, want)
    assert (want == -1).any() and (want > 65).any() and ((want >= 0) & (want < 20)).any()
    assert got.resolution == pytest.approx(grid.spec.resolution)
    np.testing.assert_allclose(got.origin, [*grid.spec.origin, 0.0])
    assert got.frame_id == "map" and got.time == pytest.approx(T0 + 1.5)
    # readable by rosbags alone, as any ROS tool would
    with AnyReader([out]) as r:
        assert [c.msgtype for c in r.connections] == ["nav_msgs/msg/OccupancyGrid"]
    assert list(tmp_path.glob(".probmap-bag-*")) == []  # no temp left behind
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_map_writer_refuses_an_existing_ros2_folder_and_a_missing_folder(tmp_path, world):
    grid = map_of(world.poses[:5], world.ranges[:5], world.angles, world.max_range)
    (tmp_path / "exists").mkdir()
    with pytest.raises(FileExistsError, match="exists"):
        write_map_to_bag(tmp_path / "exists", grid)
    with pytest.raises(FileNotFoundError, match="nope"):
        write_map_to_bag(tmp_path / "nope" / "m.bag", grid)


# ---------------------------------------------------------------------------- bad input


def test_corrupt_and_truncated_bags_name_the_file(tmp_path, world):
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    with pytest.raises(BagError, match=r"junk\.bag.*corrupt or truncated"):
        load_bag_scans(junk)
    good = write_sim_bag(tmp_path / "g.bag", world, ros=1, source="odom")
    cut = tmp_path / "cut.bag"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(BagError, match=r"cut\.bag.*corrupt or truncated"):
        load_bag_scans(cut)
    for storage in ("sqlite3", "mcap"):
        folder = write_sim_bag(
            tmp_path / f"r2{storage}", world, ros=2, source="tf", storage=storage
        )
        store = next(f for f in folder.iterdir() if f.suffix in (".db3", ".mcap"))
        store.write_bytes(store.read_bytes()[:3000])
        with pytest.raises(BagError, match=rf"r2{storage}.*corrupt or truncated"):
            load_bag_scans(folder)
    with pytest.raises(BagError, match=r"not a ROS bag"):
        (tmp_path / "x.txt").write_text("hello")
        load_bag_scans(tmp_path / "x.txt")
    with pytest.raises(FileNotFoundError, match="missing.bag"):
        load_bag_scans(tmp_path / "missing.bag")


def test_missing_topic_and_unplaceable_scans_name_topic_frame_and_time(tmp_path, world):
    path = write_sim_bag(tmp_path / "s.bag", world, ros=1, source="odom")
    with pytest.raises(BagError, match=r"no topic '/lidar'.*/scan \(sensor_msgs/msg/LaserScan\)"):
        load_bag_scans(path, scan_topic="/lidar")
    with pytest.raises(BagError, match=r"topic '/odom' holds nav_msgs/msg/Odometry"):
        load_bag_scans(path, scan_topic="/odom")
    with pytest.raises(BagError, match=r"'/scan'.*'laser' cannot be connected to frame 'map'"):
        load_bag_scans(path, fixed_frame="map")
    with pytest.raises(BagError, match=r"'/scan'.*'lidar_link' cannot be connected"):
        load_bag_scans(path, laser_frame="lidar_link")
    # a scan after the last odometry message
    b = BagBuilder(tmp_path / "late.bag", 1)
    b.odom("/odom", T0, "odom", "laser", np.zeros(3))
    b.odom("/odom", T0 + 1, "odom", "laser", np.ones(3))
    b.scan("/scan", T0 + 0.5, "laser", np.ones(3), 0.0, 0.1, 0.0, 5.0)
    b.scan("/scan", T0 + 2.5, "laser", np.ones(3), 0.0, 0.1, 0.0, 5.0)
    b.close()
    # ... is dropped with a count and a warning (tf is not extrapolated); the rest is read
    with pytest.warns(UserWarning, match=r"dropped 1 scan\(s\) stamped .* after the last"):
        late = load_bag_scans(tmp_path / "late.bag")
    assert late.times.tolist() == [T0 + 0.5]
    # a bag whose every scan lies outside the tf buffer still names the topic and the time
    b = BagBuilder(tmp_path / "later.bag", 1)
    b.odom("/odom", T0, "odom", "laser", np.zeros(3))
    b.odom("/odom", T0 + 1, "odom", "laser", np.ones(3))
    b.scan("/scan", T0 + 2.5, "laser", np.ones(3), 0.0, 0.1, 0.0, 5.0)
    b.close()
    with pytest.raises(BagError, match=r"'/scan'.*time 1600000002\.5.*outside the tf buffer"):
        load_bag_scans(tmp_path / "later.bag")
    # no pose source at all
    b = BagBuilder(tmp_path / "bare.bag", 1)
    b.scan("/scan", T0, "laser", np.ones(3), 0.0, 0.1, 0.0, 5.0)
    b.close()
    with pytest.raises(BagError, match=r"no tf link and no nav_msgs/Odometry.*'laser'"):
        load_bag_scans(tmp_path / "bare.bag")
    with pytest.raises(ValueError, match="echo"):
        RosBag(path, echo=-1)


def test_missing_rosbags_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "rosbags", None)
    with pytest.raises(ImportError, match=r"pip install 'probmap\[ros\]'"):
        require_rosbags()


# ---------------------------------------------------------------------------- the real bag


@pytest.mark.realdata
def test_real_backpack_bag_topics_counts_and_scan_geometry(shared_data):
    path = shared_data(REAL_BAG)
    s = summarize_bag(path)
    counts = {t.topic: (t.msgtype, t.count) for t in s.topics}
    assert counts == {
        "imu": ("sensor_msgs/msg/Imu", 1974),
        "horizontal_laser_2d": ("sensor_msgs/msg/MultiEchoLaserScan", 345),
        "vertical_laser_2d": ("sensor_msgs/msg/MultiEchoLaserScan", 385),
    }
    assert s.messages == 2704 and s.duration == pytest.approx(9.995, abs=1e-3)
    assert s.frames == ("horizontal_laser_link", "imu_link", "vertical_laser_link")
    assert s.tf_links == ()
    batch = load_bag_scans(
        path, scan_topic="horizontal_laser_2d", fixed_frame="horizontal_laser_link"
    )
    assert batch.ranges.shape == (345, 1079)
    assert batch.angles.shape == (1079,)
    assert batch.angles[0] == pytest.approx(-2.3518, abs=1e-4)
    assert batch.angles[-1] == pytest.approx(2.3518, abs=1e-4)
    np.testing.assert_allclose(np.diff(batch.angles), math.radians(0.25), rtol=1e-6)
    assert batch.max_range == 60.0
    assert np.nanmin(batch.ranges) >= 0.023 and np.nanmax(batch.ranges) <= 60.0
    np.testing.assert_array_equal(batch.laser_poses, 0.0)
    assert len(RosBag(path, scan_topic="vertical_laser_2d")) == 385
    # the fast decoder against rosbags' own message objects, on the first scans
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS1_NOETIC)) as r:
        conns = [c for c in r.connections if c.topic == "horizontal_laser_2d"]
        for k, (c, _, raw) in enumerate(r.messages(connections=conns)):
            m = r.deserialize(raw, c.msgtype)
            ref = np.array([e.echoes[0] for e in m.ranges], dtype=np.float64)
            ref = np.where(ref >= m.range_max, m.range_max, ref)
            ref[~(ref >= m.range_min)] = np.nan
            np.testing.assert_array_equal(batch.ranges[k], ref)
            stamp = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
            assert batch.times[k] == pytest.approx(stamp, abs=1e-6)
            if k == 4:
                break
    with pytest.raises(BagError, match="2 scan topics"):
        load_bag_scans(path)


def test_is_bag_and_resolved_frames(tmp_path, world):
    path = write_sim_bag(tmp_path / "s.bag", world, ros=1, source="tf")
    assert is_bag(path) and not is_bag(tmp_path / "log.clf.gz")
    bag = RosBag(path)
    assert bag.resolved_frames is None
    bag.batch()
    assert bag.resolved_frames == ("odom", "base_link", "laser")
    assert RosBag(path).resolve_frames() == ("odom", "base_link", "laser")
    assert RosBag(path, fixed_frame="laser").resolve_frames() == ("laser", "laser", "laser")
    b2 = write_sim_bag(tmp_path / "d", world, ros=2, source="odom")
    assert is_bag(b2) and not is_bag(tmp_path)
