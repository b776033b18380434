"""The known-angle gyro against its simulated truth, for the tests that grade its gains."""

from __future__ import annotations

import numpy as np

#: Positions of the matrix's diagonal (the gains) in ``(b, M row-major)``.
DIAGONAL = [3, 7, 11]


def diagonal_errors(g, truth) -> tuple[np.ndarray, np.ndarray]:
    """The diagonal of ``M``: error over its stated std, and relative error, (3,) each, of a
    ``gyro-known`` section ``g`` against ``truth`` (asserted to be that solver)."""
    assert g is not None and g.solver == "gyro-known", None if g is None else g.notes
    est = np.array([p.value for p in g.parameters[:12]])
    std = np.array([p.std for p in g.parameters[:12]])
    x = np.r_[truth.gyro.bias, np.ravel(truth.gyro.matrix)]
    return ((est - x) / std)[DIAGONAL], ((est - x) / x)[DIAGONAL]
