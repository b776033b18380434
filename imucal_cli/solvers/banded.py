"""Whitening with a sparse covariance: reverse Cuthill-McKee ordering, banded Cholesky (numpy).

A covariance ``Sigma = C C^T`` whose noise sources each touch a few residuals (the gravity
direction of a still period is shared by the rotation before it and the one after it) is
sparse, and banded after reordering. Its Cholesky factor ``L`` (``Sigma = L L^T``) is then
banded too: factoring costs ``O(n b^2)`` and whitening ``L^{-1} r`` costs ``O(n b)`` for
bandwidth ``b``, against ``O(n^3)`` and ``O(n^2)`` dense.

Numpy only (``scipy.sparse``/``scipy.linalg`` cost the calibrate path about 0.5 s of
start-up): sparse matrices are :class:`Coo` triplets, the band is factored as a block
tridiagonal matrix (blocks of at least the bandwidth, so the loop runs ``n / block`` times
over small dense blocks), and the ordering is Cuthill-McKee's breadth-first search.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from imucal_cli.solvers.order import distinct

#: Smallest block of the block-tridiagonal factorisation (fewer, larger numpy steps).
MIN_BLOCK = 16


@dataclass
class Coo:
    """A sparse matrix as ``(row, col, data)`` triplets (duplicates add), shape ``shape``."""

    row: np.ndarray
    col: np.ndarray
    data: np.ndarray
    shape: tuple[int, int]

    def toarray(self) -> np.ndarray:
        out = np.zeros(self.shape)
        np.add.at(out, (self.row, self.col), self.data)
        return out

    def diagonal(self, k: int = 0) -> np.ndarray:
        """Diagonal ``k`` (``A[i, i + k]``), as ``scipy.sparse``'s."""
        n = min(self.shape[0], self.shape[1] - k) if k >= 0 else min(self.shape[0] + k,
                                                                        self.shape[1])  # fmt: skip
        on = self.col - self.row == k
        start = self.row[on] if k >= 0 else self.col[on]
        return np.bincount(start, weights=self.data[on], minlength=max(n, 0))[: max(n, 0)]

    def gram(self) -> Coo:
        """``C C^T``: every pair of entries sharing a column (columns hold few entries)."""
        order = np.lexsort((self.row, self.col))
        r, c, v = self.row[order], self.col[order], self.data[order]
        rows, cols, vals = [], [], []
        for d in range(len(c)):
            same = c[d:] == c[: len(c) - d] if d else np.ones(len(c), bool)
            if not same.any():
                break
            i = np.flatnonzero(same)
            rows.append(r[i])
            cols.append(r[i + d])
            vals.append(v[i] * v[i + d])
            if d:  # the symmetric entry
                rows.append(r[i + d])
                cols.append(r[i])
                vals.append(v[i] * v[i + d])
        n = self.shape[0]
        return Coo(np.concatenate(rows), np.concatenate(cols), np.concatenate(vals), (n, n))


