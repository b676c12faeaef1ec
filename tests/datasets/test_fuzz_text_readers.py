"""Hypothesis fuzzing of the text and image readers (issue 38): CARMEN logs, TUM trajectories,
map_server YAML + PGM maps and YAML configurations, built from their own records with
arbitrary fields. Each either reads or raises a ValueError (the package's DatasetError,
MapFileError and configuration errors are ValueErrors) whose message is one line naming the
file; nothing else escapes."""

from __future__ import annotations

from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

FUZZ = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

_NUMBER = st.one_of(
    st.integers(-5, 400).map(str),
    st.integers(-(2**70), 2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["1e400", "nan", "inf", "-0", "x", "0x10", "1_0", "", "3.", ".5"]),
)


def _one_line_naming(exc: BaseException, path: Path) -> None:
    msg = str(exc)
    assert "\n" not in msg.strip() and str(path.name) in msg, msg


def _check(path: Path, read) -> None:
    try:
        read(path)
    except ValueError as exc:
        _one_line_naming(exc, path)


@FUZZ
@given(
    lines=st.lists(
        st.tuples(
            st.sampled_from(["FLASER", "ODOM", "RLASER", "PARAM", "ROBOTLASER1", "#", "SYNC"]),
            st.lists(_NUMBER, max_size=14),
        ),
        min_size=1,
        max_size=8,
    )
)
def test_carmen_logs(tmp_path, lines):
    from probmap.datasets.carmen import load_scans

    path = tmp_path / "fuzz.log"
    path.write_text("\n".join(" ".join([t, *f]) for t, f in lines) + "\n")
    _check(path, load_scans)


@FUZZ
@given(rows=st.lists(st.lists(_NUMBER, max_size=9), min_size=1, max_size=6))
def test_tum_trajectories(tmp_path, rows):
    from probmap.datasets.tum import read_tum

    path = tmp_path / "fuzz.tum"
    path.write_text("\n".join(" ".join(r) for r in rows) + "\n")
    _check(path, read_tum)


@FUZZ
@given(
    fields=st.dictionaries(
        st.sampled_from(
            ["image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode"]
        ),
        st.one_of(_NUMBER, st.lists(_NUMBER, max_size=4).map(lambda v: "[" + ", ".join(v) + "]")),
        max_size=7,
    ),
    header=st.sampled_from(["P5", "P2", "P6", "PX", ""]),
    size=st.tuples(_NUMBER, _NUMBER, _NUMBER),
    body=st.binary(max_size=64),
)
def test_map_server_maps(tmp_path, fields, header, size, body):
    from probmap.grid.io import read_map_server

    fields = {"image": "m.pgm", **fields} if "image" not in fields else fields
    (tmp_path / "m.pgm").write_bytes(f"{header}\n{size[0]} {size[1]}\n{size[2]}\n".encode() + body)
    path = tmp_path / "m.yaml"
    path.write_text("".join(f"{k}: {v}\n" for k, v in fields.items()))
    _check(path, read_map_server)


@FUZZ
@given(
    text=st.one_of(
        st.text(max_size=80),
        st.dictionaries(
            st.sampled_from(["local", "submaps", "closures", "optimization", "resolution", "x"]),
            st.one_of(
                _NUMBER,
                st.dictionaries(st.sampled_from(["scans", "min_score", "sd", "every"]), _NUMBER),
            ),
            max_size=4,
        ).map(
            lambda d: "".join(
                f"{k}:\n" + "".join(f"  {kk}: {vv}\n" for kk, vv in v.items())
                if isinstance(v, dict)
                else f"{k}: {v}\n"
                for k, v in d.items()
            )
        ),
        st.sampled_from(["!!python/object/apply:os.system ['touch pwned']", "a: !!binary AAAA"]),
    )
)
def test_yaml_configurations(tmp_path, text):
    from probmap.config import load_config
    from probmap.slam.laser.submap_slam import SubmapSlamConfig

    path = tmp_path / "c.yaml"
    path.write_text(text)
    _check(path, lambda p: load_config(SubmapSlamConfig, p))
    assert not (tmp_path / "pwned").exists()
