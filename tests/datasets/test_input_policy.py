"""One input policy (issue 20): the reading classes, pose plausibility, decode errors, NaN
rejection at construction, and fuzzing of the text readers (only DatasetError/ValueError)."""

from __future__ import annotations

import math
import string
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from probmap.datasets.carmen import CarmenLog, load_scans
from probmap.datasets.g2o import read_pose_graph
from probmap.datasets.landmarks import read_numeric_table
from probmap.datasets.ros.scans import _validated_ranges
from probmap.datasets.validate import (
    PoseLimits,
    PoseTracker,
    ReadingReport,
    require_usable,
    text_lines,
    validate_ranges,
)
from probmap.errors import BadLinesWarning, DatasetError, MapFileError

# --------------------------------------------------------------------------- log writers


def flaser(ranges, pose=(0.0, 0.0, 0.0), t=100.0, kind="FLASER"):
    r = " ".join(repr(float(v)) for v in ranges)
    p = " ".join(repr(float(v)) for v in (*pose, *pose))
    return f"{kind} {len(ranges)} {r} {p} {t!r} host {t - 50.0!r}\n"


def odom(pose, t):
    x, y, th = pose
    return f"ODOM {x!r} {y!r} {th!r} 0.5 0.1 0.0 {t!r} host {t - 50.0!r}\n"


def robotlaser(ranges, *, res=0.0174533, pose=(0.0, 0.0, 0.0), t=100.0):
    r = " ".join(repr(float(v)) for v in ranges)
    p = " ".join(repr(float(v)) for v in (*pose, *pose))
    return (
        f"ROBOTLASER1 0 -1.5664 3.141593 {res!r} 81.9 0.01 0 {len(ranges)} {r} 0 {p} "
        f"0.3 0.05 0.6 0.3 0.25 {t!r} host {t - 7.0!r}\n"
    )


def walk(n=20, beams=180, value=3.0, step=0.05, dt=0.1):
    """A robot driving along x at 0.5 m/s, every reading ``value``."""
    return [flaser([value] * beams, (step * i, 0.0, 0.0), 100.0 + dt * i) for i in range(n)]


def write(path: Path, lines) -> Path:
    path.write_text("".join(lines))
    return path


# --------------------------------------------------------------------------- reading classes


def test_every_reading_falls_in_one_class_and_is_cleaned():
    r = np.array([[2.0, 0.0, -1.0, np.nan, np.inf, -np.inf, 90.0, 81.9, 5.0]])
    before = r.copy()
    cleaned, rep = validate_ranges(r, 81.9)
    assert np.array_equal(r, before, equal_nan=True)  # the input is not modified
    assert (rep.readings, rep.usable, rep.no_return, rep.zero, rep.invalid) == (9, 2, 3, 1, 3)
    assert rep.dropped == 4 and rep.scans == 1
    np.testing.assert_array_equal(
        cleaned, [[2.0, np.nan, np.nan, np.nan, 81.9, np.nan, 90.0, 81.9, 5.0]]
    )
    assert "2 usable, 3 no return, 4 dropped (1 zero, 3 NaN/-inf/negative)" in rep.describe()


def test_clean_ranges_are_returned_as_they_are():
    r = np.full((3, 4), 2.0)
    cleaned, rep = validate_ranges(r, 80.0)
    assert cleaned is r and rep.usable == 12


def test_inf_in_float32_stays_no_return():
    r = np.array([[np.inf, 1.0]], dtype=np.float32)
    cleaned, rep = validate_ranges(r, 81.9)  # 81.9 is not a float32: rounded up, never down
    assert cleaned.dtype == np.float32 and float(cleaned[0, 0]) >= 81.9
    assert rep.no_return == 1 and rep.usable == 1


def test_padding_is_no_reading_and_beam_counts_are_reported():
    r = np.full((131, 181), 3.0)
    r[:130, 180] = np.nan  # 130 scans of 180 beams, one of 181
    beams = np.array([180] * 130 + [181])
    _, rep = validate_ranges(r, 80.0, beams=beams)
    assert rep.readings == 130 * 180 + 181 == rep.usable and rep.invalid == 0
    assert rep.beam_counts == ((180, 130), (181, 1))
    assert rep.describe().endswith("180 beams x 130 scans, 181 beams x 1 scan")


