"""Fitting the beam model to a whole log (probmap.pipelines.fit): the Intel corrected log."""

from __future__ import annotations

from probmap.pipelines.fit import fit_log


def test_fit_intel_corrected(shared_data):
    log = shared_data("intel-research-lab/intel-corrected.log.gz")
    fit = fit_log(log, resolution=0.1, every=4)
    p = fit.params
    print(f"\nIntel corrected, EM beam model: {p}, mean log-lik {fit.log_likelihood[-1]:.3f}")
    assert fit.log_likelihood[-1] > fit.log_likelihood[0]
    assert 0.01 < p.sigma_hit < 0.3  # a good laser in a consistent map
    assert p.z_hit > 0.5
