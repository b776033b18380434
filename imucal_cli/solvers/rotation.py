"""Rotations in numpy: the part of ``scipy.spatial.transform.Rotation`` the solvers use.

``Rotation.from_rotvec``, ``from_matrix``, ``as_matrix``, ``as_rotvec``, composition ``p * q``
(``q`` first), ``inv``, ``apply`` and ``Rotation.align_vectors`` (Wahba's problem, solved by
the SVD of the attitude profile matrix, Markley 1988), with scipy's conventions, so that the
calibrate path does not import ``scipy.spatial`` (about 0.7 s of start-up with its
dependencies). Single rotations or stacks of them (leading dimension).
"""

from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """``[v]x``, shape (..., 3, 3), for ``v`` of shape (..., 3)."""
    v = np.asarray(v, float)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return S


def _nearest_rotation(m: np.ndarray) -> np.ndarray:
    """The rotation nearest (Frobenius) to each 3x3 matrix (orthogonal Procrustes)."""
    U, _, Vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(U @ Vt))
    return (U * np.stack([np.ones_like(d), np.ones_like(d), d], axis=-1)[..., None, :]) @ Vt


class Rotation:
    """One rotation or a stack of them, held as rotation matrices (shape (3, 3) or (N, 3, 3))."""

    def __init__(self, matrix: np.ndarray):
        self._m = np.asarray(matrix, float)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_matrix(cls, matrix) -> Rotation:
        """From rotation matrices; a matrix that is not exactly orthogonal is replaced by the
        nearest rotation, as scipy does."""
        return cls(_nearest_rotation(np.asarray(matrix, float)))

    @classmethod
    def from_rotvec(cls, rotvec) -> Rotation:
        """From rotation vectors (axis times angle, rad): Rodrigues' formula."""
        v = np.asarray(rotvec, float)
        theta2 = np.sum(v * v, axis=-1)[..., None, None]
        theta = np.sqrt(theta2)
        small = theta2 < 1e-8
        safe = np.where(small, 1.0, theta)
        a = np.where(small, 1 - theta2 / 6 + theta2**2 / 120, np.sin(safe) / safe)
        b = np.where(small, 0.5 - theta2 / 24 + theta2**2 / 720, (1 - np.cos(safe)) / safe**2)
        K = skew(v)
        return cls(np.eye(3) + a * K + b * (K @ K))

    @classmethod
    def identity(cls) -> Rotation:
        return cls(np.eye(3))

    @classmethod
    def align_vectors(cls, a, b, weights=None) -> tuple[Rotation, float]:
        """The rotation ``R`` minimising ``sum w_i |a_i - R b_i|^2`` and that minimum's square
        root (scipy's ``rssd``). One vector pair: the shortest rotation taking ``b`` onto
        ``a``'s direction (as scipy)."""
        a = np.atleast_2d(np.asarray(a, float))
        b = np.atleast_2d(np.asarray(b, float))
        if a.shape != b.shape or a.shape[-1] != 3:
            raise ValueError(f"align_vectors needs two (N, 3) arrays, got {a.shape}, {b.shape}")
        w = np.ones(len(a)) if weights is None else np.asarray(weights, float)
        primary = np.flatnonzero(np.isinf(w))
        if len(primary) > 1:
            raise ValueError("only one infinite weight (the primary vector pair) is allowed")
        if len(a) == 1 or len(primary):
            R = _primary_secondary(a, b, w, int(primary[0]) if len(primary) else 0)
            w = np.where(np.isinf(w), 0.0, w)  # scipy's rssd leaves the primary pair out
        else:
            H = (w[:, None] * a).T @ b  # attitude profile matrix B = sum w a b^T
            U, _, Vt = np.linalg.svd(H)
            d = np.sign(np.linalg.det(U @ Vt)) or 1.0
            R = U @ np.diag([1.0, 1.0, d]) @ Vt
        rssd = float(np.sqrt(max(np.sum(w * np.sum((a - b @ R.T) ** 2, axis=1)), 0.0)))
        return cls(R), rssd

    # ------------------------------------------------------------------ output
    def as_matrix(self) -> np.ndarray:
        return self._m.copy()

    def as_rotvec(self) -> np.ndarray:
        """Rotation vectors (rad), angle in [0, pi], through the quaternion (numerically
        sound near 0 and pi)."""
        q = _quaternion(self._m)  # (..., 4): x, y, z, w with w >= 0
        qv, qw = q[..., :3], q[..., 3]
        s = np.linalg.norm(qv, axis=-1)
        angle = 2 * np.arctan2(s, qw)
        small = angle < 1e-3
        safe = np.where(small, 1.0, np.sin(angle / 2))
        a2 = angle * angle
        scale = np.where(small, 2 + a2 / 12 + 7 * a2 * a2 / 2880, angle / safe)
        return qv * scale[..., None]

    def as_quat(self) -> np.ndarray:
        """Quaternions (x, y, z, w), scalar last with ``w >= 0``, as scipy."""
        return _quaternion(self._m)

    def magnitude(self) -> np.ndarray | float:
        angle = np.linalg.norm(self.as_rotvec(), axis=-1)
        return float(angle) if np.ndim(angle) == 0 else angle

    # ------------------------------------------------------------------ algebra
    def __mul__(self, other: Rotation) -> Rotation:
        return Rotation(self._m @ other._m)

    def inv(self) -> Rotation:
        return Rotation(np.swapaxes(self._m, -1, -2))

    def apply(self, vectors) -> np.ndarray:
        v = np.asarray(vectors, float)
        if self._m.ndim == 2:
            return v @ self._m.T
        return np.einsum("nij,nj->ni", self._m, np.broadcast_to(v, (len(self._m), 3)))

    def __len__(self) -> int:
        if self._m.ndim == 2:
            raise TypeError("a single rotation has no len()")
        return len(self._m)