def test_reports_add_up():
    a = ReadingReport(1, 3, 1, 1, 1, 0, ((3, 1),), 2)
    b = ReadingReport(2, 8, 8, 0, 0, 0, ((4, 2),), 1)
    s = a + b
    assert (s.scans, s.readings, s.usable, s.skipped_lines) == (3, 11, 9, 3)
    assert s.beam_counts == ((4, 2), (3, 1))


def test_validate_ranges_checks_its_arguments():
    with pytest.raises(ValueError, match="max_range"):
        validate_ranges(np.ones((1, 2)), math.nan)
    with pytest.raises(ValueError, match="beams"):
        validate_ranges(np.ones((2, 2)), 5.0, beams=[2])


def test_no_usable_reading_is_an_error_naming_the_file():
    _, rep = validate_ranges(np.zeros((4, 3)), 80.0)
    with pytest.raises(DatasetError, match=r"^log\.clf: no usable laser reading in 4 scans"):
        require_usable(rep, "log.clf", 80.0)


@pytest.mark.parametrize(
    ("value", "cls"),
    [(0.0, "zero"), (-1.0, "invalid"), ("nan", "invalid"), ("-inf", "invalid"), (81.9, "no")],
)
def test_carmen_batches_apply_the_rule(tmp_path, value, cls):
    lines = walk(5, beams=4)
    lines.insert(2, flaser([2.0, float(value), 2.0, 2.0], (0.07, 0.0, 0.0), 100.15))
    batch = load_scans(write(tmp_path / "x.clf", lines))
    rep = batch.readings
    assert rep is not None and rep.readings == 24 and rep.usable == 23
    assert {"zero": rep.zero, "invalid": rep.invalid, "no": rep.no_return}[cls] == 1
    row = np.asarray(batch.ranges)[2]
    if cls == "no":
        assert row[1] >= batch.max_range
    else:
        assert np.isnan(row[1])  # dropped the same way for every command


def test_carmen_inf_is_no_return(tmp_path):
    lines = walk(3, beams=2)
    lines.append(flaser([np.inf, 1.0], (0.2, 0.0, 0.0), 100.3))
    batch = load_scans(write(tmp_path / "x.clf", lines))
    assert batch.readings.no_return == 1
    assert float(np.asarray(batch.ranges)[-1, 0]) == batch.max_range


def test_bag_ranges_follow_the_same_classes():
    r = np.array([0.0, 0.05, -1.0, np.nan, np.inf, 40.0, 5.0])
    out, rep = _validated_ranges(r, 0.1, 30.0)
    assert (rep.usable, rep.no_return, rep.zero, rep.invalid) == (1, 2, 1, 3)
    np.testing.assert_array_equal(out, [np.nan, np.nan, np.nan, np.nan, 30.0, 30.0, 5.0])


def test_mixed_beam_counts_are_not_dropped_readings(tmp_path):
    from probmap.pipelines import MappingConfig, map_log

    lines = walk(30)
    lines.insert(10, flaser([3.0] * 181, (0.48, 0.0, 0.0), 100.95))
    res = map_log(write(tmp_path / "mixed.clf", lines), MappingConfig(resolution=0.1))
    assert res.stats.beams == 30 * 180 + 181 and res.stats.dropped == 0
    assert res.readings.beam_counts == ((180, 30), (181, 1))


@pytest.mark.parametrize("value", [0.0, -2.0, "nan", 81.9])
def test_a_log_without_usable_readings_fails_in_every_pipeline(tmp_path, value):
    from probmap.pipelines import MappingConfig, map_log, map_log_map
    from probmap.pipelines.fit import fit_log
    from probmap.pipelines.laser_slam import load_laser_log, slam_log

    path = write(tmp_path / "blind.clf", walk(12, beams=20, value=float(value)))
    calls = [
        lambda: map_log(path, MappingConfig(resolution=0.1)),
        lambda: map_log_map(path, MappingConfig(resolution=0.1)),
        lambda: fit_log(path, resolution=0.1),
        lambda: load_laser_log(path),
        lambda: slam_log(path),
    ]
    for call in calls:
        with pytest.raises(DatasetError, match=rf"^{path}: no usable laser reading in 12 scans"):
            call()


