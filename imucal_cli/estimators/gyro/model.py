"""The full gyro model's residuals, Jacobian and noise covariance (used by
:mod:`imucal_cli.estimators.gyro.full`).

Model: ``omega = M (z - b - G a)``: raw rate ``z``, bias ``b``, matrix ``M`` (rad/s per raw
unit) and, optionally, the g-sensitivity ``G`` (raw units per m/s^2, Kalibr's ``A`` in raw
terms) times the calibrated specific force ``a`` of the same sample. Parameters
``x = (b, vec(M), vec(G))`` (row-major; 12 without ``G``, 21 with it).

Residuals: two per rotation (the predicted gravity direction after it, ``p = R^T u_before``,
minus the measured one ``u_after``, in the tangent plane of the measured one), then three per
still period (gyro mean minus ``b + G a``: the gyro reads zero rate when still).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from imucal_cli.estimators.gyro.integration import (
    Stack,
    attitudes,
    end_sensitivity,
    matrix_rows,
    quat_to_matrix,
)
from imucal_cli.numerics.banded import BandedWhitener


@dataclass
class Rotations:
    """The rotation segments of a session.

    Attributes
    ----------
    t : list of ndarray (n_k,)
        Sample times of each rotation, s (including the still samples at both ends is fine).
    z : list of ndarray (n_k, 3)
        Raw gyro samples.
    before, after : ndarray of int (K,)
        Index of the still period before and after each rotation (into :class:`Stills`).
    a : list of ndarray (n_k, 3), optional
        Calibrated accelerometer samples, m/s^2 (needed for the g-sensitivity term only).
    """

    t: list[np.ndarray]
    z: list[np.ndarray]
    before: np.ndarray
    after: np.ndarray
    a: list[np.ndarray] | None = None


@dataclass
class Stills:
    """The still periods around the rotations.

    Attributes
    ----------
    g : ndarray (P, 3)
        Calibrated accelerometer mean of each still period, m/s^2 (only the direction counts
        for the rotations; the g-sensitivity term uses the vector).
    g_sigma : ndarray (P,)
        Standard deviation of each mean's direction, per tangent component, rad.
    z_mean : ndarray (P, 3)
        Raw gyro mean of each still period.
    z_sigma : ndarray (P,)
        Standard deviation of each gyro mean, per channel, raw units.
    z_round : ndarray (3, P, P), optional
        Covariance of the gyro means' rounding errors, per channel, raw units^2: a quantised
        gyro its noise does not dither rounds every still period's rate alike where the
        rates sit at one place within a count
        (:func:`imucal_cli.numerics.quantisation.rounding_covariance`).  Not in ``z_sigma``:
        the fit cannot see the shared part (the bias takes it whole);
        :func:`rounding_parameter_covariance` adds it to the parameters' covariance.
    """

    g: np.ndarray
    g_sigma: np.ndarray
    z_mean: np.ndarray
    z_sigma: np.ndarray
    z_round: np.ndarray | None = None


def rounding_parameter_covariance(J: np.ndarray, still: Stills) -> np.ndarray | float:
    """The parameters' covariance from the gyro means' rounding errors ``e_c`` (P,) of each
    channel ``c``, covariance ``still.z_round[c]`` (consider parameters, Schmidt): the still
    rows are the last ``3 P`` of the whitened residuals, row ``3 p + c`` of them ``(z_mean -
    b - G a)_pc / z_sigma_p``, so ``d f / d e_c = D_c`` there and the estimate moves by ``A_c
    = (J^T J)^-1 J^T D_c``; returns ``sum_c A_c z_round[c] A_c^T`` (0 without it).

    Parameters
    ----------
    J : ndarray (rows, n)
        The whitened Jacobian at the solution, the still rows last.
    still : Stills
    """
    if still.z_round is None or not np.any(still.z_round):
        return 0.0
    P = len(still.z_mean)
    out = np.zeros((J.shape[1], J.shape[1]))
    for c in range(3):
        D = np.zeros((len(J), P))
        D[len(J) - 3 * P + 3 * np.arange(P) + c, np.arange(P)] = 1.0 / still.z_sigma
        A = np.linalg.lstsq(J, D, rcond=None)[0]
        out += A @ still.z_round[c] @ A.T
    return out


def tangent(u: np.ndarray) -> np.ndarray:
    """(P, 3, 2) orthonormal bases of the planes normal to unit vectors ``u`` (P, 3)."""
    helper = np.eye(3)[np.argmin(np.abs(u), axis=1)]
    t1 = np.cross(u, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(u, t1)
    return np.stack([t1, t2], axis=2)


def skew(p: np.ndarray) -> np.ndarray:
    """(K, 3, 3) cross-product matrices ``[p]x`` of (K, 3) vectors."""
    out = np.zeros((len(p), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -p[:, 2], p[:, 1], -p[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = p[:, 2], -p[:, 1], p[:, 0]
    return out


class Problem:
    """Residuals of the full model, their Jacobian, and their noise covariance.

    Parameters
    ----------
    rot, still : Rotations, Stills
    gyro_sigma : float
        Per-sample gyro noise, raw units.
    clock : float
        Factor on every sample interval (sample-clock correction).
    g_sensitivity : bool
        Include the 9 parameters of ``G`` (needs ``rot.a``).
    like : Problem, optional
        A problem of the same turns' sample times (``like.rot.t is rot.t``): its stacked layout
        (and the blocked product's, computed once) is reused, and with the same still periods
        around the turns its noise covariance's ordering.
    """

    def __init__(self, rot: Rotations, still: Stills, gyro_sigma: float, clock: float = 1.0,
                 g_sensitivity: bool = False, like: Problem | None = None):  # fmt: skip
        self.rot, self.still, self.clock = rot, still, clock
        same_t = like is not None and like.rot.t is rot.t
        self.stack = like.stack if same_t else Stack.of(rot.t)
        self.z = np.ascontiguousarray(np.concatenate(rot.z).T, dtype=float)  # (3, N)
        self.with_g = g_sensitivity
        if g_sensitivity and rot.a is None:
            raise ValueError("the g-sensitivity term needs the accelerometer samples of the turns")
        self.a = np.ascontiguousarray(np.concatenate(rot.a).T, dtype=float) if g_sensitivity \
            else None  # fmt: skip
        self.n_params = 21 if g_sensitivity else 12
        self.u = still.g / np.linalg.norm(still.g, axis=1, keepdims=True)
        self.B = tangent(self.u)
        self.gyro_sigma = gyro_sigma
        self.K, self.P = len(rot.t), len(still.g)
        # Integrated white gyro noise over a rotation: sigma * sqrt(sum dt^2) per axis (raw).
        h2 = (clock * np.diff(self.stack.t)) ** 2
        h2[self.stack.stop[:-1] - 1] = 0.0
        self.int_noise = gyro_sigma * np.sqrt(np.add.reduceat(np.r_[h2, 0.0], self.stack.start))
        # [key, attitudes, end rotations or None, derived values], newest first (:meth:`_entry`)
        self._cache: tuple = ()
        self._order = None
        if (same_t and like.rot.before is rot.before and like.rot.after is rot.after
                and like.P == self.P):  # fmt: skip
            self._order = like._order  # the same sparsity of the noise covariance

    def with_still(self, still: Stills) -> Problem:
        """The same turns with other still periods' gravity (the attitudes, which depend on
        the turns and the parameters only, and their last evaluation are shared)."""
        other = copy.copy(self)
        other.still = still
        other.P = len(still.g)
        other.u = still.g / np.linalg.norm(still.g, axis=1, keepdims=True)
        other.B = tangent(other.u)
        return other

    def share(self, other: Problem) -> None:
        """Start from ``other``'s last evaluation (the same turns and clock: ``other``'s
        last point is then evaluated without integrating again)."""
        if other.rot is self.rot and other.clock == self.clock and other.with_g == self.with_g:
            self._cache = other._cache
        if other.rot is self.rot and other.P == self.P:
            self._order = other._order  # the same sparsity of the noise covariance

    def share_without_g(self, other: Problem, x: np.ndarray) -> None:
        """Start this g-sensitive problem from ``other``'s (without ``G``) evaluation at
        ``x``: the same rates at ``(x, G = 0)``, when the turns' specific force is finite."""
        key = np.asarray(x, float).tobytes()
        entry = next((e for e in other._cache if e[0] == key), None)
        if (other.rot is self.rot and other.clock == self.clock and self.with_g
                and not other.with_g and entry is not None
                and np.all(np.isfinite(self.a))):  # fmt: skip
            # The noise covariance depends on the rates and M only: the same at G = 0.
            kept = {k: v for k, v in entry[3].items() if k == "covariance"}
            self._cache = ([np.r_[x, np.zeros(9)].tobytes(), entry[1], entry[2], kept],)
        if other.rot is self.rot and other.P == self.P:
            self._order = other._order

    def split(self, x):
        """``(b, M, G)`` from a parameter vector (``G`` zero without the term)."""
        G = x[12:21].reshape(3, 3) if self.with_g else np.zeros((3, 3))
        return x[:3], x[3:12].reshape(3, 3), G

    def _bias_free(self, x):
        """``z - b - G a`` of every turn sample, (3, N)."""
        b, _, G = self.split(x)
        d = self.z - b[:, None]
        return d - G @ self.a if self.with_g else d

    def _still_residuals(self, x):
        b, _, G = self.split(x)
        return (self.still.z_mean - b - self.still.g @ G.T).ravel()

    def _entry(self, x) -> list:
        """The integration at ``x``: ``[key, attitudes (4, N), end rotations or None,
        derived]``, ``derived`` what was computed from it (:meth:`_derived`). The last two
        points evaluated are kept (the solver asks for residuals, Jacobian and noise model at
        one point in turn, and comes back to its best point after a rejected step)."""
        key = x.tobytes()
        for entry in self._cache:
            if entry[0] == key:
                return entry
        M = x[3:12].reshape(3, 3)
        entry = [key, attitudes(self.stack, M @ self._bias_free(x), self.clock), None, {}]
        self._cache = (entry, *self._cache[:1])
        return entry

    def _derived(self, x, name: str, numbers: tuple, compute):
        """``compute()`` at ``x``, kept with the integration at ``x`` under ``name`` for these
        still periods (the same object) and ``numbers``: problems that share the integration
        (:meth:`share`, :meth:`with_still`) may differ in their still periods or noise."""
        derived = self._entry(x)[3]
        held = derived.get(name)
        if held is not None and held[0] is self.still and held[1] == numbers:
            return held[2]
        value = compute()
        derived[name] = (self.still, numbers, value)
        return value

    def _attitudes(self, x):
        """Every sample's attitude in its rotation (4, N)."""
        return self._entry(x)[1]

    def predicted(self, x):
        """Predicted gravity direction after each rotation (K, 3) and the rotations (K, 3, 3)."""
        entry = self._entry(x)
        if entry[2] is None:
            entry[2] = quat_to_matrix(entry[1][:, self.stack.stop - 1])
        R = entry[2]
        return np.einsum("kji,kj->ki", R, self.u[self.rot.before]), R  # R^T u0

    def _rotation_residuals(self, p):
        B1 = self.B[self.rot.after]
        return np.einsum("kij,ki->kj", B1, p - self.u[self.rot.after]).ravel()

    def raw_residuals(self, x):
        p, _ = self.predicted(x)
        return np.concatenate([self._rotation_residuals(p), self._still_residuals(x)])

    def residuals_and_jacobian(self, x):
        """Raw residuals and their analytic Jacobian (first order in the rate perturbation).

        A rate error ``d omega(t)`` rotates the end of a turn by
        ``d phi = integral R(t -> end) d omega(t) dt`` (body frame at the end), which moves the
        predicted gravity direction by ``d p = [p]x d phi``.

        Kept with the integration at ``x`` (read-only): the solver asks for it again at the
        same point under another noise model, and the covariance at the solution.
        """
        return self._derived(x, "jacobian", (self.n_params, self.clock),
                             lambda: self._residuals_and_jacobian(x))  # fmt: skip

    def _residuals_and_jacobian(self, x):
        _, M, _ = self.split(x)
        st, K, P = self.stack, self.K, self.P
        R = matrix_rows(self._attitudes(x))
        R_end = R[:, st.stop - 1].T.reshape(K, 3, 3)
        p = np.einsum("kji,kj->ki", R_end, self.u[self.rot.before])
        r = np.concatenate([self._rotation_residuals(p), self._still_residuals(x)])
        dphi = [
            -end_sensitivity(st, R, clock=self.clock) @ M,  # d omega_i = -M d b
            end_sensitivity(st, R, self._bias_free(x), self.clock).reshape(K, 3, 9),  # dM d_i
        ]
        if self.with_g:  # d omega_i = -M dG a_i
            S_a = end_sensitivity(st, R, self.a, self.clock)
            dphi.append(-np.einsum("kxyj,yc->kxcj", S_a, M).reshape(K, 3, 9))
        Gp = np.einsum("kai,kab->kib", self.B[self.rot.after], skew(p))  # B1^T [p]x
        J = np.zeros((2 * K + 3 * P, self.n_params))
        J[: 2 * K] = (Gp @ np.concatenate(dphi, axis=2)).reshape(2 * K, self.n_params)
        J[2 * K :, :3] = -np.tile(np.eye(3), (P, 1))
        if self.with_g:  # still rows: d(-G a_p) / dG[r, j] = -a_p[j] in row r
            for r_ in range(3):
                J[2 * K + r_ :: 3, 12 + 3 * r_ : 15 + 3 * r_] = -self.still.g
        r.setflags(write=False)
        J.setflags(write=False)
        return r, J

    def rotation_covariance(self, x) -> sparse.csr_array:
        """Covariance of the rotation residuals (2K x 2K, sparse): each rotation's from the
        gravity directions before and after it (shared with its neighbours) and its
        integrated gyro noise. Kept with the integration at ``x`` (the fit's statistics and
        the next noise model ask for it at the same point)."""
        return self._derived(x, "covariance", (self.gyro_sigma, self.clock),
                             lambda: self._rotation_covariance(x))  # fmt: skip

    def _rotation_covariance(self, x) -> sparse.csr_array:
        p, R = self.predicted(x)
        M = x[3:12].reshape(3, 3)
        K, P = self.K, self.P
        i0, i1 = self.rot.before, self.rot.after
        B1 = self.B[i1]
        g_sigma = self.still.g_sigma
        # u_before perturbed in its tangent plane: d p = R^T B0 e
        c0 = np.einsum("kai,kba,kbj->kij", B1, R, self.B[i0]) * g_sigma[i0, None, None]
        # u_after perturbed: d(-u1) projected (B1 is fixed from the data, to first order)
        c1 = -np.broadcast_to(np.eye(2), (K, 2, 2)) * g_sigma[i1, None, None]
        # Integrated gyro noise: a small rotation eps (body, end) -> d p = [p]x eps
        cg = np.einsum("kai,kab,bc->kic", B1, skew(p), M) * self.int_noise[:, None, None]
        rows = 2 * np.arange(K)[:, None, None] + np.arange(2)[None, :, None]
        blocks = [(c0, 2 * i0), (c1, 2 * i1), (cg, 2 * P + 3 * np.arange(K))]
        data, rr, cc = [], [], []
        for c, col0 in blocks:
            n = c.shape[2]
            cols = col0[:, None, None] + np.arange(n)[None, None, :]
            data.append(c.ravel())
            rr.append(np.broadcast_to(rows, c.shape).ravel())
            cc.append(np.broadcast_to(cols, c.shape).ravel())
        C = sparse.csr_array((np.concatenate(data), (np.concatenate(rr), np.concatenate(cc))),
                             shape=(2 * K, 2 * P + 3 * K))  # fmt: skip
        return C @ C.T

    def whitener(self, x) -> Whitener:
        # The covariance's sparsity depends on the turns' still periods only: its ordering is
        # found once per problem (with_still copies share it).
        banded = BandedWhitener(self.rotation_covariance(x), order=self._order)
        self._order = banded.perm
        return Whitener(banded, self)


class Whitener:
    """Whitens the stacked residuals: rotation rows by the banded factor, still rows by their
    standard deviation."""

    def __init__(self, rot: BandedWhitener, prob: Problem):
        self.rot, self.n_rot = rot, 2 * prob.K
        self.zero_sigma = np.repeat(prob.still.z_sigma, 3)

    def __call__(self, a: np.ndarray) -> np.ndarray:
        top = self.rot(a[: self.n_rot])
        bottom = a[self.n_rot :] / (self.zero_sigma if a.ndim == 1 else self.zero_sigma[:, None])
        return np.concatenate([top, bottom])
