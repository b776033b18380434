"""The factorization's inputs and result (Hwangbo & Kanade; :mod:`.factorization`): the motion
constraints (:class:`Constraints`, eq. 15), the known-magnitude motion that scales
orthogonality-only data (:class:`ScaleReference`, eq. 31), the :class:`FactorizationResult` of
the linear solution and of its refinement, and what both compute the same way (the constraint
errors' RMS, the right-handed channels).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Constraints:
    """Inner-product motion constraints ``f_i^T f_k = h_ik`` (eq. 15).

    Attributes
    ----------
    i, k : ndarray of int, shape (K,)
        Row indices into the measurement matrix ``Z``; ``i == k`` is a magnitude constraint.
    h : ndarray, shape (K,)
        The inner products, in the motion's units squared.
    """

    i: np.ndarray
    k: np.ndarray
    h: np.ndarray

    def __post_init__(self):
        for name in ("i", "k"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=int))
        object.__setattr__(self, "h", np.asarray(self.h, dtype=float))

    def __len__(self) -> int:
        return len(self.h)

    @property
    def kind(self) -> str:
        """``"magnitude-only"`` (all h equal and non-zero: eq. 29), ``"orthogonal-only"``
        (all zero: eq. 30) or ``"general"``."""
        if np.all(self.h == 0):
            return "orthogonal-only"
        if np.allclose(self.h, self.h[0]) and np.all(self.i == self.k):
            return "magnitude-only"
        return "general"


@dataclass(frozen=True)
class ScaleReference:
    """One motion of known magnitude for the global scale of orthogonality-only data (eq. 31).

    Attributes
    ----------
    w : ndarray, shape (n,)
        Integral of the bias-free measurements over the known rotation, ``sum (z - b) dt``
        (raw units x s). For a redundant unit, the integral of ``z`` and the duration ``T``.
    magnitude : float
        Its true magnitude (the rotation angle, rad).
    duration : float
        Seconds over which ``w`` was integrated (used to remove the bias term when the biases
        are estimated together with the rest).
    """

    w: np.ndarray
    magnitude: float
    duration: float = 0.0
    sigma: float | None = None  # standard deviation of the measured magnitude; default 0.1 %


@dataclass
class FactorizationResult:
    """Result of :func:`factorize` or :func:`refine`.

    Attributes
    ----------
    S : ndarray, shape (3, n)
        Sensitivity axes ``s_j`` as columns (raw units per motion unit); gains ``|s_j|``.
    b : ndarray, shape (n,)
        Biases, raw units.
    T : ndarray, shape (3, n)
        ``[S^T]^+``: motion = ``T @ (z - b)``.
    F : ndarray, shape (m, 3)
        Recovered motions (rows of ``Z``), in the frame of ``T``.
    configuration : str
        ``"redundant"`` (p = 4) or ``"triad"`` (p = 3).
    case : str
        Constraint case: ``"general"``, ``"magnitude-only"``, ``"orthogonal-only"``.
    constraint_rms : float
        RMS of ``f_i^T f_k - h_ik`` over the constraints (the paper's C_err, as an RMS).
    singular_values : ndarray
        Of ``Z`` (redundant) or ``D`` (triad), largest first: the rank evidence.
    method : str
        ``"linear"`` or ``"nonlinear"``.
    iterations, converged, message
        Of the nonlinear refinement (0, True, "" for the linear solution).
    cov : ndarray or None
        Covariance of ``(b, vec(T))`` (n + 3n); only for :func:`refine`. Rotation-gauge
        directions are removed (pseudo-inverse), so use it for rotation-invariant quantities.
    noise_scale : float
        Factor applied to ``cov`` (residual chi^2/dof when the noise was not given or the
        residuals exceed it).
    """

    S: np.ndarray
    b: np.ndarray
    T: np.ndarray
    F: np.ndarray
    configuration: str
    case: str
    constraint_rms: float
    singular_values: np.ndarray
    method: str = "linear"
    iterations: int = 0
    converged: bool = True
    message: str = ""
    cov: np.ndarray | None = None
    noise_scale: float = 1.0
    notes: list[str] = field(default_factory=list)
    fixture_tolerance: float = 0.0

    @property
    def gains(self) -> np.ndarray:
        """``|s_j|``, raw units per motion unit, shape (n,)."""
        return np.linalg.norm(self.S, axis=0)

    def angles_deg(self) -> np.ndarray:
        """Angles between sensitivity axes, degrees, shape (n, n)."""
        s = self.S / self.gains
        return np.degrees(np.arccos(np.clip(s.T @ s, -1, 1)))


def constraint_rms(F: np.ndarray, c: Constraints) -> float:
    e = np.sum(F[c.i] * F[c.k], axis=1) - c.h
    return float(np.sqrt(np.mean(e * e)))


def right_handed(T, S, F):
    """Resolve the reflection that inner products cannot see: the first three channels form a
    right-handed set (``det T[:, :3] > 0``), as on every standard IMU."""
    if np.linalg.det(T[:, :3]) < 0:
        flip = np.diag([1.0, 1.0, -1.0])
        return flip @ T, flip @ S, F @ flip
    return T, S, F