def test_zero_ranges_mean_the_same_to_localize_and_fit(tmp_path):
    lines = walk(15, beams=8)
    lines[5] = flaser([0.0] * 4 + [3.0] * 4, (0.25, 0.0, 0.0), 100.5)
    batch = load_scans(write(tmp_path / "z.clf", lines), poses="odometry")
    row = np.asarray(batch.ranges)[5]
    assert np.isnan(row[:4]).all() and batch.readings.zero == 4  # not readings at 0 m


def test_fit_log_reports_readings(tmp_path):
    from probmap.pipelines.fit import fit_log

    got = []
    lines = walk(40, beams=30)
    lines[3] = flaser([0.0] + [3.0] * 29, (0.15, 0.0, 0.0), 100.3)
    fit_log(write(tmp_path / "f.clf", lines), resolution=0.1, readings=got.append)
    assert len(got) == 1 and got[0].zero == 1 and got[0].readings == 1200


# --------------------------------------------------------------------------- bad lines


def test_robotlaser_with_zero_resolution_is_a_bad_line(tmp_path):
    lines = [robotlaser([2.0] * 5, t=100.0), robotlaser([2.0] * 5, res=0.0, t=100.5)]
    path = write(tmp_path / "rl.clf", lines)
    with pytest.raises(DatasetError) as info:
        load_scans(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}, line 2, field 'angular_resolution'"), msg
    with pytest.warns(BadLinesWarning):
        batch = load_scans(path, skip_bad_lines=True)
    assert len(batch) == 1 and batch.skipped_lines == 1 and batch.readings.skipped_lines == 1


@pytest.mark.parametrize(
    ("pose", "field", "needle"),
    [
        ((1e7, 0.0, 0.0), "x", "plausible extent"),
        ((0.0, -1e7, 0.0), "y", "plausible extent"),
        ((0.55, 1000.0, 0.0), "y", "jumps"),
        ((0.55, 0.0, 3.0), "theta", "turns"),
    ],
)
def test_implausible_pose_is_a_bad_line(tmp_path, pose, field, needle):
    lines = walk(20)
    lines[11] = flaser([3.0] * 180, pose, 101.1)
    path = write(tmp_path / "glitch.clf", lines)
    with pytest.raises(DatasetError) as info:
        load_scans(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}, line 12, field '{field}': implausible FLASER line"), msg
    assert needle in msg
    with pytest.warns(BadLinesWarning, match="skipped 1 bad"):
        batch = load_scans(path, skip_bad_lines=True)
    assert len(batch) == 19 and batch.skipped_lines == 1


def test_implausible_odometry_is_a_bad_line(tmp_path):
    lines = [odom((0.01 * i, 0.0, 0.0), 100.0 + 0.1 * i) for i in range(10)]
    lines[4] = odom((5000.0, 0.0, 0.0), 100.4)
    lines += walk(3)
    path = write(tmp_path / "odo.clf", lines)
    with pytest.raises(DatasetError, match=r"line 5, field 'x': implausible ODOM line"):
        list(CarmenLog(path).odometry())
    log = CarmenLog(path, skip_bad_lines=True)
    with pytest.warns(BadLinesWarning):
        assert len(list(log.odometry())) == 9


def test_slow_but_long_motion_is_plausible(tmp_path):
    # 50 m in 10 s (a gap in the log): within 10 m + 20 m/s
    lines = walk(5)
    lines.append(flaser([3.0] * 180, (50.0, 0.0, 0.0), 110.0))
    assert len(load_scans(write(tmp_path / "gap.clf", lines))) == 6


