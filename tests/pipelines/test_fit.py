"""Fitting the beam model to a whole log (probmap.pipelines.fit): the Intel corrected log, and
the one-release shim of the old path probmap.grid.fit.fit_log."""

from __future__ import annotations

import pytest

from probmap.pipelines.fit import fit_log


def test_fit_intel_corrected(shared_data):
    log = shared_data("intel-research-lab/intel-corrected.log.gz")
    fit = fit_log(log, resolution=0.1, every=4)
    p = fit.params
    print(f"\nIntel corrected, EM beam model: {p}, mean log-lik {fit.log_likelihood[-1]:.3f}")
    assert fit.log_likelihood[-1] > fit.log_likelihood[0]
    assert 0.01 < p.sigma_hit < 0.3  # a good laser in a consistent map
    assert p.z_hit > 0.5


def test_old_path_warns_and_forwards():
    import probmap.grid.fit as old

    with pytest.warns(DeprecationWarning, match="probmap.pipelines.fit.fit_log"):
        assert old.fit_log is fit_log
    with pytest.raises(AttributeError):
        _ = old.no_such_name