def _primary_secondary(a: np.ndarray, b: np.ndarray, w: np.ndarray, p: int) -> np.ndarray:
    """Pair ``p`` aligned exactly (the shortest rotation), then the turn about ``a_p`` that
    best aligns the other pairs (weights ``w``): scipy's rule for one infinite weight."""
    u = a[p] / np.linalg.norm(a[p])
    R1 = _shortest(u, b[p] / np.linalg.norm(b[p]))
    rest = np.arange(len(a)) != p
    if not rest.any():
        return R1
    c, t, ws = b[rest] @ R1.T, a[rest], w[rest]
    # a . R(theta) c = cos(theta) (a.c - (u.a)(u.c)) + sin(theta) a.(u x c) + constant
    S = float(np.sum(ws * np.sum(t * np.cross(u, c), axis=1)))
    C = float(np.sum(ws * (np.sum(t * c, axis=1) - (t @ u) * (c @ u))))
    return Rotation.from_rotvec(u * np.arctan2(S, C)).as_matrix() @ R1


def _shortest(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Matrix of the smallest rotation taking unit ``b`` onto unit ``a``."""
    axis = np.cross(b, a)
    s, c = np.linalg.norm(axis), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(b, np.eye(3)[np.argmin(np.abs(b))])  # half turn about any normal
        return Rotation.from_rotvec(np.pi * perp / np.linalg.norm(perp)).as_matrix()
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c)).as_matrix()


def _quaternion(m: np.ndarray) -> np.ndarray:
    """Quaternions (x, y, z, w), ``w >= 0``, of rotation matrices (Shepperd's method: from the
    largest of the four diagonal combinations)."""
    m = np.asarray(m, float)
    tr = np.trace(m, axis1=-2, axis2=-1)
    d = np.stack([m[..., 0, 0], m[..., 1, 1], m[..., 2, 2], tr], axis=-1)
    k = np.argmax(d, axis=-1)
    q = np.empty(m.shape[:-2] + (4,))
    # each candidate: the quaternion built from diagonal element k (or the trace)
    cands = np.empty(m.shape[:-2] + (4, 4))
    for i in range(3):
        j, l = (i + 1) % 3, (i + 2) % 3
        c = cands[..., i, :]
        c[..., i] = 1 - tr + 2 * m[..., i, i]
        c[..., j] = m[..., j, i] + m[..., i, j]
        c[..., l] = m[..., l, i] + m[..., i, l]
        c[..., 3] = m[..., l, j] - m[..., j, l]
    c = cands[..., 3, :]
    c[..., 0] = m[..., 2, 1] - m[..., 1, 2]
    c[..., 1] = m[..., 0, 2] - m[..., 2, 0]
    c[..., 2] = m[..., 1, 0] - m[..., 0, 1]
    c[..., 3] = 1 + tr
    q = np.take_along_axis(cands, k[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)