def test_pose_limits_are_configurable(tmp_path):
    path = write(tmp_path / "w.clf", walk(10))
    assert len(load_scans(path)) == 10
    tight = PoseLimits(max_step=0.01, max_speed=0.1)
    with pytest.raises(DatasetError, match="line 2, field 'x'"):
        load_scans(path, pose_limits=tight)
    with pytest.raises(DatasetError, match="plausible extent"):
        load_scans(path, pose_limits=PoseLimits(max_coordinate=0.2))
    off = PoseLimits(*(math.inf,) * 5)
    assert PoseTracker(off).check("s", 0.0, 1e300, 0.0, 0.0) is None


@pytest.mark.parametrize("bad", [math.nan, 0.0, -1.0, True, "1"])
def test_pose_limits_reject_nonsense(bad):
    with pytest.raises(ValueError, match="max_speed"):
        PoseLimits(max_speed=bad)


REAL_LOGS = {
    "intel-research-lab/intel.clf.bz2": 13631,
    "intel-research-lab/intel-corrected.log.gz": 910,
    "freiburg-clinic/fr-clinic_robotlaser.clf.bz2": 6917,
    "freiburg-campus/freiburg-campus-corrected.log.gz": 2008,
}


@pytest.mark.realdata
@pytest.mark.parametrize("rel", list(REAL_LOGS))
def test_real_logs_pass_untouched(shared_data, rel):
    """Every real log loads whole: no implausible pose, no dropped reading, same scan count.
    (Logs kept aside for evaluation are not tested here: nothing may depend on them.)"""
    path = shared_data(rel)
    for poses in ("corrected", "odometry"):
        batch = load_scans(path, poses=poses)
        assert len(batch) == REAL_LOGS[rel]
        rep = batch.readings
        assert batch.skipped_lines == 0 and rep.dropped == 0 and rep.usable > 0
        assert rep.readings == int(batch.beams.sum())
    log = CarmenLog(path)
    assert sum(1 for _ in log.odometry()) >= 0 and log.skipped_lines == 0


# --------------------------------------------------------------------------- decode errors


def test_text_lines_names_file_line_and_column(tmp_path):
    p = tmp_path / "t.dat"
    p.write_bytes(b"1 2 3\r\n4 5 6\n7 \xff 9\n")
    it = text_lines(p)
    assert next(it) == (1, "1 2 3\n") and next(it) == (2, "4 5 6\n")
    with pytest.raises(DatasetError, match=rf"^{p}, line 3: not a UTF-8 text file: byte 0xff"):
        next(it)


def test_numeric_table_decode_error_names_the_file(tmp_path):
    p = tmp_path / "Robot1_Odometry.dat"
    p.write_bytes(b"# header\n1.0 0.1 0.0\n\xc3\x28 0.1 0.0\n")
    with pytest.raises(DatasetError, match=rf"^{p}, line 3: not a UTF-8"):
        read_numeric_table(p, ("time", "v", "w"))


def test_mrclam_and_victoria_park_decode_errors_name_the_file(tmp_path):
    from probmap.datasets.utias import MRCLAM
    from probmap.datasets.victoria_park import VictoriaPark

    (tmp_path / "Barcodes.dat").write_bytes(b"1 5\n2 \x89PNG\n")
    with pytest.raises(DatasetError, match=r"Barcodes\.dat, line 2: not a UTF-8"):
        MRCLAM(tmp_path, 1)
    (tmp_path / "inputs.dat").write_bytes(b"0.0 1.0 0.0\n\xfe\xff\n")
    with pytest.raises(DatasetError, match=r"inputs\.dat, line 2: not a UTF-8"):
        VictoriaPark(tmp_path, source="dat")


def test_g2o_decode_error_names_the_file(tmp_path):
    p = tmp_path / "g.g2o"
    p.write_bytes(b"VERTEX_SE2 0 0 0 0\n\x80\n")
    with pytest.raises(DatasetError, match=rf"^{p}, line 2: not a UTF-8"):
        read_pose_graph(p)


# --------------------------------------------------------------------------- Python API


