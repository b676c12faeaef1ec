"""Information-form steps of SEIF SLAM, Probabilistic Robotics chapter 12, on dense arrays.

The function tier of :mod:`probmap.slam.landmark.seif`: pure functions that state each table's
equations on a dense information system ``Omega``, ``xi`` with the mean ``mu``, the robot pose in
rows 0..2 and each landmark in two rows after it. :class:`~probmap.slam.landmark.seif.SEIFSlam`
applies them to small systems gathered from its sparse store over the robot and the active
landmarks.

- :func:`motion_update_information`: the motion update (Table 12.2), for any motion model with
  ``G = d g / d x`` and ``Q = V M V^T``;
- :func:`measurement_update_information`: the measurement update (Table 12.3), a batch of
  range-bearing observations linearised at the same mean;
- :func:`sparsify_information`: sparsification (Table 12.4), with optional context landmarks
  marginalised instead of conditioned on;
- :func:`update_mean_information`: amortised mean recovery (Table 12.5), block coordinate
  descent on ``Omega mu = xi``;
- :func:`robot_link_information`: the conditional mutual information between the robot and each
  landmark, what Table 12.4 discards when it cuts their link (the ``"weakest"`` deactivation
  policy).

References
----------
S. Thrun, W. Burgard, D. Fox, *Probabilistic Robotics*, MIT Press, 2005, chapter 12.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy import linalg as sla

from probmap._typing import FloatArray
from probmap.errors import SingularInformationError

__all__ = [
    "measurement_update_information",
    "motion_update_information",
    "robot_link_information",
    "sparsify_information",
    "update_mean_information",
]


def _cho_solve(A: FloatArray, B: FloatArray, what: str) -> FloatArray:
    """``A^-1 B`` by Cholesky for a symmetric positive definite information block ``A``.

    Raises
    ------
    SingularInformationError
        When ``A`` is not positive definite (the message names ``what``).
    """
    try:
        fac = sla.cho_factor(A)
    except np.linalg.LinAlgError as exc:
        raise SingularInformationError(f"{what} is not positive definite") from exc
    return np.asarray(sla.cho_solve(fac, B))


def motion_update_information(
    Omega: FloatArray,
    xi: FloatArray,
    mu: FloatArray,
    delta: FloatArray,
    G: FloatArray,
    Q: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """SEIF motion update (Table 12.2) on a dense information system.

    The book writes ``G_t = I + F_x^T Delta F_x`` for its velocity model; here ``G`` is any
    model's pose Jacobian, so ``Psi = F_x^T (G^-1 - I) F_x`` and

    - ``Phi = (I + Psi)^T Omega (I + Psi) = Omega + lambda`` (lines 5-8): only the robot rows and
      columns change;
    - ``kappa = Phi F_x^T (Q^-1 + F_x Phi F_x^T)^-1 F_x Phi`` (line 9), with
      ``(Q^-1 + A)^-1 = (I + Q A)^-1 Q`` so that a rank-deficient ``Q = V M V^T`` is allowed;
    - ``Omega_bar = Phi - kappa`` (line 10);
    - ``xi_bar = xi + (lambda - kappa) mu + Omega_bar F_x^T delta`` (line 11).

    Parameters
    ----------
    Omega : ndarray, shape (d, d)
        Information matrix; rows 0..2 are the robot pose ``(x, y, theta)``.
    xi, mu : ndarray, shape (d,)
        Information vector and the mean estimate at which to linearise.
    delta : ndarray, shape (3,)
        Pose change ``g(u, mu_x) - mu_x`` (angle difference wrapped), world frame.
    G : ndarray, shape (3, 3)
        ``d g / d x`` at ``mu_x``.
    Q : ndarray, shape (3, 3)
        Motion noise ``V M V^T`` (may be singular).

    Returns
    -------
    Omega_bar : ndarray, shape (d, d)
    xi_bar : ndarray, shape (d,)
    """
    Ginv = np.linalg.inv(G)
    Phi = Omega.copy()
    Phi[:3, :] = Ginv.T @ Omega[:3, :]
    Phi[:, :3] = Phi[:, :3] @ Ginv
    A = Phi[:3, :3]
    K = np.linalg.solve(np.eye(3) + Q @ A, Q)
    K = 0.5 * (K + K.T)
    col = Phi[:, :3]
    Omega_bar = Phi - col @ K @ col.T
    Omega_bar = 0.5 * (Omega_bar + Omega_bar.T)
    xi_bar = xi + (Omega_bar - Omega) @ mu + Omega_bar[:, :3] @ delta
    return Omega_bar, xi_bar


def measurement_update_information(
    Omega: FloatArray,
    xi: FloatArray,
    mu: FloatArray,
    rows: Sequence[int],
    H_x: FloatArray,
    H_m: FloatArray,
    nu: FloatArray,
    R: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """SEIF measurement update (Table 12.3) for ``k`` range-bearing observations.

    For each observation ``i`` of the landmark at rows ``rows[i], rows[i] + 1``, with
    ``H_i = [H_x  0  H_m  0]``: ``Omega += H_i^T R^-1 H_i`` and
    ``xi += H_i^T R^-1 (z_i - z_hat_i + H_i mu)`` (lines 9-10). All observations are linearised at
    the same ``mu`` (a batch update).

    Parameters
    ----------
    Omega, xi, mu : ndarray, shapes (d, d), (d,), (d,)
    rows : sequence of int, length k
        First row of each observed landmark (>= 3).
    H_x : ndarray, shape (k, 2, 3)
    H_m : ndarray, shape (k, 2, 2)
    nu : ndarray, shape (k, 2)
        Innovations ``z - z_hat``, bearing wrapped.
    R : ndarray, shape (2, 2)

    Returns
    -------
    Omega_new : ndarray, shape (d, d)
    xi_new : ndarray, shape (d,)
    """
    k = len(rows)
    d = Omega.shape[0]
    if k == 0:
        return Omega.copy(), xi.copy()
    H = np.zeros((k, 2, d))
    H[:, :, :3] = H_x
    for i, r in enumerate(rows):
        H[i, :, r : r + 2] = H_m[i]
    Rinv = np.linalg.inv(R)
    RH = np.einsum("ab,kbd->kad", Rinv, H)  # (k, 2, d)
    Omega_new = Omega + np.einsum("kad,kae->de", H, RH)
    y = nu + np.einsum("kad,d->ka", H, mu)
    xi_new = xi + np.einsum("kad,ka->d", RH, y)
    return 0.5 * (Omega_new + Omega_new.T), xi_new


def sparsify_information(
    Omega: FloatArray,
    xi: FloatArray,
    mu: FloatArray,
    m0_rows: Sequence[int],
    n_context: int = 0,
) -> tuple[FloatArray, FloatArray]:
    """SEIF sparsification (Table 12.4): cut the robot's links to the landmarks ``m0``.

    With ``Omega`` over the robot, the landmarks that stay active (``m+``) and those that become
    passive (``m0``), all other landmarks (``m-``) conditioned on zero (so ``Omega0`` is this
    submatrix)::

        Omega1 = Omega0 - Omega0 F_m0 (F_m0^T Omega0 F_m0)^-1 F_m0^T Omega0       (marginalise m0)
        Omega2 = Omega0 - Omega0 F_x,m0 (F_x,m0^T Omega0 F_x,m0)^-1 F_x,m0^T Omega0  (and x)
        Omega3 = Omega - Omega F_x (F_x^T Omega F_x)^-1 F_x^T Omega               (marginalise x)
        Omega~ = Omega1 - Omega2 + Omega3,     xi~ = xi + (Omega~ - Omega) mu

    ``Omega3`` uses the full matrix, but its correction lives on the robot's Markov blanket
    (``x``, ``m+``, ``m0``), so every change is confined to that block: pass exactly that block
    (the submatrix, which is ``Omega0``); all links to ``m-`` stay as they are. The robot-``m0``
    blocks of the result are exactly zero.

    **Context** (``n_context > 0``, an extension, not in the book): the last ``n_context``
    landmarks of the system are passive landmarks ``c`` near the blanket. They are marginalised
    together with ``m0`` in ``Omega1`` and ``Omega2`` instead of being conditioned on, so the
    robot's new conditional ``p(x | m+)`` (``Omega1 - Omega2``) is taken from a posterior in which
    only the landmarks beyond ``c`` are held at their means. Their rows are returned unchanged.
    With ``c`` = every other landmark the result is ``p(m) p(x | m+)``: among the distributions
    in which the robot depends on the map only through ``m+``, the one closest to the posterior
    (smallest ``KL(p || q)``); its covariance over ``(x, m+)`` and over the map is the posterior's.
    Table 12.4 conditions on all of them, which makes the filter overconfident (Eustice et al.
    2005).

    Parameters
    ----------
    Omega, xi, mu : ndarray, shapes (d, d), (d,), (d,)
        Over the robot (first), the active landmarks ``m+`` and ``m0``, then ``n_context``
        context landmarks (the last ``2 n_context`` rows).
    m0_rows : sequence of int
        First rows of the landmarks to deactivate.
    n_context : int
        Number of context landmarks at the end of the system (0: Table 12.4 as printed).

    Returns
    -------
    Omega_tilde : ndarray, shape (d, d)
    xi_tilde : ndarray, shape (d,)
    """
    if len(m0_rows) == 0:
        return Omega.copy(), xi.copy()
    d = Omega.shape[0]
    n_ctx_rows = 2 * int(n_context)
    if n_context < 0 or 3 + n_ctx_rows > d:
        raise ValueError(f"n_context must be in [0, {(d - 3) // 2}], got {n_context}")
    m0 = np.concatenate([[r, r + 1] for r in m0_rows]).astype(np.intp)
    if np.any(m0 < 3) or np.any(m0 >= d - n_ctx_rows):
        raise ValueError("m0_rows must be landmark rows before the context rows")
    ctx = np.arange(d - n_ctx_rows, d, dtype=np.intp)
    x = np.arange(3)
    c = np.concatenate([m0, ctx])  # marginalised in Omega1 (and with x in Omega2)
    xc = np.concatenate([x, c])

    def marginal_correction(idx: NDArray[np.intp], rows: NDArray[np.intp]) -> FloatArray:
        # Omega[rows, idx] Omega[idx, idx]^-1 Omega[idx, rows]: what marginalising idx
        # subtracts from the rows that stay
        cols = Omega[np.ix_(rows, idx)]
        block = Omega[np.ix_(idx, idx)]
        what = "sparsification: information block to marginalise"
        return cols @ _cho_solve(block, cols.T, what)

    # Omega1 - Omega2 is zero outside the rows and columns of (x, m+); Omega3 - Omega is zero
    # outside the robot's Markov blanket, i.e. wherever a row or column is a context row
    keep = np.setdiff1d(np.arange(d - n_ctx_rows), m0)
    Omega_t = Omega.copy()
    Omega_t[np.ix_(keep, keep)] += marginal_correction(xc, keep) - marginal_correction(c, keep)
    everything = np.arange(d, dtype=np.intp)
    Omega_t -= marginal_correction(x, everything)
    Omega_t = 0.5 * (Omega_t + Omega_t.T)
    Omega_t[np.ix_(x, m0)] = 0.0
    Omega_t[np.ix_(m0, x)] = 0.0
    if n_ctx_rows:  # exactly unchanged in exact arithmetic; drop the round-off
        Omega_t[ctx, :] = Omega[ctx, :]
        Omega_t[:, ctx] = Omega[:, ctx]
    xi_t = xi + (Omega_t - Omega) @ mu
    return Omega_t, xi_t


def update_mean_information(
    Omega: FloatArray,
    xi: FloatArray,
    mu: FloatArray,
    blocks: Sequence[int],
    sweeps: int = 1,
) -> FloatArray:
    """Amortised mean recovery (Table 12.5): block coordinate descent on ``Omega mu = xi``.

    For each block ``i`` (robot: 3 rows at 0; a landmark: 2 rows at its first row)::

        mu_i <- Omega_ii^-1 (xi_i - sum_{j != i} Omega_ij mu_j)

    i.e. one Gauss-Seidel step; it maximises ``exp(-mu^T Omega mu / 2 + xi^T mu)`` over ``mu_i``
    with the rest fixed, so repeated sweeps converge to ``Omega^-1 xi``.

    Parameters
    ----------
    Omega, xi, mu : ndarray, shapes (d, d), (d,), (d,)
    blocks : sequence of int
        First rows of the blocks to update, in order (0 means the robot).
    sweeps : int
        Number of passes over ``blocks``.

    Returns
    -------
    mu_new : ndarray, shape (d,)
    """
    mu = mu.copy()
    for _ in range(sweeps):
        for r in blocks:
            w = 3 if r == 0 else 2
            sl = slice(r, r + w)
            rhs = xi[sl] - Omega[sl, :] @ mu + Omega[sl, sl] @ mu[sl]
            mu[sl] = np.linalg.solve(Omega[sl, sl], rhs)
    return mu


def robot_link_information(Omega: FloatArray, rows: Sequence[int]) -> FloatArray:
    """Conditional mutual information (nats) between the robot and each landmark, given the rest.

    For a Gaussian in information form, the robot ``x`` and a landmark ``m`` conditioned on all
    other variables have joint information ``Omega_[x,m]`` (the 5x5 block), so::

        I(x; m | rest) = 1/2 (log det Omega_xx + log det Omega_mm - log det Omega_[x,m])

    It is zero exactly when the robot-landmark link ``Omega_xm`` is zero, and it measures what
    sparsification (Table 12.4) discards when it cuts that link: the ``"weakest"`` deactivation
    policy of :class:`SEIFSlam` deactivates the landmarks with the smallest value.

    Parameters
    ----------
    Omega : ndarray, shape (d, d)
        Information over the robot (rows 0..2) and landmarks (the local system is enough: the
        blocks used are the global ones).
    rows : sequence of int
        First row of each landmark.

    Returns
    -------
    ndarray, shape (len(rows),)
        Non-negative; ``inf`` never (a singular block raises).
    """
    k = len(rows)
    if k == 0:
        return np.zeros(0)
    r = np.asarray(rows, dtype=np.intp)
    idx = np.concatenate([np.broadcast_to(np.arange(3), (k, 3)), r[:, None] + np.arange(2)], 1)
    J = Omega[idx[:, :, None], idx[:, None, :]]  # (k, 5, 5)
    sign_j, logdet_j = np.linalg.slogdet(J)
    sign_m, logdet_m = np.linalg.slogdet(J[:, 3:, 3:])
    sign_x, logdet_x = np.linalg.slogdet(Omega[:3, :3])
    if sign_x <= 0 or np.any(sign_j <= 0) or np.any(sign_m <= 0):
        raise SingularInformationError("robot-landmark information block is not positive definite")
    return np.maximum(0.5 * (logdet_x + logdet_m - logdet_j), 0.0)
