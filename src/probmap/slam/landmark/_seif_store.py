"""Sparse block storage of an information matrix over one robot pose and many 2-D landmarks.

The SEIF (Probabilistic Robotics, chapter 12) keeps the information matrix ``Omega`` and vector
``xi`` over the state ``(x, y, theta, m_1x, m_1y, ..., m_nx, m_ny)``. Sparsification keeps
``Omega`` sparse, so storing it densely (``(3 + 2n)^2`` numbers) would throw away the point of
the filter. Here it is stored as blocks:

- the robot block ``Omega_xx`` (3x3), the robot's ``xi_x`` (3,) and mean ``mu_x`` (3,);
- per landmark ``j`` a diagonal block ``Omega_jj`` (2x2), ``xi_j`` (2,) and ``mu_j`` (2,), in
  growable contiguous arrays indexed by the landmark's slot (amortised O(1) append);
- the robot-landmark links ``Omega_xj`` (3x2) in a dictionary keyed by slot: after
  sparsification only the active landmarks have one, so it holds at most ``max_active`` blocks;
- the landmark-landmark links ``Omega_ij`` (2x2, ``i < j``) in one adjacency dictionary per
  landmark, both ends referring to the same array object, so the neighbours of a landmark and any
  one link are found in O(1).

Reading or writing the robot's links or one landmark's block is O(1); memory is O(n + links), and
links per landmark are bounded by how many landmarks were ever active together with it (a property
of the trajectory and ``max_active``, not of ``n``).

This module is private: :mod:`probmap.slam.landmark.seif` validates inputs and owns the algorithm.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from probmap._typing import FloatArray

__all__ = ["InformationStore"]


class InformationStore:
    """Block-sparse ``Omega``, ``xi`` and the running mean estimate ``mu``.

    Parameters
    ----------
    robot_omega : ndarray, shape (3, 3)
        Initial robot information block.
    robot_xi : ndarray, shape (3,)
        Initial robot information vector.
    robot_mu : ndarray, shape (3,)
        Initial robot mean (kept unwrapped in theta so that ``xi = Omega mu`` stays continuous).
    capacity : int
        Initial number of landmark slots (grows by doubling).
    """

    def __init__(
        self,
        robot_omega: FloatArray,
        robot_xi: FloatArray,
        robot_mu: FloatArray,
        capacity: int = 64,
    ) -> None:
        self.robot_omega = np.array(robot_omega, dtype=np.float64).reshape(3, 3)
        self.robot_xi = np.array(robot_xi, dtype=np.float64).reshape(3)
        self.robot_mu = np.array(robot_mu, dtype=np.float64).reshape(3)
        cap = max(int(capacity), 4)
        self.n = 0
        self._omega = np.zeros((cap, 2, 2))
        self._xi = np.zeros((cap, 2))
        self._mu = np.zeros((cap, 2))
        self.robot_links: dict[int, FloatArray] = {}
        self.adjacency: list[dict[int, FloatArray]] = []

    # ------------------------------------------------------------------ landmarks
    def add_landmark(self, mu: FloatArray) -> int:
        """Append a landmark with zero information at mean ``mu`` (2,); return its slot."""
        if self.n == self._omega.shape[0]:
            cap = 2 * self.n
            self._omega = np.concatenate([self._omega, np.zeros((cap - self.n, 2, 2))])
            self._xi = np.concatenate([self._xi, np.zeros((cap - self.n, 2))])
            self._mu = np.concatenate([self._mu, np.zeros((cap - self.n, 2))])
        j = self.n
        self._mu[j] = mu
        self.adjacency.append({})
        self.n += 1
        return j

    @property
    def omega_diag(self) -> FloatArray:
        """Landmark diagonal blocks ``Omega_jj``, shape (n, 2, 2) (a view)."""
        return self._omega[: self.n]

    @property
    def xi_landmarks(self) -> FloatArray:
        """Landmark information vectors, shape (n, 2) (a view)."""
        return self._xi[: self.n]

    @property
    def mu_landmarks(self) -> FloatArray:
        """Landmark mean estimates, shape (n, 2) (a view)."""
        return self._mu[: self.n]

    def link(self, i: int, j: int) -> FloatArray | None:
        """Return ``Omega_ij`` (2x2, rows of ``i``) or None when the two are not linked."""
        block = self.adjacency[i].get(j)
        if block is None:
            return None
        return block if i < j else block.T

    # ------------------------------------------------------------------ local dense views
    @staticmethod
    def local_index(slots: Sequence[int]) -> dict[int, int]:
        """Row offset of each landmark slot in a local dense system ``[robot, slots...]``."""
        return {s: 3 + 2 * k for k, s in enumerate(slots)}

    def gather(self, slots: Sequence[int]) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Dense ``Omega``, ``xi`` and ``mu`` over the robot followed by ``slots``.

        Returns
        -------
        omega : ndarray, shape (3 + 2k, 3 + 2k)
            The submatrix of Omega over these variables (links to the rest are left out).
        xi, mu : ndarray, shape (3 + 2k,)
        """
        k = len(slots)
        d = 3 + 2 * k
        omega = np.zeros((d, d))
        xi = np.empty(d)
        mu = np.empty(d)
        omega[:3, :3] = self.robot_omega
        xi[:3] = self.robot_xi
        mu[:3] = self.robot_mu
        if k == 0:
            return omega, xi, mu
        idx = np.asarray(slots, dtype=np.intp)
        xi[3:] = self._xi[idx].reshape(-1)
        mu[3:] = self._mu[idx].reshape(-1)
        pos = {s: a for a, s in enumerate(slots)}
        # landmark blocks as a (k, k, 2, 2) array: diagonal, then each link once (s < t)
        L = np.zeros((k, k, 2, 2))
        ar = np.arange(k)
        L[ar, ar] = self._omega[idx]
        A: list[int] = []
        B: list[int] = []
        blocks: list[FloatArray] = []
        adjacency = self.adjacency
        for s, a in pos.items():
            for t, block in adjacency[s].items():
                if s < t:
                    b = pos.get(t)
                    if b is not None:
                        A.append(a)
                        B.append(b)
                        blocks.append(block)
        if blocks:
            stacked = np.stack(blocks)
            L[A, B] = stacked
            L[B, A] = stacked.transpose(0, 2, 1)
        omega[3:, 3:] = L.transpose(0, 2, 1, 3).reshape(2 * k, 2 * k)
        links = self.robot_links
        R = np.zeros((k, 3, 2))
        have = [a for s, a in pos.items() if s in links]
        if have:
            R[have] = np.stack([links[slots[a]] for a in have])
            omega[:3, 3:] = R.transpose(1, 0, 2).reshape(3, 2 * k)
            omega[3:, :3] = omega[:3, 3:].T
        return omega, xi, mu

    def boundary(self, slots: Sequence[int]) -> FloatArray:
        """``sum_{t not in slots} Omega_st mu_t`` for each ``s`` in ``slots``, shape (2k,).

        The contribution of the landmarks outside a local set to that set's mean equations; the
        robot never links outside ``slots`` when ``slots`` holds every landmark linked to it.
        """
        out = np.zeros(2 * len(slots))
        inside = set(slots)
        mu = self._mu
        for k, s in enumerate(slots):
            acc: FloatArray | None = None
            for t, block in self.adjacency[s].items():
                if t in inside:
                    continue
                term = (block if s < t else block.T) @ mu[t]
                acc = term if acc is None else acc + term
            if acc is not None:
                out[2 * k : 2 * k + 2] = acc
        return out

    def scatter(
        self,
        slots: Sequence[int],
        omega: FloatArray,
        xi: FloatArray,
        mu: FloatArray | None = None,
    ) -> None:
        """Write a dense local system from :meth:`gather` back into the blocks.

        Blocks that are exactly zero are removed (that is how sparsification deletes links).
        """
        self.robot_omega = omega[:3, :3].copy()
        self.robot_xi = xi[:3].copy()
        if mu is not None:
            self.robot_mu = mu[:3].copy()
        if not slots:
            return
        idx = np.asarray(slots, dtype=np.intp)
        k = len(slots)
        self._xi[idx] = xi[3:].reshape(k, 2)
        if mu is not None:
            self._mu[idx] = mu[3:].reshape(k, 2)
        L = omega[3:, 3:].reshape(k, 2, k, 2).transpose(0, 2, 1, 3)  # (k, k, 2, 2)
        ar = np.arange(k)
        self._omega[idx] = L[ar, ar]
        R = omega[:3, 3:].reshape(3, k, 2).transpose(1, 0, 2)  # (k, 3, 2)
        robot_nz = np.any(R != 0.0, axis=(1, 2)).tolist()
        link_nz = np.any(L != 0.0, axis=(2, 3))
        links = self.robot_links
        adjacency = self.adjacency
        for a, s in enumerate(slots):
            if robot_nz[a]:
                links[s] = R[a].copy()
            else:
                links.pop(s, None)
            row = link_nz[a].tolist()
            for b in range(a + 1, k):
                t = slots[b]
                lo, hi = (s, t) if s < t else (t, s)
                if row[b]:
                    stored = L[a, b].copy() if s < t else L[b, a].copy()
                    adjacency[lo][hi] = stored
                    adjacency[hi][lo] = stored
                elif hi in adjacency[lo]:
                    del adjacency[lo][hi]
                    del adjacency[hi][lo]

    # ------------------------------------------------------------------ whole-state views
    def to_sparse(self):  # type: ignore[no-untyped-def]
        """``Omega`` as a ``scipy.sparse.csc_matrix`` of shape (3 + 2n, 3 + 2n)."""
        from scipy import sparse

        n = self.n
        d = 3 + 2 * n
        rows: list[NDArray[Any]] = []
        cols: list[NDArray[Any]] = []
        vals: list[NDArray[Any]] = []
        r3, c3 = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
        rows.append(r3.ravel())
        cols.append(c3.ravel())
        vals.append(self.robot_omega.ravel())
        r2, c2 = np.meshgrid(np.arange(2), np.arange(2), indexing="ij")
        if n:
            base = 3 + 2 * np.arange(n)
            rows.append((base[:, None] + r2.ravel()[None, :]).ravel())
            cols.append((base[:, None] + c2.ravel()[None, :]).ravel())
            vals.append(self.omega_diag.reshape(-1))
        if self.robot_links:
            s = np.fromiter(self.robot_links.keys(), dtype=np.intp)
            blocks = np.stack(list(self.robot_links.values()))  # (m, 3, 2)
            rx, cx = np.meshgrid(np.arange(3), np.arange(2), indexing="ij")
            rr = np.broadcast_to(rx.ravel(), (len(s), 6))
            cc = 3 + 2 * s[:, None] + cx.ravel()[None, :]
            rows += [rr.ravel(), cc.ravel()]
            cols += [cc.ravel(), rr.ravel()]
            vals += [blocks.reshape(-1), blocks.reshape(-1)]
        pairs = [(s, t, b) for s, nb in enumerate(self.adjacency) for t, b in nb.items() if s < t]
        if pairs:
            si = np.array([p[0] for p in pairs], dtype=np.intp)
            ti = np.array([p[1] for p in pairs], dtype=np.intp)
            blocks = np.stack([p[2] for p in pairs])  # (m, 2, 2)
            rr = 3 + 2 * si[:, None] + r2.ravel()[None, :]
            cc = 3 + 2 * ti[:, None] + c2.ravel()[None, :]
            rows += [rr.ravel(), cc.ravel()]
            cols += [cc.ravel(), rr.ravel()]
            vals += [blocks.reshape(-1), blocks.reshape(-1)]
        return sparse.csc_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(d, d)
        )

    def xi_vector(self) -> FloatArray:
        """The full information vector, shape (3 + 2n,)."""
        return np.concatenate([self.robot_xi, self.xi_landmarks.reshape(-1)])

    def mu_vector(self) -> FloatArray:
        """The full running mean estimate, shape (3 + 2n,)."""
        return np.concatenate([self.robot_mu, self.mu_landmarks.reshape(-1)])

    def set_mu_vector(self, mu: FloatArray) -> None:
        """Overwrite the running mean estimate with ``mu`` (3 + 2n,)."""
        self.robot_mu = mu[:3].copy()
        self._mu[: self.n] = mu[3:].reshape(self.n, 2)

    # ------------------------------------------------------------------ accounting
    def block_counts(self) -> dict[str, int]:
        """How many blocks are stored: robot links, landmark diagonals, landmark-landmark links."""
        pairs = sum(len(nb) for nb in self.adjacency) // 2
        return {"robot_links": len(self.robot_links), "landmarks": self.n, "landmark_links": pairs}

    def state_nbytes(self) -> int:
        """Bytes of numbers held for the state (blocks in use, excluding spare capacity).

        Per landmark: ``Omega_jj`` (4 floats), ``xi_j`` and ``mu_j`` (2 each), plus 4 floats per
        landmark-landmark link and 6 per robot link.
        """
        c = self.block_counts()
        floats = 9 + 3 + 3 + 8 * c["landmarks"] + 4 * c["landmark_links"] + 6 * c["robot_links"]
        return 8 * floats