def test_localize_config_rejects_nan():
    from probmap.pipelines.localize import LocalizeConfig

    with pytest.raises(ValueError, match="initial_pose"):
        LocalizeConfig(initial_pose=(math.nan, 0.0, 0.0))
    with pytest.raises(ValueError, match="alphas"):
        LocalizeConfig(alphas=(0.1, math.nan, 0.1, 0.1))
    with pytest.raises(ValueError, match="initial_std"):
        LocalizeConfig(initial_std=(0.1, math.inf, 0.1))
    with pytest.raises(ValueError, match="sigma_hit"):
        LocalizeConfig(sigma_hit=math.nan)
    with pytest.raises(ValueError, match="max_range"):
        LocalizeConfig(max_range=math.inf)
    assert LocalizeConfig(initial_pose=(1.0, 2.0, 0.5)).initial_pose == (1.0, 2.0, 0.5)


def test_motion_models_reject_nan():
    from probmap.models.motion import AckermannModel, VelocityModel

    with pytest.raises(ValueError, match="alphas"):
        VelocityModel(alphas=(math.nan, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="sigma_v"):
        VelocityModel(sigma_v=math.nan)
    with pytest.raises(ValueError, match="reference_dt"):
        VelocityModel(reference_dt=math.nan)
    with pytest.raises(ValueError, match="wheelbase"):
        AckermannModel(wheelbase=math.inf)
    with pytest.raises(ValueError, match="reference_point"):
        AckermannModel(reference_point=(math.nan, 0.0))
    VelocityModel()
    AckermannModel()


def _ekf(cov, **cfg):
    from probmap.models.measurement import RangeBearingModel
    from probmap.models.motion import VelocityModel
    from probmap.slam.landmark.ekf import EKFSLAM, EKFConfig

    return EKFSLAM(
        VelocityModel(),
        RangeBearingModel(R=np.diag([0.01, 0.001])),
        np.zeros(3),
        cov,
        EKFConfig(**cfg),
    )


def test_ekf_rejects_what_seif_rejects():
    with pytest.raises(ValueError, match="positive semi-definite"):
        _ekf(-np.eye(3))
    with pytest.raises(ValueError, match="symmetric"):
        _ekf(np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))
    ekf = _ekf(np.zeros((3, 3)))  # an exactly known start stays allowed
    with pytest.raises(ValueError, match="landmark ids must be >= 0, or -1"):
        ekf.update(np.array([[2.0, 0.1]]), np.array([-2]))
    with pytest.raises(ValueError, match="min_range"):
        _ekf(np.eye(3), min_range=math.nan)


def _npz(path, lo):
    from probmap.grid.io import save_npz
    from probmap.grid.occupancy import OccupancyGrid

    grid = OccupancyGrid(0.1)
    grid.integrate_scans(np.zeros((1, 3)), np.full((1, 8), 1.0), np.linspace(-1, 1, 8))
    save_npz(path, grid)
    with np.load(path) as z:
        data = dict(z)
    data["log_odds"] = np.full_like(data["log_odds"], lo)
    np.savez(path, **data)
    return path


@pytest.mark.parametrize("lo", [np.nan, np.inf, -np.inf, 50.0, -50.0])
def test_load_npz_rejects_non_finite_and_out_of_clamp_log_odds(tmp_path, lo):
    from probmap.grid.io import load_npz

    path = _npz(tmp_path / "m.npz", lo)
    with pytest.raises(MapFileError, match=rf"^{path}, field 'log_odds'"):
        load_npz(path)


def test_load_npz_still_reads_its_own_maps(tmp_path):
    from probmap.grid.io import load_npz

    path = _npz(tmp_path / "m.npz", 0.5)
    assert load_npz(path).spec.shape


# --------------------------------------------------------------------------- fuzzing

FUZZ = settings(
    max_examples=60,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
NUMBERS = st.sampled_from(
    ["0", "1", "-1", "2.5", "nan", "inf", "-inf", "1e308", "1e400", "180", "181", "x", "", "3"]
)
CARMEN_TAGS = st.sampled_from(["FLASER", "RLASER", "ROBOTLASER1", "ODOM", "PARAM", "#", "NEFF"])


def _carmen_line(tag, fields):
    return " ".join([tag, *fields]) + "\n"


@FUZZ
@given(
    st.lists(
        st.one_of(
            st.tuples(CARMEN_TAGS, st.lists(NUMBERS, max_size=30)).map(lambda t: _carmen_line(*t)),
            st.text(alphabet=string.printable, max_size=60).map(lambda s: s + "\n"),
            st.just(flaser([2.0] * 4, (0.0, 0.0, 0.0), 100.0)),
        ),
        max_size=12,
    ),
    st.booleans(),
)
def test_fuzz_carmen_reader_raises_only_dataset_errors(tmp_path, lines, skip):
    path = tmp_path / "fuzz.clf"
    path.write_text("".join(lines), encoding="latin-1", errors="replace")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BadLinesWarning)
        try:
            load_scans(path, skip_bad_lines=skip)
        except (DatasetError, ValueError):
            pass
        try:
            list(CarmenLog(path, skip_bad_lines=skip).records())
        except (DatasetError, ValueError):
            pass


