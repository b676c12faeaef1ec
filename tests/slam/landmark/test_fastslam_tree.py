"""FastSLAM's shared landmark tree (Montemerlo's balanced binary tree, copy-on-write): the tree
against the flat arrays on random operation sequences, reference counts recounted from the
roots, node copies per resample and per update, and a seeded run equal to the flat store's."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from probmap.slam.landmark.fastslam import FastSLAM, FastSLAMConfig, FlatLandmarks, LandmarkTree


def _recount(tree: LandmarkTree) -> tuple[dict[int, int], set[int]]:
    """Pure-Python reference of the reference counts: walk every particle's tree from its root
    and count the pointers to each node; returns the counts and the reachable nodes."""
    counts: dict[int, int] = {}
    reach: set[int] = set()
    for r in tree.roots.tolist():
        if r:
            counts[r] = counts.get(r, 0) + 1
    stack = [r for r in set(tree.roots.tolist()) if r]
    while stack:
        x = stack.pop()
        if x in reach:
            continue
        reach.add(x)
        for c in tree._child[x].tolist():
            if c:
                counts[c] = counts.get(c, 0) + 1
                stack.append(c)
    return counts, reach


def _check_invariants(tree: LandmarkTree) -> None:
    counts, reach = _recount(tree)
    for x in reach:
        assert tree._refc[x] == counts[x], f"node {x}: refc {tree._refc[x]}, pointers {counts[x]}"
    assert tree.nodes_in_use == len(reach)  # no leak, nothing freed while in use
    free = set(tree._free[: tree._top[0]].tolist())
    assert not free & reach and 0 not in free


def _random_rows(rng, m):
    return rng.normal(size=(m, 2)), rng.normal(size=(m, 2, 2)), rng.integers(0, 9, m)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tree_reads_back_what_the_flat_store_does(seed):
    """Random scatter / clear / resample / growth sequences: every read of the tree (one
    column per particle, and all columns) equals the flat reference's, and the reference
    counts equal the pointers recounted from the roots after every operation."""
    rng = np.random.default_rng(seed)
    m = 7
    flat, tree = FlatLandmarks(m), LandmarkTree(m, capacity=4)  # a small pool grows often
    n_cols = 1
    for _ in range(300):
        op = rng.integers(0, 5)
        if op == 0 and n_cols < 40:
            n_cols += int(rng.integers(1, 6))
            flat.ensure_cols(n_cols)
            tree.ensure_cols(n_cols)
        flat.ensure_cols(n_cols)
        tree.ensure_cols(n_cols)
        cols = rng.integers(-1, n_cols, m)
        if op in (0, 1, 2):
            mean, cov, count = _random_rows(rng, m)
            flat.scatter(cols, mean, cov, count)
            tree.scatter(cols, mean, cov, count)
        elif op == 3:
            flat.clear(cols)
            tree.clear(cols)
        else:
            keep = np.sort(rng.integers(0, m, m))
            flat.resample(keep)
            tree.resample(keep)
        _check_invariants(tree)
        probe = rng.integers(-1, n_cols, m)
        (fm, fc, fn, ff), (tm, tc, tn, tf) = flat.gather(probe), tree.gather(probe)
        np.testing.assert_array_equal(ff, tf)  # the values of absent rows are unspecified
        np.testing.assert_array_equal(fm[ff], tm[tf])
        np.testing.assert_array_equal(fc[ff], tc[tf])
        np.testing.assert_array_equal(fn[ff], tn[tf])
    f_mean, f_cov, f_count, f_found = flat.dense()
    t_mean, t_cov, t_count, t_found = tree.dense()
    np.testing.assert_array_equal(f_found, t_found)
    np.testing.assert_array_equal(f_mean[f_found], t_mean[t_found])
    np.testing.assert_array_equal(f_cov[f_found], t_cov[t_found])
    np.testing.assert_array_equal(f_count[f_found], t_count[t_found])
    sub = np.array([3, 0])
    (fm, fc, fn, ff), (tm, tc, tn, tf) = flat.dense(sub), tree.dense(sub)
    np.testing.assert_array_equal(ff, tf)
    np.testing.assert_array_equal(fm[ff], tm[tf])
    np.testing.assert_array_equal(fc[ff], tc[tf])
    np.testing.assert_array_equal(fn[ff], tn[tf])


def _filled_tree(m: int, n: int) -> LandmarkTree:
    tree = LandmarkTree(m)
    tree.ensure_cols(n)
    rng = np.random.default_rng(0)
    for c in range(n):
        mean, cov, count = _random_rows(rng, m)
        tree.scatter(np.full(m, c), mean, cov, count)
    return tree


@pytest.mark.parametrize("n", [16, 1024])
def test_resampling_copies_no_node_and_an_update_copies_a_path(n):
    """The memory a resample costs does not grow with the landmarks (counted in nodes, not
    timed): resampling copies no node and frees the unused particles' nodes; one landmark
    updated in every particle afterwards copies at most the ``depth + 1`` nodes of its path
    per particle, ``O(M log N)`` where the flat store copies ``O(M N)``."""
    m = 20
    tree = _filled_tree(m, n)
    in_use = tree.nodes_in_use
    copied = tree.nodes_copied
    rng = np.random.default_rng(1)
    keep = np.sort(rng.integers(0, m, m))
    tree.resample(keep)
    assert tree.nodes_copied == copied  # resampling copies nothing
    assert tree.nodes_in_use <= in_use  # and only frees
    _check_invariants(tree)
    mean, cov, count = _random_rows(rng, m)
    tree.scatter(np.full(m, n // 2), mean, cov, count)
    assert tree.depth == int(np.ceil(np.log2(n)))
    assert tree.nodes_copied - copied <= m * (tree.depth + 1)
    _check_invariants(tree)
    # an exclusive path is rewritten in place: the same landmark again copies nothing
    before = tree.nodes_copied
    tree.scatter(np.full(m, n // 2), mean, cov, count)
    assert tree.nodes_copied == before


def test_tree_state_after_resampling_is_smaller_than_the_flat_one():
    """After resampling onto one particle the tree holds one map (plus nothing), the flat
    store M copies of it."""
    m, n = 50, 512
    tree = _filled_tree(m, n)
    flat = FlatLandmarks(m)
    flat.ensure_cols(n)
    tree.resample(np.zeros(m, dtype=np.int64))
    flat.resample(np.zeros(m, dtype=np.int64))
    assert tree.nodes_in_use == 2 * n - 1  # one full tree: n leaves, n - 1 inner nodes
    assert tree.nbytes() < flat.nbytes() / 10


@pytest.mark.parametrize(("version", "known"), [(1, True), (2, True), (2, False)])
def test_tree_run_equals_the_flat_run(version, known):
    """A seeded simulation (identical random stream): the tree store gives the flat store's
    estimates bit for bit, with known and unknown correspondences."""
    from probmap.datasets.simulation import simulate_landmarks

    ds = simulate_landmarks(15, 80, seed=5, known_correspondences=known)
    out = {}
    for store in ("flat", "tree"):
        cfg = FastSLAMConfig(20, version, 0.5, seed=2, landmark_store=store, visibility_range=10.0,
                             visibility_fov=np.pi, new_landmark_likelihood=1e-2)  # fmt: skip
        fs = FastSLAM(ds.motion_model, ds.measurement_model, ds.initial_pose, cfg)
        poses = []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for step in ds:
                fs.predict(step.control, step.dt)
                fs.update(step.z, step.ids)
                poses.append(fs.pose)
        out[store] = (np.array(poses), fs.landmarks(), fs.resamples)
    assert out["flat"][2] == out["tree"][2] > 0
    np.testing.assert_array_equal(out["flat"][0], out["tree"][0])
    for a, b in zip(out["flat"][1], out["tree"][1], strict=True):
        np.testing.assert_array_equal(a, b)
