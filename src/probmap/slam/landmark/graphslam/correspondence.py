"""Tables 11.8-11.9 of Probabilistic Robotics and the front end: GraphSLAM with unknown
correspondences.

:func:`graphslam_correspondence_test` is the test of Table 11.8 (with
:func:`landmark_joint_covariance`); :func:`optimize_graphslam_unknown` runs Table 11.9 with the
joint covariance of all landmarks (small maps; ``_merge_pass`` and ``_join_most_likely_first``).
:func:`optimize_graphslam_front_end` starts from the correspondences of an incremental
maximum-likelihood front end (:func:`graphslam_associate`), solves sparsely and tests only the
landmark pairs a KD-tree finds close, with their covariances from one sparse factorization
(:func:`landmark_pair_covariances`).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

import probmap.slam.landmark.graphslam._kernels as _k
from probmap._typing import BoolArray, FloatArray, IntArray
from probmap.geometry.se2 import wrap_angle
from probmap.models.measurement import RangeBearingModel
from probmap.slam.landmark.graphslam.linearize import (
    _chi2_gate_2dof,
    _Linearizer,
    graphslam_linearize,
)
from probmap.slam.landmark.graphslam.optimize import (
    GraphSLAMResult,
    _replace_cfg,
    optimize_graphslam,
)
from probmap.slam.landmark.graphslam.problem import (
    GraphSLAMConfig,
    GraphSLAMProblem,
    _measurements,
    motion_chain,
)

__all__ = [
    "graphslam_correspondence_test",
    "landmark_joint_covariance",
    "optimize_graphslam_unknown",
    "optimize_graphslam_front_end",
    "graphslam_associate",
    "landmark_pair_covariances",
]


# ------------------------------------------------------------------ Tables 11.8-11.9
def landmark_joint_covariance(H: sp.spmatrix, n_pose_vars: int) -> FloatArray:
    """The joint marginal covariance ``Sigma_mm`` (2L, 2L) of all landmarks: the landmark rows
    of ``H^-1``, from one sparse factorization and ``2L`` solves (small maps only)."""
    Hc = sp.csc_matrix(H)
    n = Hc.shape[0]
    m = n - n_pose_vars
    if m == 0:
        return np.zeros((0, 0))
    lu = splu(
        Hc, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
    )
    E = np.zeros((n, m))
    E[n_pose_vars + np.arange(m), np.arange(m)] = 1.0
    Sm = np.asarray(lu.solve(E), dtype=np.float64)[n_pose_vars:]
    return 0.5 * (Sm + Sm.T)


def graphslam_correspondence_test(
    landmarks: FloatArray, joint_covariance: FloatArray, pairs: IntArray
) -> tuple[FloatArray, FloatArray]:
    """The correspondence test of Table 11.8 for landmark pairs ``(j, k)``.

    The book marginalizes everything but ``m_j, m_k`` (lines 2-3), maps them to the difference
    ``Delta = m_j - m_k`` (lines 4-6) and returns the Gaussian density of ``Delta = 0``
    (line 7). In moments: ``Delta ~ N(mu_j - mu_k, Sigma_jj + Sigma_kk - Sigma_jk - Sigma_kj)``.

    Parameters
    ----------
    landmarks : ndarray, shape (L, 2)
    joint_covariance : ndarray, shape (2L, 2L)
        :func:`landmark_joint_covariance`.
    pairs : ndarray of int, shape (P, 2)

    Returns
    -------
    d2 : ndarray, shape (P,)
        ``mu_Delta^T Sigma_Delta^-1 mu_Delta`` (chi-square, 2 dof, when ``j`` and ``k`` are one
        landmark).
    probability : ndarray, shape (P,)
        ``|2 pi Sigma_Delta|^-1/2 exp(-d2 / 2)``, the book's value.
    """
    pr = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    j, k = pr[:, 0], pr[:, 1]
    C = joint_covariance.reshape(landmarks.shape[0], 2, landmarks.shape[0], 2)
    S = C[j, :, j, :] + C[k, :, k, :] - C[j, :, k, :] - C[k, :, j, :]
    d = landmarks[j] - landmarks[k]
    det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
    det = np.maximum(det, 1e-300)
    d2 = S[:, 1, 1] * d[:, 0] ** 2 - 2 * S[:, 0, 1] * d[:, 0] * d[:, 1] + S[:, 0, 0] * d[:, 1] ** 2
    d2 = d2 / det
    return d2, np.exp(-0.5 * d2) / (2 * np.pi * np.sqrt(det))


def _merge_pass(
    problem: GraphSLAMProblem, Lm: FloatArray, Sigma_mm: FloatArray, gate: float
) -> IntArray | None:
    """One round of Table 11.9's merges: landmark pairs passing the correspondence test, most
    likely first, joined unless the two were seen from one pose (two observations at one time
    are two landmarks). Returns the new slot of every landmark, or None when nothing merges.
    (Merging each hypothesis at most once per round, so that every merge is re-solved first,
    stalled with more duplicates left on simulation.)"""
    from scipy.spatial import cKDTree

    L = Lm.shape[0]
    if L < 2:
        return None
    sd = np.sqrt(np.maximum(np.diagonal(Sigma_mm).reshape(L, 2).max(axis=1), 0.0))
    radius = float(np.sqrt(gate) * 2.0 * sd.max()) + 1e-9
    pairs = np.array(sorted(cKDTree(Lm).query_pairs(radius)), dtype=np.int64).reshape(-1, 2)
    if pairs.size == 0:
        return None
    d2, _ = graphslam_correspondence_test(Lm, Sigma_mm, pairs)
    ok = d2 < gate
    pairs, d2 = pairs[ok], d2[ok]
    if pairs.size == 0:
        return None
    nodes: list[set[int]] = [set() for _ in range(L)]
    for n, j in zip(problem.obs_node, problem.obs_landmark, strict=True):
        nodes[int(j)].add(int(n))
    return _join_most_likely_first(pairs, d2, nodes)


def _join_most_likely_first(
    pairs: IntArray, d2: FloatArray, nodes: list[set[int]]
) -> IntArray | None:
    """Join the landmark ``pairs`` (P, 2) that passed the correspondence test, smallest
    Mahalanobis distance ``d2`` first (union-find), unless the two groups were seen from one
    pose (``nodes[j]``: the poses that observed landmark ``j``; two observations at one time
    are two landmarks). Returns the new slot of each of the ``len(nodes)`` landmarks, or None
    when nothing was joined. ``nodes`` is updated in place."""
    parent = np.arange(len(nodes))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = int(parent[a])
        return a

    merged = False
    for a, b in pairs[np.argsort(d2)]:
        ra, rb = root(int(a)), root(int(b))
        if ra == rb or nodes[ra] & nodes[rb]:
            continue
        parent[rb] = ra
        nodes[ra] |= nodes[rb]
        merged = True
    if not merged:
        return None
    roots = np.array([root(i) for i in range(len(nodes))])
    _, slot = np.unique(roots, return_inverse=True)
    return slot.astype(np.int64)


def optimize_graphslam_unknown(
    problem: GraphSLAMProblem,
    config: GraphSLAMConfig | None = None,
    *,
    correspondence_probability: float = 0.99,
    max_rounds: int = 40,
    max_hypotheses: int = 4000,
) -> tuple[GraphSLAMResult, GraphSLAMProblem]:
    """GraphSLAM with unknown correspondences (Table 11.9): start from the given landmark
    hypotheses (e.g. one per observation), solve, merge the pairs that pass the correspondence
    test (Table 11.8) at the chi-square ``correspondence_probability`` gate, and repeat until
    nothing merges. Needs the joint landmark covariance, so it suits small maps (hundreds of
    hypotheses).

    Returns the final result and the problem with its merged landmark slots. More than
    ``max_hypotheses`` hypotheses raise ``ValueError`` (Victoria Park has 48,000): large logs
    take :func:`optimize_graphslam_front_end` instead (what :class:`GraphSLAM` runs).
    """
    cfg = config if config is not None else GraphSLAMConfig()
    if problem.n_landmarks > max_hypotheses:
        raise ValueError(
            f"{problem.n_landmarks:,} landmark hypotheses are too many for GraphSLAM's unknown-"
            f"correspondence loop (its joint covariance; at most {max_hypotheses:,}): give "
            "landmark ids, or use the EKF or SEIF on this log"
        )
    gate = _chi2_gate_2dof(correspondence_probability)
    res = optimize_graphslam(problem, cfg)
    for _ in range(max_rounds):
        sysm = graphslam_linearize(problem, res.nodes, res.landmarks, cfg)
        Sigma_mm = landmark_joint_covariance(sysm.H, sysm.n_pose_vars)
        slot = _merge_pass(problem, res.landmarks, Sigma_mm, gate)
        if slot is None:
            break
        from dataclasses import replace

        n_new = int(slot.max()) + 1
        Lm = np.zeros((n_new, 2))
        np.add.at(Lm, slot, res.landmarks)
        Lm /= np.bincount(slot, minlength=n_new)[:, None]
        problem = replace(
            problem,
            obs_landmark=slot[problem.obs_landmark],
            landmark_ids=np.arange(n_new, dtype=np.int64),
        )
        res = optimize_graphslam(problem, cfg, initial=(res.nodes, Lm))
    return res, problem


# --------------------------------------------------------------- unknown correspondences
def _body_increments(
    problem: GraphSLAMProblem, floor: tuple[float, float, float]
) -> tuple[FloatArray, FloatArray]:
    """Every segment's motion ``d (S, 3)`` and its noise ``Sigma (S, 3, 3)`` in the frame of its
    start node (the models move in the robot frame, so these do not depend on the start pose)."""
    K = problem.n_nodes
    ch = motion_chain(problem, np.zeros((K, 3)), floor)
    end = problem.seg_ptr[1:] - 1
    return ch.xbar[end], ch.Sig[end]


def graphslam_associate(
    problem: GraphSLAMProblem,
    *,
    gate_probability: float = 0.99,
    new_landmark_probability: float = 0.9999,
    floor: tuple[float, float, float] = (1e-6, 1e-6, 1e-8),
) -> tuple[IntArray, FloatArray, FloatArray]:
    """Initial correspondences for GraphSLAM (the front end of Table 11.9's loop).

    The poses are walked in order along the odometry (the segments' motion and noise); at each
    pose its observations are associated by maximum likelihood with Mahalanobis gating
    (:func:`~probmap.slam.landmark.association.associate_ml`, Table 10.2 lines 16-18) against the
    landmarks mapped so far, with ``S = H_x P H_x^T + H_m P_m H_m^T + Q`` from the pose's and each
    landmark's own covariance. The matched ones correct the pose and those landmarks together
    (one EKF update of the pose and the few landmarks involved, Table 10.1 lines 12-18, their
    cross-covariances with everything else ignored, which keeps a step O(1) in the map size);
    an observation beyond the ``new_landmark_probability`` gate of every landmark starts a new
    one (inverse measurement model), and one between the gates is left out. Ignoring the
    cross-covariances makes the estimate overconfident after a long loop, so a revisited tree
    may come back as a second landmark: the correspondence test of Table 11.8 merges those
    after the batch solve (:func:`optimize_graphslam_unknown`).

    Parameters
    ----------
    problem : GraphSLAMProblem
        Its ``obs_landmark`` is ignored.
    gate_probability, new_landmark_probability : float
        Chi-square probabilities (2 dof) of the acceptance and new-landmark gates.
    floor : (3,) float
        The motion noise floor (variance per second), as in :class:`GraphSLAMConfig`.

    Returns
    -------
    slot : ndarray of int64, shape (k,)
        Landmark of every observation, or -1 for one left out.
    X : ndarray, shape (K, 3)
        The front end's pose of every node.
    Lm : ndarray, shape (L, 2)
        Its landmarks (``L = slot.max() + 1``).
    """
    if not 0 < gate_probability <= new_landmark_probability < 1:
        raise ValueError("need 0 < gate_probability <= new_landmark_probability < 1")
    gate = _chi2_gate_2dof(gate_probability)
    new_gate = _chi2_gate_2dof(new_landmark_probability)
    K = problem.n_nodes
    model = problem.measurement_model
    if K > 1:
        d, Sig = _body_increments(problem, floor)
    else:
        d, Sig = np.zeros((0, 3)), np.zeros((0, 3, 3))
    if type(model) is not RangeBearingModel:
        return _associate_python(problem, gate, new_gate, d, Sig)
    n_obs = problem.z.shape[0]
    slot = np.full(n_obs, -1, dtype=np.int64)
    X = np.zeros((K, 3))
    Lm = np.zeros((max(n_obs, 1), 2))
    Pm = np.zeros((max(n_obs, 1), 2, 2))
    L = _k.associate_front_end(
        np.asarray(problem.prior_mean, dtype=np.float64).copy(),
        np.linalg.inv(problem.prior_information),
        np.ascontiguousarray(d),
        np.ascontiguousarray(Sig),
        np.searchsorted(problem.obs_node, np.arange(K + 1)).astype(np.int64),
        np.ascontiguousarray(problem.z, dtype=np.float64),
        np.asarray(model.sensor_offset, dtype=np.float64),
        np.ascontiguousarray(model.R, dtype=np.float64),
        float(gate),
        float(new_gate),
        _reach(problem),
        slot,
        X,
        Lm,
        Pm,
    )
    if L < 0:
        raise ValueError("a landmark coincides with the sensor position (zero range)")
    return slot, X, Lm[:L].copy()


def _reach(problem: GraphSLAMProblem) -> float:
    """Landmarks farther than this from the robot (m) are not candidates for association."""
    return float(problem.z[:, 0].max()) + 5.0 if problem.z.shape[0] else 0.0


def _associate_python(
    problem: GraphSLAMProblem, gate: float, new_gate: float, d: FloatArray, Sig: FloatArray
) -> tuple[IntArray, FloatArray, FloatArray]:
    """:func:`graphslam_associate` for any measurement model with ``predict_many`` and
    ``inverse`` (and the reference of its compiled kernel in the tests)."""
    from probmap.slam.landmark.association import NEW, associate_ml

    K = problem.n_nodes
    model = problem.measurement_model
    Q = np.asarray(model.R, dtype=np.float64)
    n_obs = problem.z.shape[0]
    slot = np.full(n_obs, -1, dtype=np.int64)
    X = np.zeros((K, 3))
    Lm = np.zeros((max(n_obs, 1), 2))
    Pm = np.zeros((max(n_obs, 1), 2, 2))
    L = 0
    x = np.asarray(problem.prior_mean, dtype=np.float64).copy()
    P = np.linalg.inv(problem.prior_information)
    obs_ptr = np.searchsorted(problem.obs_node, np.arange(K + 1))
    reach = _reach(problem)
    for s in range(K):
        if s > 0:  # predict along the segment: x <- x (+) d, P <- F P F^T + Rt^T Sigma Rt
            c, sn = math.cos(x[2]), math.sin(x[2])
            dx, dy = d[s - 1, 0], d[s - 1, 1]
            F = np.eye(3)
            F[0, 2] = -sn * dx - c * dy
            F[1, 2] = c * dx - sn * dy
            Rw = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
            x = np.array([x[0] + c * dx - sn * dy, x[1] + sn * dx + c * dy, x[2] + d[s - 1, 2]])
            x[2] = wrap_angle(x[2])
            P = F @ P @ F.T + Rw @ Sig[s - 1] @ Rw.T
        a, b = int(obs_ptr[s]), int(obs_ptr[s + 1])
        if b > a:
            z = problem.z[a:b]
            k = b - a
            if L:
                near = np.flatnonzero(np.hypot(Lm[:L, 0] - x[0], Lm[:L, 1] - x[1]) < reach)
            else:
                near = np.zeros(0, dtype=np.int64)
            if near.size:
                zh, Hx, Hm = _measurements(
                    model, x[None, :], Lm[near], np.zeros(near.size, np.int64), np.arange(near.size)
                )
                S = Hx @ P @ Hx.transpose(0, 2, 1) + Hm @ Pm[near] @ Hm.transpose(0, 2, 1) + Q
                match = associate_ml(z, zh, S, gate=gate, new_gate=new_gate).match
            else:
                match = np.full(k, NEW, dtype=np.int64)
            hit = np.flatnonzero(match >= 0)
            if hit.size:  # one EKF update of the pose and the matched landmarks
                js = near[match[hit]]
                m = hit.size
                n = 3 + 2 * m
                mu = np.concatenate([x, Lm[js].ravel()])
                C = np.zeros((n, n))
                C[:3, :3] = P
                for q, j in enumerate(js):
                    C[3 + 2 * q : 5 + 2 * q, 3 + 2 * q : 5 + 2 * q] = Pm[j]
                zh, Hx, Hm = _measurements(
                    model, x[None, :], Lm[js], np.zeros(m, np.int64), np.arange(m)
                )
                H = np.zeros((2 * m, n))
                for q in range(m):
                    H[2 * q : 2 * q + 2, :3] = Hx[q]
                    H[2 * q : 2 * q + 2, 3 + 2 * q : 5 + 2 * q] = Hm[q]
                nu = z[hit] - zh
                nu[:, 1] = wrap_angle(nu[:, 1])
                HC = H @ C
                Sfull = HC @ H.T + np.kron(np.eye(m), Q)
                Kg = np.linalg.solve(Sfull, HC).T
                mu = mu + Kg @ nu.ravel()
                C = C - Kg @ HC
                C = 0.5 * (C + C.T)
                x = mu[:3].copy()
                x[2] = wrap_angle(x[2])
                P = C[:3, :3].copy()
                Lm[js] = mu[3:].reshape(m, 2)
                for q, j in enumerate(js):
                    Pm[j] = C[3 + 2 * q : 5 + 2 * q, 3 + 2 * q : 5 + 2 * q]
                slot[a + hit] = js
            for i in np.flatnonzero(match == NEW):
                xy, Jx, Jz = model.inverse(x, z[i])
                Lm[L] = xy
                Pm[L] = Jx @ P @ Jx.T + Jz @ Q @ Jz.T
                slot[a + i] = L
                L += 1
        X[s] = x
    return slot, X, Lm[:L].copy()


def landmark_pair_covariances(H: sp.spmatrix, n_pose_vars: int, landmarks: IntArray) -> FloatArray:
    """The joint marginal covariance of a few landmarks (the rows and columns of ``H^-1`` for
    ``landmarks``): one sparse factorization of ``H`` and ``2 m`` solves, so it scales to large
    maps where :func:`landmark_joint_covariance` (all ``2L`` columns) does not.

    Parameters
    ----------
    H : scipy.sparse matrix, shape (n, n)
        The information matrix at the solution.
    n_pose_vars : int
    landmarks : ndarray of int, shape (m,)
        Landmark slots.

    Returns
    -------
    ndarray, shape (2m, 2m)
        ``Cov(m_landmarks[0], m_landmarks[1], ...)``, landmark ``i`` at rows ``2i, 2i + 1``.
    """
    lm = np.asarray(landmarks, dtype=np.int64).reshape(-1)
    if lm.size == 0:
        return np.zeros((0, 0))
    Hc = sp.csc_matrix(H)
    n = Hc.shape[0]
    rows = (n_pose_vars + 2 * lm[:, None] + np.arange(2)).ravel()
    try:
        lu = splu(
            Hc, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
        )
    except RuntimeError as exc:
        raise ValueError(f"the information matrix is singular ({exc})") from exc
    C = np.empty((rows.size, rows.size))
    for a in range(0, rows.size, 128):  # columns in chunks: (n, 128) at a time, not (n, 2m)
        cols = rows[a : a + 128]
        E = np.zeros((n, cols.size))
        E[cols, np.arange(cols.size)] = 1.0
        C[:, a : a + cols.size] = np.asarray(lu.solve(E), dtype=np.float64)[rows]
    return 0.5 * (C + C.T)


def _merge_candidates(
    problem: GraphSLAMProblem,
    Lm: FloatArray,
    H: sp.spmatrix,
    n_pose_vars: int,
    gate: float,
    radius: float,
) -> IntArray | None:
    """Table 11.9's merges at scale: candidate pairs are the landmarks closer than ``radius``
    (a KD-tree), tested with :func:`graphslam_correspondence_test` on the joint covariance of
    the landmarks involved (:func:`landmark_pair_covariances`), and joined most likely first
    unless the two were seen from one pose. Returns the new slot of every landmark, or None."""
    from scipy.spatial import cKDTree

    L = Lm.shape[0]
    if L < 2:
        return None
    pairs = np.array(sorted(cKDTree(Lm).query_pairs(radius)), dtype=np.int64).reshape(-1, 2)
    if pairs.size == 0:
        return None
    # two landmarks seen from one pose are two trees: no test needed
    order = np.argsort(problem.obs_landmark, kind="stable")
    ptr = np.searchsorted(problem.obs_landmark[order], np.arange(L + 1))
    nodes = [problem.obs_node[order[ptr[j] : ptr[j + 1]]] for j in range(L)]
    apart = np.array([np.intersect1d(nodes[a], nodes[b]).size == 0 for a, b in pairs], dtype=bool)
    pairs = pairs[apart]
    if pairs.size == 0:
        return None
    used, inv = np.unique(pairs, return_inverse=True)
    C = landmark_pair_covariances(H, n_pose_vars, used)
    d2, _ = graphslam_correspondence_test(Lm[used], C, inv.reshape(-1, 2))
    ok = d2 < gate
    pairs, d2 = pairs[ok], d2[ok]
    if pairs.size == 0:
        return None
    return _join_most_likely_first(pairs, d2, [set(int(v) for v in nodes[j]) for j in range(L)])


def _relabel(
    problem: GraphSLAMProblem, slot: IntArray, keep_obs: BoolArray | None = None
) -> GraphSLAMProblem:
    """``problem`` with observation ``i`` on landmark ``slot[obs_landmark[i]]`` (slots 0..n-1),
    keeping only ``keep_obs``."""
    from dataclasses import replace

    lm = slot[problem.obs_landmark]
    keep = np.ones(lm.size, dtype=bool) if keep_obs is None else keep_obs
    n = int(lm[keep].max()) + 1 if keep.any() else 0
    return replace(
        problem,
        obs_node=problem.obs_node[keep],
        z=problem.z[keep],
        obs_landmark=lm[keep].astype(np.int64),
        landmark_ids=np.arange(n, dtype=np.int64),
    )


def _mean_by_slot(Lm: FloatArray, slot: IntArray) -> FloatArray:
    n = int(slot.max()) + 1
    out = np.zeros((n, 2))
    np.add.at(out, slot, Lm)
    return out / np.bincount(slot, minlength=n)[:, None]


def _confirmed_before_misses(
    problem: GraphSLAMProblem, X: FloatArray, Lm: FloatArray, cfg: GraphSLAMConfig
) -> BoolArray:
    """Which landmarks reach ``min_observations`` sightings before more than ``max_misses``
    poses (after their first sighting) had them in view without seeing them: the EKF's
    provisional-landmark rule (section 10.3.3) replayed on the smoothed path. Only poses that
    observed something count (the scans)."""
    from scipy.spatial import cKDTree

    assert cfg.visibility_range is not None
    L = Lm.shape[0]
    ok = np.ones(L, dtype=bool)
    if L == 0:
        return ok
    scans = np.unique(problem.obs_node)
    dx, dy, dth = problem.measurement_model.sensor_offset
    c, s = np.cos(X[scans, 2]), np.sin(X[scans, 2])
    sensor = np.column_stack([X[scans, 0] + c * dx - s * dy, X[scans, 1] + s * dx + c * dy])
    near = cKDTree(sensor).query_ball_tree(cKDTree(Lm), float(cfg.visibility_range))
    node = np.repeat(scans, [len(v) for v in near])
    lm = np.fromiter((j for v in near for j in v), dtype=np.int64, count=node.size)
    d = Lm[lm] - sensor[np.searchsorted(scans, node)]
    bearing = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - X[node, 2] - dth)
    vis = np.abs(bearing) <= 0.5 * cfg.visibility_fov
    node, lm = node[vis], lm[vis]
    seen = set(zip(problem.obs_node.tolist(), problem.obs_landmark.tolist(), strict=True))
    first = np.full(L, np.iinfo(np.int64).max)
    np.minimum.at(first, problem.obs_landmark, problem.obs_node)
    # every (node, landmark) event after the first sighting, in time order: hit or miss
    after = node >= first[lm]
    node, lm = node[after], lm[after]
    hit = np.array(
        [(n, j) in seen for n, j in zip(node.tolist(), lm.tolist(), strict=True)], dtype=np.int64
    )
    order = np.lexsort((node, lm))
    lm, hit = lm[order], hit[order]
    need = int(cfg.min_observations)
    bounds = np.searchsorted(lm, np.arange(L + 1))
    for j in range(L):
        h = hit[bounds[j] : bounds[j + 1]]
        confirmed_at = np.flatnonzero(np.cumsum(h) >= need)
        stop = int(confirmed_at[0]) if confirmed_at.size else h.size
        if int((1 - h[:stop]).sum()) > cfg.max_misses:
            ok[j] = False
    return ok


def optimize_graphslam_front_end(
    problem: GraphSLAMProblem,
    config: GraphSLAMConfig | None = None,
    *,
    max_rounds: int = 10,
) -> tuple[GraphSLAMResult, GraphSLAMProblem]:
    """GraphSLAM with unknown correspondences on large logs (Table 11.9 from a front end).

    1. Initial correspondences and a starting point from :func:`graphslam_associate`
       (incremental maximum-likelihood association along the odometry, gates
       ``config.association_probability`` and ``config.new_landmark_probability``).
    2. The sparse batch solve (:func:`optimize_graphslam`, with the robust kernel and outlier
       rejection of ``config``).
    3. The correspondence test of Table 11.8 on the pairs of landmarks closer than
       ``config.merge_radius`` (a KD-tree, so the number of tests grows with the map, not its
       square; their joint covariance from :func:`landmark_pair_covariances`), merging those
       under the ``config.correspondence_probability`` gate; back to 2 until nothing merges
       (at most ``max_rounds`` times).
    4. Landmarks seen fewer than ``config.min_observations`` times are dropped with their
       observations (a landmark seen once is fitted exactly and tells nothing about the path;
       the EKF likewise reports a landmark only after ``accept_hits`` sightings) and the log is
       solved a last time, with covariances if ``config`` asks for them.

    Parameters
    ----------
    problem : GraphSLAMProblem
        Its ``obs_landmark`` and ``landmark_ids`` are ignored.
    config : GraphSLAMConfig, optional
    max_rounds : int
        Most merge rounds.

    Returns
    -------
    result : GraphSLAMResult
    problem : GraphSLAMProblem
        ``problem`` with the observations kept and their final landmark slots.
    """
    cfg = config if config is not None else GraphSLAMConfig()
    gate = _chi2_gate_2dof(cfg.correspondence_probability)
    slot, X, Lm = graphslam_associate(
        problem,
        gate_probability=cfg.association_probability,
        new_landmark_probability=cfg.new_landmark_probability,
        floor=cfg.motion_noise_floor,
    )
    from dataclasses import replace

    seen = slot >= 0
    prob = replace(problem, obs_landmark=np.maximum(slot, 0))
    prob = _relabel(prob, np.arange(max(Lm.shape[0], 1), dtype=np.int64), seen)
    # the Schur solver's dense (3K, 2L) block is O(K L) memory on a long log with a large map:
    # the iterations factor the sparse system instead (the same step)
    solver = "sparse" if cfg.solver == "schur" else cfg.solver
    cfg = _replace_cfg(cfg, solver=solver)
    inner = _replace_cfg(cfg, covariances=False)
    res = optimize_graphslam(prob, inner, initial=(X, Lm))
    for _ in range(max_rounds):
        lin = _Linearizer(prob, inner)
        sysm = lin.linearize(res.nodes, res.landmarks)
        new = _merge_candidates(
            prob, res.landmarks, sysm.H, sysm.n_pose_vars, gate, cfg.merge_radius
        )
        if new is None:
            break
        Lm = _mean_by_slot(res.landmarks, new)
        prob = _relabel(prob, new)
        res = optimize_graphslam(prob, inner, initial=(res.nodes, Lm))
    count = np.bincount(prob.obs_landmark, minlength=prob.n_landmarks)
    strong = count >= int(cfg.min_observations)
    if cfg.visibility_range is not None:
        strong &= _confirmed_before_misses(prob, res.nodes, res.landmarks, cfg)
    if not strong.all():
        new = np.cumsum(strong) - 1
        keep = strong[prob.obs_landmark]
        Lm = res.landmarks[strong]
        prob = _relabel(prob, new, keep)
    else:
        Lm = res.landmarks
    res = optimize_graphslam(prob, cfg, initial=(res.nodes, Lm))
    return res, prob