def _triplets(cov) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Triplets of a :class:`Coo`, a scipy.sparse matrix or a dense array."""
    if isinstance(cov, Coo):
        return cov.row, cov.col, cov.data, cov.shape[0]
    if hasattr(cov, "tocoo"):
        coo = cov.tocoo()
        return coo.row, coo.col, coo.data, coo.shape[0]
    cov = np.asarray(cov, float)
    r, c = np.nonzero(cov)
    return r, c, cov[r, c], cov.shape[0]


def reverse_cuthill_mckee(row: np.ndarray, col: np.ndarray, n: int) -> np.ndarray:
    """Reverse Cuthill-McKee ordering of a symmetric pattern: breadth-first from a node of
    least degree in each connected part, neighbours in increasing degree, then reversed."""
    off = row != col
    r, c = np.concatenate([row[off], col[off]]), np.concatenate([col[off], row[off]])
    key = distinct(r.astype(np.int64) * n + c)  # distinct pairs, by row (a 1-D sort: fast)
    pairs = np.stack([key // n, key % n], 1)
    degree = np.bincount(pairs[:, 0], minlength=n) if len(pairs) else np.zeros(n, int)
    starts = np.r_[0, np.cumsum(degree)]
    # neighbours of each node sorted by their degree (then index)
    nb = pairs[np.lexsort((pairs[:, 1], degree[pairs[:, 1]], pairs[:, 0]))][:, 1]
    seen = np.zeros(n, bool)
    order: list[int] = []
    for s in np.lexsort((np.arange(n), degree)):
        if seen[s]:
            continue
        seen[s] = True
        queue = deque([int(s)])
        while queue:
            i = queue.popleft()
            order.append(i)
            for j in nb[starts[i] : starts[i + 1]]:
                if not seen[j]:
                    seen[j] = True
                    queue.append(int(j))
    return np.array(order[::-1], dtype=int)


class BandedWhitener:
    """``W`` with ``W^T W = Sigma^-1`` for a sparse symmetric positive definite ``Sigma``.

    Parameters
    ----------
    cov : Coo, scipy.sparse matrix or ndarray (n, n)
        The covariance.
    ridge : float
        Relative regularisation: ``ridge * trace(Sigma) / n`` is added to the diagonal (keeps
        the factor finite when a noise source is exactly zero).
    order : ndarray of int, optional
        The ordering of a covariance of the same sparsity pattern (:attr:`perm` of an earlier
        whitener): the reverse Cuthill-McKee search is skipped.
    """

    def __init__(self, cov, ridge: float = 1e-12, order: np.ndarray | None = None):
        row, col, data, n = _triplets(cov)
        self.n = n
        if n == 0:
            self.perm, self.band = np.zeros(0, int), 0
            return
        trace = float(data[row == col].sum())
        diag = np.arange(n)
        row, col = np.concatenate([row, diag]), np.concatenate([col, diag])
        data = np.concatenate([data, np.full(n, ridge * trace / n)])
        self.perm = reverse_cuthill_mckee(row, col, n) if order is None else order
        where = np.empty(n, int)
        where[self.perm] = np.arange(n)
        pr, pc = where[row], where[col]
        self.band = int(np.abs(pr - pc).max())
        s = max(self.band, MIN_BLOCK)
        m = -(-n // s)  # blocks
        # the block tridiagonal matrix: D (diagonal blocks), E (below the diagonal)
        D = np.zeros((m, s, s))
        E = np.zeros((max(m - 1, 0), s, s))
        bi, bj = pr // s, pc // s
        on = bi == bj
        np.add.at(D, (bi[on], pr[on] % s, pc[on] % s), data[on])
        below = bi == bj + 1
        np.add.at(E, (bj[below], pr[below] % s, pc[below] % s), data[below])
        pad = m * s - n  # padding rows: identity
        if pad:
            D[-1, s - pad :, s - pad :] = np.eye(pad)
        self.s, self.m = s, m
        self.Linv = np.empty((m, s, s))
        self.F = np.zeros((max(m - 1, 0), s, s))
        Linv_prev = None
        for k in range(m):
            A = D[k]
            if k:
                F = E[k - 1] @ Linv_prev.T  # E L^-T
                self.F[k - 1] = F
                A = A - F @ F.T
            Lk = np.linalg.cholesky(A)
            Linv_prev = np.linalg.inv(Lk)
            self.Linv[k] = Linv_prev

    @property
    def bandwidth(self) -> int:
        return self.band

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """``W x`` for ``x`` of shape (n,) or (n, m)."""
        if self.n == 0:
            return x
        x = np.asarray(x, float)
        vec = x.ndim == 1
        b = x[self.perm].reshape(self.n, -1)
        s, m = self.s, self.m
        pad = m * s - self.n
        if pad:
            b = np.concatenate([b, np.zeros((pad, b.shape[1]))])
        b = b.reshape(m, s, -1)
        y = np.empty_like(b)
        y[0] = self.Linv[0] @ b[0]
        for k in range(1, m):  # forward substitution, block by block
            y[k] = self.Linv[k] @ (b[k] - self.F[k - 1] @ y[k - 1])
        out = y.reshape(m * s, -1)[: self.n]
        return out[:, 0] if vec else out
