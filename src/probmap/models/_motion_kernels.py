"""Numba kernels of the motion models (private; see :mod:`probmap.models.motion`).

The one home of the Ackermann model's speed conversion and its derivatives: the Python model
(:class:`~probmap.models.motion.AckermannModel`) calls it per step and landmark GraphSLAM's chain
kernel (:mod:`probmap.slam.landmark.graphslam._kernels`) calls it inside its compiled loop, so both
run the same arithmetic (plain IEEE operations, no ``fastmath``: the same bits either way).
"""

from __future__ import annotations

from numba import njit

SINGULAR_DEN = 1e-6  # |1 - tan(alpha) H / L| below which the speed conversion is singular


@njit(cache=True)
def ackermann_rates(ve, t, H, L):  # pragma: no cover - compiled
    """Centre speed and curvature rate of the Ackermann model, with their derivatives.

    Parameters
    ----------
    ve : float
        Encoder speed ``v_e`` (m/s).
    t : float
        ``tan(alpha)`` of the steering angle ``alpha`` (the caller takes the tangent, so each
        side keeps its own ``tan``).
    H, L : float
        Encoder offset and wheelbase (m).

    Returns
    -------
    ok : bool
        False when ``|1 - t H / L| < SINGULAR_DEN``; the other values are then 0.
    vc, k : float
        ``v_c = v_e / (1 - t H / L)`` (m/s) and ``k = v_c t / L`` (rad/s).
    dvc_dve, dvc_dal, dk_dve, dk_dal : float
        Derivatives of ``v_c`` and ``k`` with respect to ``(v_e, alpha)``.
    """
    den = 1.0 - t * H / L
    if abs(den) < SINGULAR_DEN:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    vc = ve / den
    dt_dal = 1.0 + t * t
    dvc_dve = 1.0 / den
    dvc_dal = ve * (H / L) * dt_dal / (den * den)
    k = vc * t / L
    dk_dve = dvc_dve * t / L
    dk_dal = (dvc_dal * t + vc * dt_dal) / L
    return True, vc, k, dvc_dve, dvc_dal, dk_dve, dk_dal
