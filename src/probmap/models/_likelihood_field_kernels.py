"""Numba kernels of the likelihood field model (private; see :mod:`probmap.models.likelihood_field`).

Every kernel takes contiguous arrays and scalars only; the public class validates inputs. The
lookups use ``fastmath`` (they only add table entries and test bounds on finite coordinates; no
NaN or infinity reaches them), which lets LLVM reorder the sums. Grid convention: arrays indexed
``[iy, ix]``, row 0 at the smallest y, ``(x0, y0)`` the lower-left corner of cell ``[0, 0]``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def endpoints_in_robot_frame(ranges, angles, offset, max_range, lx, ly, valid):
    """Beam endpoints in the robot frame (sensor offset applied once per scan).

    ``valid[b]`` is False for max-range or non-finite readings, which the likelihood field
    skips (Probabilistic Robotics Table 6.3, line 4).
    """
    c = math.cos(offset[2])
    s = math.sin(offset[2])
    for b in range(ranges.shape[0]):
        r = ranges[b]
        ok = math.isfinite(r) and r < max_range and r >= 0.0
        valid[b] = ok
        if not ok:
            r = 0.0
        px = r * math.cos(angles[b])
        py = r * math.sin(angles[b])
        lx[b] = offset[0] + c * px - s * py
        ly[b] = offset[1] + s * px + c * py


@njit(cache=True, fastmath=True, inline="always")
def scan_log_likelihood(x, y, c, s, lx, ly, table, x0, y0, inv_res, outside):
    """Sum of the table's log-likelihoods at the endpoints ``lx, ly`` (B,) (robot frame) seen
    from the pose ``(x, y)`` with heading cosine and sine ``c, s``; ``outside`` for each endpoint
    off the table (Table 6.3, lines 3-8, summed in log space).

    The one lookup loop of the likelihood field: :func:`likelihood_field_sum` and MCL's fused
    step (:func:`probmap.filters._kernels.odometry_predict_and_weight`) inline it.
    """
    h, w = table.shape
    acc = 0.0
    for b in range(lx.shape[0]):
        fx = (x + c * lx[b] - s * ly[b] - x0) * inv_res
        fy = (y + s * lx[b] + c * ly[b] - y0) * inv_res
        if fx >= 0.0 and fy >= 0.0 and fx < w and fy < h:
            acc += table[int(fy), int(fx)]
        else:
            acc += outside
    return acc


@njit(cache=True, fastmath=True)
def likelihood_field_per_beam(poses, lx, ly, valid, table, x0, y0, inv_res, outside, out):
    """Per-beam log-likelihoods ``out[n, b]`` by lookup in a log-likelihood table ``(H, W)``."""
    h, w = table.shape
    for n in range(poses.shape[0]):
        x = poses[n, 0]
        y = poses[n, 1]
        c = math.cos(poses[n, 2])
        s = math.sin(poses[n, 2])
        for b in range(lx.shape[0]):
            if not valid[b]:
                out[n, b] = 0.0
                continue
            ex = x + c * lx[b] - s * ly[b]
            ey = y + s * lx[b] + c * ly[b]
            fx = (ex - x0) * inv_res
            fy = (ey - y0) * inv_res
            if fx >= 0.0 and fy >= 0.0 and fx < w and fy < h:
                out[n, b] = table[int(fy), int(fx)]
            else:
                out[n, b] = outside


@njit(cache=True, fastmath=True)
def likelihood_field_sum(poses, lx, ly, valid, table, x0, y0, inv_res, outside, out):
    """Sum over beams of the per-beam log-likelihoods: ``out[n]`` (one particle per row)."""
    nb = 0
    for b in range(lx.shape[0]):
        if valid[b]:
            nb += 1
    bx = np.empty(nb)
    by = np.empty(nb)
    k = 0
    for b in range(lx.shape[0]):
        if valid[b]:
            bx[k] = lx[b]
            by[k] = ly[b]
            k += 1
    for n in range(poses.shape[0]):
        c = math.cos(poses[n, 2])
        s = math.sin(poses[n, 2])
        out[n] = scan_log_likelihood(
            poses[n, 0], poses[n, 1], c, s, bx, by, table, x0, y0, inv_res, outside
        )