G2O_TAGS = st.sampled_from(
    ["VERTEX_SE2", "EDGE_SE2", "VERTEX2", "EDGE2", "VERTEX_XY", "EDGE_SE2_XY", "FIX", "EQUIV"]
)


@FUZZ
@given(
    st.lists(
        st.one_of(
            st.tuples(G2O_TAGS, st.lists(NUMBERS, max_size=14)).map(lambda t: _carmen_line(*t)),
            st.binary(max_size=30).map(lambda b: b.decode("latin-1") + "\n"),
        ),
        max_size=10,
    ),
    st.booleans(),
)
def test_fuzz_g2o_reader_raises_only_dataset_errors(tmp_path, lines, skip):
    path = tmp_path / "fuzz.g2o"
    path.write_bytes("".join(lines).encode("latin-1", errors="replace"))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # skipped unknown lines: reported
            read_pose_graph(path, skip_unknown=skip)
    except (DatasetError, ValueError):
        pass


YAML_VALUES = st.one_of(
    st.sampled_from(["map.pgm", "missing.pgm", "0.05", "-1", "nan", ".inf", "[0, 0, 0]", "[1]"]),
    st.sampled_from(["[.nan, 0, 0]", "0.65", "0.196", "2", "trinary", "scale", "raw", "{}"]),
    st.text(alphabet=string.ascii_letters + "[]{}:,-. '\"", max_size=12),
)
YAML_KEYS = st.sampled_from(
    ["image", "resolution", "origin", "occupied_thresh", "free_thresh", "negate", "mode"]
)


@FUZZ
@given(st.dictionaries(YAML_KEYS, YAML_VALUES, max_size=7), st.binary(max_size=40))
def test_fuzz_map_yaml_reader_raises_only_map_errors(tmp_path, doc, tail):
    from probmap.grid.io import read_map_server

    (tmp_path / "map.pgm").write_bytes(b"P5\n2 2\n255\n\x00\xff\x80\xcd")
    text = "".join(f"{k}: {v}\n" for k, v in doc.items())
    path = tmp_path / "map.yaml"
    path.write_bytes(text.encode() + tail)
    try:
        read_map_server(path)
    except (DatasetError, ValueError, FileNotFoundError):
        pass


# --------------------------------------------------------------------------- landmark datasets


def _mrclam(d: Path, measurements: str) -> Path:
    (d / "Barcodes.dat").write_text("1 5\n6 63\n")
    (d / "Landmark_Groundtruth.dat").write_text("6 1.0 2.0 0.0 0.0\n")
    (d / "Robot1_Odometry.dat").write_text("".join(f"{t:.1f} 0.1 0.0\n" for t in range(10)))
    (d / "Robot1_Groundtruth.dat").write_text(
        "".join(f"{t:.1f} {0.1 * t:.2f} 0.0 0.0\n" for t in range(10))
    )
    (d / "Robot1_Measurement.dat").write_text(measurements)
    return d


def test_mrclam_needs_a_landmark_measurement_and_a_positive_end_time(tmp_path):
    from probmap.datasets.utias import MRCLAM

    d = _mrclam(tmp_path, "")
    with pytest.raises(DatasetError, match=r"Robot1_Measurement\.dat: no landmark measurement"):
        MRCLAM(d, 1)
    _mrclam(tmp_path, "2.0 63 1.5 0.2\n")
    assert len(MRCLAM(d, 1)) > 0
    for bad in (-5.0, 0.0, math.nan):
        with pytest.raises(ValueError, match="end_time"):
            MRCLAM(d, 1, end_time=bad)


