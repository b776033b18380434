"""Whitening with a sparse covariance: reverse Cuthill-McKee ordering, banded Cholesky.

A covariance ``Sigma = C C^T`` whose noise sources each touch a few residuals (the gravity
direction of a still period is shared by the rotation before it and the one after it) is
sparse, and banded after reordering. Its Cholesky factor ``L`` (``Sigma = L L^T``) is then
banded too: factoring costs ``O(n b^2)`` and whitening ``L^{-1} r`` costs ``O(n b)`` for
bandwidth ``b``, against ``O(n^3)`` and ``O(n^2)`` dense.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.linalg import cholesky_banded, lapack
from scipy.sparse.csgraph import reverse_cuthill_mckee


class BandedWhitener:
    """``W`` with ``W^T W = Sigma^-1`` for a sparse symmetric positive definite ``Sigma``.

    Parameters
    ----------
    cov : sparse matrix (n, n)
        The covariance.
    ridge : float
        Relative regularisation: ``ridge * trace(Sigma) / n`` is added to the diagonal (keeps
        the factor finite when a noise source is exactly zero).
    """

    def __init__(self, cov: sparse.spmatrix, ridge: float = 1e-12):
        cov = sparse.csr_matrix(cov)
        n = cov.shape[0]
        self.n = n
        if n == 0:
            self.perm, self.ab = np.zeros(0, int), np.zeros((1, 0))
            return
        cov = cov + sparse.identity(n, format="csr") * (ridge * cov.diagonal().sum() / n)
        self.perm = reverse_cuthill_mckee(cov, symmetric_mode=True)
        coo = cov[self.perm][:, self.perm].tocoo()
        lower = coo.row >= coo.col
        rows, cols, vals = coo.row[lower], coo.col[lower], coo.data[lower]
        band = int((rows - cols).max()) if len(rows) else 0
        ab = np.zeros((band + 1, n))
        np.add.at(ab, (rows - cols, cols), vals)
        self.ab = cholesky_banded(ab, lower=True)

    @property
    def bandwidth(self) -> int:
        return self.ab.shape[0] - 1

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """``W x`` for ``x`` of shape (n,) or (n, m)."""
        if self.n == 0:
            return x
        vec = x.ndim == 1
        b = np.asarray(x, float)[self.perm].reshape(self.n, -1)
        out, info = lapack.dtbtrs(self.ab, b, uplo="L")
        if info != 0:
            raise np.linalg.LinAlgError(f"banded triangular solve failed (info {info})")
        return out[:, 0] if vec else out
