"""Numba kernels for Monte Carlo localization (private; see :mod:`probmap.filters.mcl`).

Kernels take contiguous arrays and scalars; the public classes validate inputs once. The
fused update uses ``fastmath``: its inputs are finite by construction (validated poses, valid
beam endpoints only), and reordering the per-beam sum lets LLVM vectorise the lookups.
"""

from __future__ import annotations

import math

from numba import njit

from probmap.models._likelihood_field_kernels import scan_log_likelihood, scan_log_likelihood_walls


@njit(cache=True, fastmath=True, inline="always")
def _odometry_step(particles, n, noise, rot1, trans, rot2, sd1, sdt, sd2, reverse):
    """Move particle ``n`` by one odometry sample (Table 5.6) in place, its translation
    reversed when ``reverse``; returns its new ``(x, y, theta)``."""
    h1 = rot1 - sd1 * noise[n, 0]
    ht = trans - sdt * noise[n, 1]
    if reverse:
        ht = -ht
    h2 = rot2 - sd2 * noise[n, 2]
    th = particles[n, 2] + h1
    x = particles[n, 0] + ht * math.cos(th)
    y = particles[n, 1] + ht * math.sin(th)
    th = th + h2
    th = (th + math.pi) % (2.0 * math.pi) - math.pi
    particles[n, 0] = x
    particles[n, 1] = y
    particles[n, 2] = th
    return x, y, th


@njit(cache=True, fastmath=True)
def odometry_predict_and_weight(
    particles, noise, rot1, trans, rot2, sd1, sdt, sd2, lx, ly, table, x0, y0, inv_res, outside, lw
):
    """One fused pass per particle: odometry sample (Table 5.6), then likelihood field weight.

    ``particles`` (N, 3) is moved in place; ``noise`` (N, 3) holds standard normals;
    ``sd1, sdt, sd2`` are the standard deviations of rot1, trans and rot2; ``lx, ly`` (B,)
    the valid beam endpoints in the robot frame; ``lw`` (N,) receives the scan
    log-likelihood added to the previous log weight.
    """
    for n in range(particles.shape[0]):
        x, y, th = _odometry_step(particles, n, noise, rot1, trans, rot2, sd1, sdt, sd2, False)
        c = math.cos(th)
        s = math.sin(th)
        lw[n] += scan_log_likelihood(x, y, c, s, lx, ly, table, x0, y0, inv_res, outside)


@njit(cache=True)
def low_variance_indexes(weights, u, out):
    """Low-variance sampler (Table 4.4) on normalised ``weights`` with offset ``u`` in [0, 1).

    Writes ``len(out)`` indexes into ``out``.
    """
    m = out.shape[0]
    n = weights.shape[0]
    c = weights[0]
    i = 0
    for k in range(m):
        target = (u + k) / m
        while target >= c and i < n - 1:
            i += 1
            c += weights[i]
        out[k] = i


@njit(cache=True)
def gather_rows(src, idx, dst):
    """``dst[k] = src[idx[k]]`` for (N, 3) pose arrays."""
    for k in range(idx.shape[0]):
        j = idx[k]
        dst[k, 0] = src[j, 0]
        dst[k, 1] = src[j, 1]
        dst[k, 2] = src[j, 2]


@njit(cache=True, fastmath=True)
def odometry_predict_and_weight_robust(
    particles, noise, rot1, trans, rot2, sd1, sdt, sd2, lx, ly, table, x0, y0, inv_res, outside,
    walls, ox, oy, beam_angle, beam_range, margin, occ, slots, pool, cells, state, block,
    quantum, every, offset, lw,
):  # fmt: skip
    """:func:`odometry_predict_and_weight` with two robust parts, each optional.

    - ``walls``: beams that run through the map's walls count as random readings
      (:func:`probmap.models._likelihood_field_kernels.scan_log_likelihood_walls`; its
      arguments from ``ox`` to ``quantum``).
    - ``every > 0``: particle ``n`` with ``(n + offset) % every == 0`` moves by the odometry's
      translation reversed (odometry that logs reversing as forward driving), a systematic
      ``1 / every`` of the set.
    """
    for n in range(particles.shape[0]):
        back = every > 0 and (n + offset) % every == 0
        x, y, th = _odometry_step(particles, n, noise, rot1, trans, rot2, sd1, sdt, sd2, back)
        if walls:
            lw[n] += scan_log_likelihood_walls(
                x, y, th, lx, ly, table, x0, y0, inv_res, outside, ox, oy, beam_angle,
                beam_range, margin, occ, slots, pool, cells, state, block, quantum,
            )  # fmt: skip
        else:
            lw[n] += scan_log_likelihood(
                x, y, math.cos(th), math.sin(th), lx, ly, table, x0, y0, inv_res, outside
            )


@njit(cache=True)
def ess_fraction(lw, ll, gamma):
    """``ESS / N`` of the weights ``exp(lw + gamma * ll)`` (NaN in ``ll``: weight 0); 0 when
    every weight is 0. Two passes: the largest log-weight, then the sums."""
    n = lw.shape[0]
    top = -math.inf
    for i in range(n):
        if not math.isnan(ll[i]):
            x = lw[i] + gamma * ll[i]
            if x > top:
                top = x
    if not (top > -math.inf and top < math.inf):
        return 0.0
    s = 0.0
    s2 = 0.0
    for i in range(n):
        if not math.isnan(ll[i]):
            w = math.exp(lw[i] + gamma * ll[i] - top)
            s += w
            s2 += w * w
    return s * s / s2 / n


@njit(cache=True)
def pose_bounds(p, out):
    """Per column of the (N, 3) poses ``p`` (N >= 1), the smallest and the largest value:
    ``out[0] = (min x, min y, min theta)``, ``out[1]`` the maxima. One pass (numpy's
    ``max(axis=0)`` on an (N, 3) array is several times slower)."""
    for j in range(3):
        out[0, j] = p[0, j]
        out[1, j] = p[0, j]
    for i in range(1, p.shape[0]):
        for j in range(3):
            v = p[i, j]
            if v < out[0, j]:
                out[0, j] = v
            elif v > out[1, j]:
                out[1, j] = v


@njit(cache=True)
def adaptive_exponent(lw, ll, exponent, min_fraction):
    """The bisection of :func:`probmap.filters.mcl.mcl_adaptive_exponent` in one call: the
    same 30 halvings and :func:`ess_fraction` tests, so the same exponent."""
    if ess_fraction(lw, ll, exponent) >= min_fraction:
        return exponent
    lo = 0.0
    hi = exponent
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if ess_fraction(lw, ll, mid) >= min_fraction:
            lo = mid
        else:
            hi = mid
    return lo