def test_victoria_park_needs_a_detection_and_a_positive_end_time(tmp_path):
    from probmap.datasets.victoria_park import VictoriaPark

    (tmp_path / "inputs.dat").write_text("".join(f"{t:.1f} 1.0 0.0\n" for t in range(1, 10)))
    (tmp_path / "gps.dat").write_text("1.0 0.0 0.0\n")
    (tmp_path / "measurements.dat").write_text("")
    with pytest.raises(DatasetError, match=r"measurements\.dat: no tree detection"):
        VictoriaPark(tmp_path, source="dat")
    (tmp_path / "measurements.dat").write_text("2.0 10.0 1.0 0.3\n")
    assert len(VictoriaPark(tmp_path, source="dat")) > 0
    with pytest.raises(ValueError, match="end_time"):
        VictoriaPark(tmp_path, source="dat", end_time=-5.0)
    with pytest.raises(DatasetError, match="no tree detection to use before end_time"):
        VictoriaPark(tmp_path, source="dat", end_time=1.5)


# --------------------------------------------------------------------------- bags


def _glitch_bag(path: Path, glitch: int | None) -> Path:
    """A ROS 1 bag: 10 scans in frame ``laser`` posed by /odom (``odom -> laser``), one pose
    at 1e7 m when ``glitch`` is given."""
    pytest.importorskip("rosbags")
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    t = store.types
    writer = Writer(path)
    writer.open()
    conns: dict[str, object] = {}

    def write(topic: str, msgtype: str, stamp: float, msg: object) -> None:
        if topic not in conns:
            conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
        writer.write(conns[topic], int(round(stamp * 1e9)), store.serialize_ros1(msg, msgtype))

    def header(stamp: float, frame: str) -> object:
        sec = int(stamp)
        tm = t["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((stamp - sec) * 1e9)))
        return t["std_msgs/msg/Header"](seq=0, stamp=tm, frame_id=frame)

    v3 = t["geometry_msgs/msg/Vector3"]
    for k in range(10):
        stamp = 1000.0 + 0.1 * k
        x = 1e7 if k == glitch else 0.05 * k
        pose = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=x, y=0.0, z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        )
        cov = np.zeros(36)
        odo = t["nav_msgs/msg/Odometry"](
            header=header(stamp, "odom"),
            child_frame_id="laser",
            pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](
                    linear=v3(x=0.0, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.0)
                ),
                covariance=cov,
            ),
        )
        write("/odom", "nav_msgs/msg/Odometry", stamp, odo)
        scan = t["sensor_msgs/msg/LaserScan"](
            header=header(stamp, "laser"),
            angle_min=-1.0,
            angle_max=1.0,
            angle_increment=0.5,
            time_increment=0.0,
            scan_time=0.0,
            range_min=0.1,
            range_max=10.0,
            ranges=np.array([2.0, 0.0, np.inf, 3.0, np.nan], dtype=np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )
        write("/scan", "sensor_msgs/msg/LaserScan", stamp, scan)
    writer.close()
    return path


def test_bag_implausible_pose_names_the_message_or_is_skipped(tmp_path):
    from probmap.datasets.ros.scans import load_bag_scans
    from probmap.errors import BagError

    good = load_bag_scans(_glitch_bag(tmp_path / "good.bag", None))
    rep = good.readings
    assert len(good) == 10 and good.skipped_lines == 0
    assert (rep.usable, rep.no_return, rep.zero, rep.invalid) == (20, 10, 10, 10)
    path = _glitch_bag(tmp_path / "glitch.bag", 5)
    with pytest.raises(BagError, match=rf"^{path}: scan message 6: implausible laser pose x"):
        load_bag_scans(path)
    with pytest.warns(BadLinesWarning, match="skipped 1 scan"):
        batch = load_bag_scans(path, skip_bad_lines=True)
    assert len(batch) == 9 and batch.skipped_lines == 1 and batch.readings.skipped_lines == 1
    assert batch.readings.scans == 9
