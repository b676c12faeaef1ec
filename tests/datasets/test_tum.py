"""``probmap.datasets.tum``: TUM trajectories (``timestamp tx ty tz qx qy qz qw``) written and
read back; the yaw quaternion against its closed form; malformed lines are one-line errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.datasets.tum import TUM_HEADER, quaternion_yaw, read_tum, write_tum, yaw_quaternion
from probmap.errors import DatasetError
from probmap.metrics.relations import read_trajectory


def _angle_diff(a, b):
    return np.abs((np.asarray(a) - np.asarray(b) + np.pi) % (2 * np.pi) - np.pi)


def test_round_trip_of_random_poses(tmp_path):
    rng = np.random.default_rng(7)
    n = 500
    times = 976052857.0 + np.cumsum(rng.uniform(0.01, 0.5, n))
    poses = np.column_stack(
        [rng.uniform(-500, 500, n), rng.uniform(-500, 500, n), rng.uniform(-20, 20, n)]
    )  # headings far outside [-pi, pi): written wrapped
    path = write_tum(tmp_path / "run.tum", times, poses)
    assert path == tmp_path / "run.tum"
    t, p = read_tum(path)
    assert t.shape == (n,) and p.shape == (n, 3)
    np.testing.assert_allclose(t, times, rtol=0, atol=1e-6)
    np.testing.assert_allclose(p[:, :2], poses[:, :2], rtol=0, atol=1e-8)
    assert _angle_diff(p[:, 2], poses[:, 2]).max() < 1e-9
    assert np.all((p[:, 2] >= -np.pi) & (p[:, 2] < np.pi))
    # the same through the metrics' trajectory reader
    t2, p2 = read_trajectory(path)
    np.testing.assert_array_equal(t2, t)
    np.testing.assert_array_equal(p2, p)


def test_file_layout_and_quaternion_closed_form(tmp_path):
    rng = np.random.default_rng(3)
    theta = rng.uniform(-10, 10, 50)
    poses = np.column_stack([rng.normal(size=50), rng.normal(size=50), theta])
    path = write_tum(tmp_path / "t.tum", np.arange(50) * 0.1, poses)
    lines = path.read_text().splitlines()
    assert lines[0] == TUM_HEADER and len(lines) == 51
    rows = np.array([[float(v) for v in line.split(" ")] for line in lines[1:]])
    assert rows.shape == (50, 8)
    assert np.all(rows[:, 3] == 0) and np.all(rows[:, 4:6] == 0)  # z, qx, qy
    wrapped = (theta + math.pi) % (2 * math.pi) - math.pi
    np.testing.assert_allclose(rows[:, 6], np.sin(wrapped / 2), atol=1e-12)
    np.testing.assert_allclose(rows[:, 7], np.cos(wrapped / 2), atol=1e-12)
    assert np.all(rows[:, 7] >= 0)
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:8], axis=1), 1.0, atol=1e-11)


def test_quaternion_helpers():
    q = yaw_quaternion([0.0, math.pi / 2, -math.pi / 2, math.pi])
    np.testing.assert_allclose(
        q,
        [
            [0, 0, 0, 1],
            [0, 0, math.sqrt(0.5), math.sqrt(0.5)],
            [0, 0, -math.sqrt(0.5), math.sqrt(0.5)],
            [0, 0, -1, 0],  # pi wraps to -pi
        ],
        atol=1e-15,
    )
    # a general rotation: yaw of z-y-x Euler angles, at any norm and either sign
    yaw, pitch, roll = 0.7, 0.2, -0.1
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    general = [
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    ]
    assert quaternion_yaw(general) == pytest.approx(yaw)
    assert quaternion_yaw(-3.0 * np.asarray(general)) == pytest.approx(yaw)


def test_reads_what_other_tools_write(tmp_path):
    path = tmp_path / "evo.txt"
    path.write_text(
        "# written by another tool\n\n"
        "1.0\t2.0\t3.0\t0.5\t0\t0\t0\t1\n"
        "2.0, 4.0, 5.0, 0.5, 0, 0, 0.7071067811865476, 0.7071067811865476\n"
    )
    t, p = read_tum(path)
    np.testing.assert_allclose(t, [1.0, 2.0])
    np.testing.assert_allclose(p, [[2.0, 3.0, 0.0], [4.0, 5.0, math.pi / 2]], atol=1e-12)


@pytest.mark.parametrize(
    ("line", "words"),
    [
        ("1 2 3 0 0 0 0", "expected 8 fields"),
        ("1 2 3 0 0 0 0 1 9", "expected 8 fields"),
        ("1 2 x 0 0 0 0 1", "non-numeric"),
        ("1 2 nan 0 0 0 0 1", "non-finite"),
        ("1 2 3 0 0 0 0 0", "zero quaternion"),
    ],
)
def test_bad_lines_are_one_line_errors_naming_the_line(tmp_path, line, words):
    path = tmp_path / "bad.tum"
    path.write_text(f"{TUM_HEADER}\n0 0 0 0 0 0 0 1\n{line}\n0.5 0 0 0 0 0 0 1\n")
    with pytest.raises(DatasetError) as info:
        read_tum(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(f"{path}, line 3: ") and words in msg
    assert info.value.line == 3


def test_empty_and_missing_files(tmp_path):
    empty = tmp_path / "empty.tum"
    empty.write_text(f"{TUM_HEADER}\n")
    with pytest.raises(DatasetError, match="no poses"):
        read_tum(empty)
    with pytest.raises(FileNotFoundError, match="nope.tum"):
        read_tum(tmp_path / "nope.tum")


def test_write_checks_its_input(tmp_path):
    with pytest.raises(ValueError, match=r"shape \(T, 3\)"):
        write_tum(tmp_path / "a.tum", [0.0], [[1.0, 2.0]])
    with pytest.raises(ValueError, match="2 timestamps for 1 poses"):
        write_tum(tmp_path / "a.tum", [0.0, 1.0], [[1.0, 2.0, 3.0]])
    with pytest.raises(ValueError, match="finite"):
        write_tum(tmp_path / "a.tum", [0.0], [[1.0, np.inf, 3.0]])
    assert not list(tmp_path.iterdir())  # nothing written, no temporary left
