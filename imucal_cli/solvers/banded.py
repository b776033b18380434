"""Whitening with a sparse covariance: reverse Cuthill-McKee ordering, banded Cholesky factor.

A covariance ``Sigma`` whose noise sources each touch a few residuals (the gravity direction of
a still period is shared by the rotation before it and the one after it) is sparse, and banded
after reordering. Its Cholesky factor ``L`` (``Sigma = L L^T``) is then banded too: factoring
costs ``O(n b^2)`` and whitening ``L^{-1} r`` costs ``O(n b)`` for bandwidth ``b``, against
``O(n^3)`` and ``O(n^2)`` dense. The ordering is ``scipy.sparse.csgraph``'s, the factor
``scipy.linalg.cholesky_banded`` and the solve LAPACK's banded triangular ``dtbtrs``.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.linalg import cholesky_banded
from scipy.linalg.lapack import dtbtrs
from scipy.sparse.csgraph import reverse_cuthill_mckee


class BandedWhitener:
    """``W = L^{-1} P`` with ``W^T W = Sigma^-1`` for a sparse symmetric positive definite
    ``Sigma`` (``P`` the reordering, ``P Sigma P^T = L L^T``).

    Parameters
    ----------
    cov : scipy.sparse array or ndarray (n, n)
        The covariance.
    ridge : float
        Relative regularisation: ``ridge * trace(Sigma) / n`` is added to the diagonal (keeps
        the factor finite when a noise source is exactly zero).
    order : ndarray of int, optional
        The ordering of a covariance of the same sparsity pattern (:attr:`perm` of an earlier
        whitener): the reverse Cuthill-McKee search is skipped.
    """

    def __init__(self, cov, ridge: float = 1e-12, order: np.ndarray | None = None):
        A = sparse.csr_array(cov)
        n = self.n = A.shape[0]
        if n == 0:
            self.perm, self.band = np.zeros(0, int), 0
            return
        A = A + sparse.diags_array(np.full(n, ridge * A.diagonal().sum() / n))
        self.perm = reverse_cuthill_mckee(A, symmetric_mode=True) if order is None else order
        P = A[self.perm][:, self.perm].tocoo()
        lower = P.row >= P.col
        offset, col = (P.row - P.col)[lower], P.col[lower]
        self.band = int(offset.max())
        ab = np.zeros((self.band + 1, n))  # LAPACK's lower band storage: ab[i - j, j] = A[i, j]
        ab[offset, col] = P.data[lower]
        self.L = cholesky_banded(ab, lower=True)

    @property
    def bandwidth(self) -> int:
        return self.band

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """``W x`` for ``x`` of shape (n,) or (n, m)."""
        if self.n == 0:
            return x
        x = np.asarray(x, float)
        y, _ = dtbtrs(self.L, x[self.perm].reshape(self.n, -1), uplo="L")
        return y[:, 0] if x.ndim == 1 else y
