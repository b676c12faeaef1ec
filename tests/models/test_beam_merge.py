"""One beam model (issue 19): the particle filter's ``BeamModel``, the MAP mapper's and the EM
fit's ``BeamModelParams`` share one parameter class and one log-likelihood kernel.

Before the merge ``grid/_forward_kernels.py`` and ``models/_beam_kernels.py`` each had a
``beam_log_likelihood``; the tests compare the one kept with a plain copy of the one removed.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from probmap.grid.spec import GridSpec
from probmap.models import _beam_kernels as K
from probmap.models.beam import BeamModel, BeamModelParams, component_densities


def old_models_kernel(z, zs, max_range, z_hit, z_short, z_max, z_rand, sigma, lam):
    """``models._beam_kernels.beam_log_likelihood`` before the merge, as it was."""
    p = 0.0
    if z >= max_range:
        p = z_max
    else:
        norm = 0.5 * (
            math.erf((max_range - zs) / (sigma * math.sqrt(2.0)))
            - math.erf((0.0 - zs) / (sigma * math.sqrt(2.0)))
        )
        if norm > 1e-300:
            d = z - zs
            p += (
                z_hit
                * math.exp(-0.5 * d * d / (sigma * sigma))
                / (sigma * math.sqrt(2.0 * math.pi) * norm)
            )
        if z <= zs and zs > 0.0:
            p += z_short * lam * math.exp(-lam * z) / (1.0 - math.exp(-lam * zs))
        p += z_rand / max_range
    return math.log(p)


def _random_params(rng):
    w = rng.dirichlet(np.ones(4)) * 0.9 + 0.025  # every weight >= 0.025, sum 1
    return BeamModelParams(
        z_hit=float(w[0]),
        z_short=float(w[1]),
        z_max=float(w[2]),
        z_rand=float(1.0 - w[0] - w[1] - w[2]),
        sigma_hit=float(rng.uniform(0.02, 1.0)),
        lambda_short=float(rng.uniform(0.05, 3.0)),
    )


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_one_kernel_equals_the_removed_one(seed):
    """Equal to 1e-14 relative, not to the bit: the kept kernel takes the normaliser of the
    truncated Gaussian as exactly 1 when ``z*`` is more than 8 sigma inside both ends, where
    the removed one computed ``erf`` values that differ from it by under 1e-15."""
    rng = np.random.default_rng(seed)
    for _ in range(40):
        p = _random_params(rng)
        mr = float(rng.uniform(2.0, 30.0))
        zs = rng.uniform(0.0, mr, 50)
        z = np.concatenate(
            [rng.uniform(0.0, mr, 20), zs[:20] + rng.normal(0, p.sigma_hit, 20), [mr, mr + 1.0]]
        )
        z = np.clip(z, 0.0, None)
        for zi in z:
            for zsi in zs[:10]:
                new = K.beam_log_likelihood(zi, zsi, mr, *p.as_array())
                old = old_models_kernel(zi, zsi, mr, *p.as_array())
                assert new == pytest.approx(old, rel=1e-14, abs=1e-14)


def test_beam_model_and_params_give_identical_log_likelihoods():
    """BeamModel (particle weights) and BeamModelParams (MAP mapping, EM) on the same readings
    and expected ranges: the same kernel, so the same bits."""
    rng = np.random.default_rng(7)
    occ = rng.random((40, 50)) < 0.05
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    spec = GridSpec(0.1, (0.0, 0.0), occ.shape)
    params = _random_params(rng)
    bm = BeamModel(spec, occ, max_range=6.0, params=params, ray_casting="exact")
    poses = np.column_stack(
        [rng.uniform(0.5, 4.5, 8), rng.uniform(0.5, 3.5, 8), rng.uniform(-3, 3, 8)]
    )
    angles = np.linspace(-np.pi / 2, np.pi / 2, 31)
    ranges = rng.uniform(0.0, 7.0, angles.size)
    got = bm.log_likelihood(poses, ranges, angles)
    zs = bm.expected_ranges(poses, angles)
    want = params.log_likelihood(np.broadcast_to(np.minimum(ranges, 6.0), zs.shape), zs, 6.0)
    np.testing.assert_array_equal(got, want)


def test_em_component_densities_mix_to_the_kernel():
    rng = np.random.default_rng(8)
    p = _random_params(rng)
    zs = rng.uniform(0.0, 10.0, 2000)
    z = np.clip(zs + rng.normal(0, 0.5, zs.size), 0.0, 10.0)
    z[::50] = 10.0
    weights = np.array([p.z_hit, p.z_short, p.z_max, p.z_rand])
    dens = component_densities(z, zs, 10.0, p.sigma_hit, p.lambda_short)
    mix = np.log((dens * weights[:, None]).sum(axis=0))
    np.testing.assert_allclose(mix, p.log_likelihood(z, zs, 10.0), rtol=1e-12, atol=1e-12)


def test_beam_model_takes_the_parameter_class_and_its_rules():
    occ = np.zeros((10, 10), bool)
    spec = GridSpec(0.1, (0.0, 0.0), occ.shape)
    p = BeamModelParams(z_hit=0.7, z_short=0.1, z_max=0.1, z_rand=0.1, sigma_hit=0.3)
    a = BeamModel(spec, occ, max_range=5.0, params=p)
    b = BeamModel(spec, occ, max_range=5.0, z_hit=0.7, z_short=0.1, z_max=0.1, z_rand=0.1,
                  sigma_hit=0.3)  # fmt: skip
    assert a.model == b.model == p
    np.testing.assert_array_equal(a.params, p.as_array())
    assert BeamModel(spec, occ, max_range=5.0).model == BeamModelParams()
    with pytest.raises(ValueError, match="sum to 1"):
        BeamModel(spec, occ, max_range=5.0, z_hit=0.5)
    with pytest.raises(ValueError, match="z_rand"):
        BeamModel(spec, occ, max_range=5.0, z_hit=0.85, z_rand=0.0)
    with pytest.raises(ValueError, match="not both"):
        BeamModel(spec, occ, max_range=5.0, params=p, sigma_hit=0.1)
    with pytest.raises(ValueError, match="max_range"):
        BeamModel(spec, occ, max_range=0.0)
