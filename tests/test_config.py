"""probmap.config: every configuration dataclass of the package dumps to YAML and loads back
equal; partial files keep defaults; every bad input is one ValueError naming file and field."""

from __future__ import annotations

import dataclasses
import importlib
import math
import re
from pathlib import Path

import pytest
import yaml

from probmap.config import CLASS_KEY, VERSION_KEY, dump_config, load_config, write_config

SRC = Path(__file__).resolve().parents[1] / "src" / "probmap"
_CONFIG = re.compile(r"^@dataclass\(frozen=True\)\nclass (\w+Config)\b", re.MULTILINE)


def _config_classes() -> list[type]:
    """Every ``@dataclass(frozen=True)`` class named ``*Config`` in the package's source."""
    found = []
    for path in sorted(SRC.rglob("*.py")):
        names = _CONFIG.findall(path.read_text(encoding="utf-8"))
        if not names:
            continue
        module = ".".join(("probmap", *path.relative_to(SRC).with_suffix("").parts))
        mod = importlib.import_module(module)
        found += [getattr(mod, n) for n in names]
    return found


CLASSES = _config_classes()


def test_the_search_finds_the_configs_we_know():
    names = {c.__name__ for c in CLASSES}
    known = {"SubmapSlamConfig", "RbpfConfig", "MatcherConfig", "OptimizerConfig", "EKFConfig"}
    known |= {"SeifConfig", "MCLConfig", "KLDConfig", "LocalizeConfig", "MappingConfig"}
    known |= {"MapMappingConfig"}
    assert known <= names, known - names
    for cls in CLASSES:
        assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen
        assert {VERSION_KEY, CLASS_KEY}.isdisjoint(f.name for f in dataclasses.fields(cls))


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_defaults_round_trip(cls, tmp_path):
    cfg = cls()
    text = dump_config(cfg)
    doc = yaml.safe_load(text)
    assert doc[VERSION_KEY] == importlib.metadata.version("probmap")
    assert doc[CLASS_KEY] == cls.__name__
    assert list(doc)[2:] == [f.name for f in dataclasses.fields(cls)]
    assert load_config(cls, text) == cfg
    path = write_config(tmp_path / "c.yaml", cfg)
    assert load_config(cls, path) == cfg
    assert load_config(cls, str(path)) == cfg
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.yaml"]  # no temporary left
    assert load_config(cls, "") == cfg  # an empty file: every default


def _changed():
    from probmap.filters.kld import KLDConfig
    from probmap.filters.mcl import MCLConfig
    from probmap.pipelines.localize import LocalizeConfig
    from probmap.slam.landmark.ekf import EKFConfig
    from probmap.slam.landmark.seif import SeifConfig
    from probmap.slam.laser.rbpf import RbpfConfig
    from probmap.slam.laser.scan_matching import MatcherConfig
    from probmap.slam.laser.submap_slam import (
        LocalMatchingConfig,
        OptimizationConfig,
        SubmapConfig,
        SubmapSlamConfig,
    )
    from probmap.slam.posegraph.optimize import OptimizerConfig

    return [
        SubmapSlamConfig(
            submaps=SubmapConfig(scans=30),
            local=LocalMatchingConfig(
                matcher=MatcherConfig(linear_window=0.3, beam_skip=2), recover_window=(0.7, 0.25)
            ),
            optimization=OptimizationConfig(robust="cauchy"),
        ),
        RbpfConfig(particles=5, degeneracy_guard=False, odometry_noise=(0.2, 0.1, 0.3, 0.4)),
        MCLConfig(n_particles=500, kld=KLDConfig(epsilon=0.1, bin_size=(0.2, 0.2, 0.1))),
        LocalizeConfig(initial_pose=(1.0, -2.5, math.pi / 3), max_range=8.0, augmented=True),
        EKFConfig(visibility_range=12.5, outlier_probability=0.01),
        SeifConfig(max_active=None, deactivation="oldest"),
        OptimizerConfig(robust="huber", robust_scale=1.5, chart="xyt", damping="diagonal"),
    ]


@pytest.mark.parametrize("cfg", _changed(), ids=lambda c: type(c).__name__)
def test_changed_values_round_trip(cfg):
    back = load_config(type(cfg), dump_config(cfg))
    assert back == cfg
    for f in dataclasses.fields(cfg):  # tuples stay tuples, not lists
        assert type(getattr(back, f.name)) is type(getattr(cfg, f.name)), f.name


def test_numpy_scalars_dump_as_plain_numbers():
    np = pytest.importorskip("numpy")
    from probmap.slam.laser.scan_matching import MatcherConfig

    cfg = MatcherConfig(sigma=np.float64(0.07), iterations=np.int64(4))
    back = load_config(MatcherConfig, dump_config(cfg))
    assert back.sigma == 0.07 and back.iterations == 4 and type(back.iterations) is int


def test_partial_file_keeps_defaults_nested_ones_included():
    from probmap.slam.laser.submap_slam import SubmapSlamConfig

    default = SubmapSlamConfig()
    text = "submaps:\n  scans: 30\nlocal:\n  matcher:\n    linear_window: 0.3\n"
    cfg = load_config(SubmapSlamConfig, text)
    # the matcher's other fields keep SubmapSlamConfig's matcher defaults, not MatcherConfig()'s
    local = dataclasses.replace(
        default.local, matcher=dataclasses.replace(default.local.matcher, linear_window=0.3)
    )
    expected = dataclasses.replace(
        default, submaps=dataclasses.replace(default.submaps, scans=30), local=local
    )
    assert cfg == expected
    # ints where a float is asked, YAML 1.1's "1e-3" string and .inf are numbers
    cfg = load_config(SubmapSlamConfig, "submaps: {resolution: 1}\nlocal: {min_distance: 1e-3}\n")
    res = cfg.submaps.resolution
    assert res == 1.0 and type(res) is float and cfg.local.min_distance == 1e-3
    from probmap.slam.landmark.ekf import EKFConfig

    assert load_config(EKFConfig, "visibility_range: .inf\n").visibility_range == math.inf


def test_optional_nested_dataclass_from_null_and_from_a_mapping():
    from probmap.filters.kld import KLDConfig
    from probmap.filters.mcl import MCLConfig

    assert load_config(MCLConfig, "kld: null\n").kld is None
    assert load_config(MCLConfig, "kld: {epsilon: 0.2}\n").kld == KLDConfig(epsilon=0.2)


BAD = [
    ("local:\n  matcher:\n    linear_window: x\n", "cfg.yaml: local.matcher.linear_window: expected a number, got 'x'"),
    ("submaps: {scns: 3}\n", "cfg.yaml: submaps.scns: unknown field of SubmapConfig (did you mean scans?)"),
    ("submap_scans: 3\n", "cfg.yaml: submap_scans: this key is now submaps.scans"),
    ("closure_min_score: 0.6\n", "cfg.yaml: closure_min_score: this key is now closures.min_score"),
    ("matcher: {sigma: 1}\n", "cfg.yaml: matcher: this key is now local.matcher"),
    ("local: {matcher: {sigmaa: 1}}\n", "cfg.yaml: local.matcher.sigmaa: unknown field of MatcherConfig"),
    ("submaps: {scans: 3.5}\n", "cfg.yaml: submaps.scans: expected an integer, got 3.5"),
    ("submaps: {scans: true}\n", "cfg.yaml: submaps.scans: expected an integer, got True"),
    ("submaps: {resolution: true}\n", "cfg.yaml: submaps.resolution: expected a number, got True"),
    ("submaps: {resolution: null}\n", "cfg.yaml: submaps.resolution: expected a number, got None"),
    ("optimization: {robust: foo}\n", "cfg.yaml: optimization.robust: expected one of"),
    ("local: {recover_window: [1]}\n", "cfg.yaml: local.recover_window: expected a list of 2 values, got 1"),
    ("local: {recover_window: 1}\n", "cfg.yaml: local.recover_window: expected a list, got 1"),
    ("local: {recover_window: [1, a]}\n", "cfg.yaml: local.recover_window[1]: expected a number, got 'a'"),
    ("local: {matcher: 3}\n", "cfg.yaml: local.matcher: expected a mapping of MatcherConfig fields, got 3"),
    ("local: {matcher: {linear_window: -1}}\n", "cfg.yaml: local.matcher: linear_window must be >= 0"),
    ("submaps: {resolution: -1}\n", "cfg.yaml: submaps"),
    ("- 1\n- 2\n", "cfg.yaml: expected a mapping of SubmapSlamConfig fields, got a list"),
    ("a: [\n", "cfg.yaml: line 2: not valid YAML"),
    ("config_class: RbpfConfig\n", "cfg.yaml: config_class: expected SubmapSlamConfig, got"),
    ("probmap_version: [1]\n", "cfg.yaml: probmap_version: expected a version string"),
    ("1: 2\n", "cfg.yaml: 1: unknown field of SubmapSlamConfig"),
]  # fmt: skip


@pytest.mark.parametrize(("text", "message"), BAD)
def test_bad_input_is_one_value_error_naming_file_and_field(tmp_path, text, message):
    from probmap.slam.laser.submap_slam import SubmapSlamConfig

    path = tmp_path / "cfg.yaml"
    path.write_text(text)
    with pytest.raises(ValueError) as info:
        load_config(SubmapSlamConfig, path)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.replace(str(tmp_path) + "/", "").startswith(message), msg
    with pytest.raises(ValueError, match=re.escape(message.replace("cfg.yaml", "<config>"))):
        load_config(SubmapSlamConfig, text + "# text")


def test_bad_literal_in_a_nested_optimizer_and_a_post_init_error_at_the_top():
    from probmap.slam.laser.rbpf import RbpfConfig
    from probmap.slam.posegraph.optimize import OptimizerConfig

    with pytest.raises(ValueError, match=r"^x.yaml: chart: expected one of 'logmap', 'xyt'"):
        load_config(OptimizerConfig, "chart: polar\n", source="x.yaml")
    with pytest.raises(ValueError, match=r"^x.yaml: particles must be >= 1, got 0$"):
        load_config(RbpfConfig, "particles: 0\n", source="x.yaml")


def test_missing_file_and_non_dataclass_arguments(tmp_path):
    from probmap.slam.laser.rbpf import RbpfConfig

    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        load_config(RbpfConfig, tmp_path / "nope.yaml")
    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        load_config(RbpfConfig, str(tmp_path / "nope.yaml"))
    with pytest.raises(TypeError):
        load_config(dict, "a: 1")  # type: ignore[type-var]
    with pytest.raises(TypeError):
        dump_config(RbpfConfig)
    with pytest.raises(TypeError):
        dump_config({"a": 1})


def test_write_config_failure_leaves_no_file(tmp_path):
    from probmap.slam.laser.scan_matching import MatcherConfig

    with pytest.raises(OSError, match="cannot write"):
        write_config(tmp_path / "no" / "c.yaml", MatcherConfig())
    assert not list(tmp_path.iterdir())
