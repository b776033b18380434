"""The model of the labelled-pose solver (see :mod:`.labelled`): geometry of the directions,
the parameterisation ``M = R(r) K``, and the whitened residuals and Jacobian of (L3) with the
second-order marginalisation over the placement."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.spatial.transform import Rotation

from imucal_cli.estimators.accel.gravity import _UPPER, triangular_and_rotation

PAIRS = ((0, 1), (0, 2), (1, 2))


def tangent_bases(u: np.ndarray) -> np.ndarray:
    """Orthonormal bases of the planes perpendicular to unit vectors ``u`` (N, 3): (N, 3, 2)."""
    u = np.atleast_2d(np.asarray(u, float))
    helper = np.eye(3)[np.argmin(np.abs(u), axis=1)]
    t1 = np.cross(u, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(u, t1)
    return np.stack([t1, t2], axis=2)


def sphere_exp(u0: np.ndarray, T: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``u = Exp(T d) u0`` (L1) and ``du/dd``, vectorised: shapes (N, 3) and (N, 3, 2)."""
    v = np.einsum("nij,nj->ni", T, d)
    th = np.linalg.norm(d, axis=1)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    sinc = np.where(small, 1.0 - th * th / 6.0, np.sin(ths) / ths)
    dsinc = np.where(small, -1.0 / 3.0, (ths * np.cos(ths) - np.sin(ths)) / ths**3)  # sinc'/th
    u = np.cos(th)[:, None] * u0 + sinc[:, None] * v
    du = (
        sinc[:, None, None] * (T - u0[:, :, None] * d[:, None, :])
        + dsinc[:, None, None] * v[:, :, None] * d[:, None, :]
    )
    return u, du


def axes(S: np.ndarray) -> np.ndarray:
    """Sensitivities and angles of a sensitivity matrix ``S`` (rows: each channel's axis,
    raw units per m/s^2), (3, 3) or a stack (..., 3, 3): ``(s_x, s_y, s_z, a_xy, a_xz,
    a_yz)``, (6,) or (..., 6), the row norms and the angles between rows minus 90 degrees.
    Invariant to a rotation of the frame (``S R^T``)."""
    gains = np.linalg.norm(S, axis=-1)
    n = S / gains[..., None]
    cos = np.stack([np.sum(n[..., i, :] * n[..., j, :], axis=-1) for i, j in PAIRS], axis=-1)
    return np.concatenate([gains, np.degrees(np.arccos(np.clip(cos, -1, 1))) - 90.0], axis=-1)


def public_params(B: np.ndarray, S: np.ndarray) -> np.ndarray:
    """:data:`.labelled.PARAM_NAMES` from ``B`` and ``S = M^-1``: bias, sensitivities, angles
    between the sensitivity axes minus 90 deg, and the rotation vector (deg) of ``M = R(r) K``
    (``K`` upper triangular)."""
    _, Q = triangular_and_rotation(np.linalg.inv(S))
    return np.concatenate([B, axes(S), np.degrees(Rotation.from_matrix(Q).as_rotvec())])


def public_from_theta(theta: np.ndarray) -> np.ndarray:
    """Public parameters from ``theta = (B, K upper, r in degrees)``, (12,) or a stack
    (..., 12)."""
    theta = np.asarray(theta, float)
    K = np.zeros((*theta.shape[:-1], 3, 3))
    K[..., _UPPER[0], _UPPER[1]] = theta[..., 3:9]
    return np.concatenate([theta[..., :3], axes(np.linalg.inv(K)), theta[..., 9:12]], axis=-1)


def theta_floor(theta: np.ndarray) -> np.ndarray:
    """Smallest magnitudes the difference steps of ``theta = (B, K upper, r)`` are scaled to
    (:func:`jacobian`): ``K``'s entries to a thousandth of its largest diagonal entry (an
    off-diagonal entry near zero would otherwise get a step near zero, and its derivatives
    rounding noise); the bias and the rotation, on which the parameters depend linearly, to
    the bias's size and to 1."""
    theta = np.asarray(theta, float)
    out = np.ones(len(theta))
    out[:3] = max(float(np.max(np.abs(theta[:3]))), 1.0)
    out[3:9] = 1e-3 * float(np.max(np.abs(theta[3:6])))
    return out


def jacobian(f, x: np.ndarray, rel: float = 1e-6, floor=1e-12, many=False) -> np.ndarray:
    """Central-difference Jacobian of a small vector function; step ``rel * max(|x_k|,
    floor_k)`` (``floor`` a number or one per coordinate, e.g. :func:`theta_floor`).
    ``many``: ``f`` maps a stack of points (p, n) to their values (p, m) in one call."""
    x = np.asarray(x, float)
    n = len(x)
    floor = np.broadcast_to(np.asarray(floor, float), (n,))
    h = np.array([rel * max(abs(x[k]), floor[k]) for k in range(n)])
    E = np.diag(h)
    points = np.concatenate([x + E, x - E])  # x + h_k e_k, then x - h_k e_k
    F = _evaluate(f, points, many)
    return ((F[:n] - F[n:]) / (2 * h)[:, None]).T


def _evaluate(f, points: np.ndarray, many: bool) -> np.ndarray:
    """``f`` at each row of ``points``, (p, m)."""
    if many:
        return np.asarray(f(points), float)
    return np.array([np.asarray(f(p), float) for p in points])


def second_order(f, x: np.ndarray, cov: np.ndarray, rel: float = 1e-4, many=False):
    """Second-order moments of ``f(x_hat)`` when ``x_hat ~ N(x, cov)``: the bias
    ``tr(cov H_i) / 2`` and the extra covariance ``tr(H_i cov H_j cov) / 2`` (``H_i`` the
    Hessian of output i, central differences). ``x`` is one block in one unit (``K``): each
    step is at least ``rel`` times a thousandth of its largest entry, so that an entry near
    zero does not get a step near zero (its second differences would be rounding noise over
    ``h^2``: a 1.8e-6 off-diagonal entry once gave angles of 24000 degrees). ``many`` as
    :func:`jacobian`'s."""
    n = len(x)
    h = rel * np.maximum(np.abs(x), 1e-3 * max(float(np.max(np.abs(x))), 1e-300))
    E = np.diag(h)
    iu, ju = np.triu_indices(n, 1)
    # x; x +- h_i e_i; then x + s_i h_i e_i + s_j h_j e_j (i < j) for (s_i, s_j) = ++, +-, -+, --
    points = [x[None], x + E, x - E]
    points += [x + si * E[iu] + sj * E[ju] for si in (1, -1) for sj in (1, -1)]
    F = _evaluate(f, np.concatenate(points), many)
    f0, fp, fm = F[0], F[1 : n + 1], F[n + 1 : 2 * n + 1]
    fpp, fpm, fmp, fmm = F[2 * n + 1 :].reshape(4, len(iu), -1)
    H = np.empty((len(f0), n, n))
    H[:, np.arange(n), np.arange(n)] = ((fp - 2 * f0 + fm) / (h**2)[:, None]).T
    off = ((fpp - fpm - fmp + fmm) / (4 * h[iu] * h[ju])[:, None]).T
    H[:, iu, ju] = H[:, ju, iu] = off
    HC = H @ cov
    return 0.5 * np.einsum("iab,ba->i", H, cov), 0.5 * np.einsum("iab,jba->ij", HC, HC)


def faces_of(up: np.ndarray) -> np.ndarray:
    """The face of each pose: poses with the same label share one index (unlabelled poses
    their own), shape (N,)."""
    keys: dict = {}
    out = np.empty(len(up), dtype=int)
    for k, u in enumerate(np.asarray(up, float)):
        key = tuple(np.round(u, 9)) if np.isfinite(u).all() else ("unlabelled", k)
        out[k] = keys.setdefault(key, len(keys))
    return out


def whitening(cov_mean: np.ndarray) -> np.ndarray:
    """``W_k`` with ``W_k^T W_k = Sigma_k^-1``, shape (N, 3, 3)."""
    L = np.linalg.cholesky(np.linalg.inv(cov_mean))
    return np.transpose(L, (0, 2, 1))


class Problem:
    """Whitened residuals and Jacobian of (L3) in normalised raw coordinates.

    ``x = (B_n (3), K_n upper (6), phi (3, rad), delta (2N))`` with ``a_n = (a - offset) /
    scale``, ``B_n = (B - offset) / scale``, ``K_n = scale K`` and the prediction of pose k
    ``f_k = B_n + g K_n^-1 R(phi)^T u_k(delta_k)`` (L2 with ``S = K^-1 R^T``). The explicit
    rotation keeps the frame's uncertainty a rotation: no spurious second-order effect of the
    (label-limited) frame on the (noise-limited) gains.
    """

    def __init__(self, a_n, cov_n, u0, labelled, g, sigma_p, meas_scale=1.0, faces=None):
        self.a_n, self.cov_n, self.u0, self.g = a_n, cov_n, u0, g
        self.W = whitening(cov_n)
        self.offset = np.zeros_like(a_n)  # second-order mean of each prediction (marginalise)
        self.T = tangent_bases(u0)
        self.lab = np.flatnonzero(labelled)
        self.N = len(a_n)
        # Face of each labelled pose (its label, :func:`faces_of`): the poses on one face
        # share that face's part of their placement (L1b). None: every pose its own face.
        self.faces = None if faces is None else np.asarray(faces)[self.lab]
        self.sigma_p = sigma_p
        self.meas_scale = meas_scale  # measurement sigma multiplier (noise_scale ** 0.5)
        # The last prediction and where it was made: a Levenberg-Marquardt step evaluates
        # the residuals at a point, then (accepted) the Jacobian at the same point.
        self._last: tuple[bytes, tuple[np.ndarray, np.ndarray]] | None = None
        self._last_f: tuple[bytes, np.ndarray] | None = None  # the last prediction alone
        # The directions (L1) and the rotation with its difference quotients, by argument:
        # refits hold the directions, the marginalisation the rotation.
        self._dirs: tuple[bytes, tuple[np.ndarray, np.ndarray]] | None = None
        self._rot: tuple[bytes, np.ndarray, list | None] | None = None
        self._layout: tuple | None = None

    @property
    def sigma_p(self) -> float:
        """Prior std of each placement angle, rad: ``sqrt(sigma_f^2 + sigma_h^2)`` (L1b)."""
        return float(np.hypot(self.sigma_f, self.sigma_h))

    @sigma_p.setter
    def sigma_p(self, value: float) -> None:  # one component: every pose placed on its own
        self.set_placement(0.0, value)

    @property
    def repeated(self) -> bool:
        """Whether some face holds more than one labelled pose (the two parts separate)."""
        return self.faces is not None and len(np.unique(self.faces)) < len(self.faces)

    def set_placement(self, sigma_f: float, sigma_h: float) -> None:
        """The placement's two parts (L1b), rad per angle, and the prior rows' whitening
        ``C^-1/2`` (symmetric, so that each pose keeps its own two rows): per face of ``m``
        poses ``C = sigma_f^2 1 1^T + sigma_h^2 I``, whose inverse square root is
        ``(I - 1 1^T / m) / sigma_h + 1 1^T / m / sqrt(sigma_h^2 + m sigma_f^2)``."""
        self.sigma_f, self.sigma_h = float(sigma_f), float(sigma_h)
        L = len(self.lab)
        if self.sigma_f == 0.0 or not self.repeated:
            self.Wp = np.eye(L) / self.sigma_p
        else:
            Wl = np.zeros((L, L))
            for f in np.unique(self.faces):
                idx = np.flatnonzero(self.faces == f)
                m = len(idx)
                mean = np.full((m, m), 1.0 / m)
                Wl[np.ix_(idx, idx)] = ((np.eye(m) - mean) / self.sigma_h
                                        + mean / np.sqrt(self.sigma_h**2 + m * self.sigma_f**2))
            self.Wp = Wl
        self.Wp2 = np.kron(self.Wp, np.eye(2))  # on the rows (delta_k1, delta_k2) per pose

    def placement_covariance(self) -> tuple[np.ndarray, np.ndarray]:
        """The placement's prior covariance (2L, 2L) and its face part per unit
        ``sigma_f^2`` (the face indicator), for the variance components (L1b)."""
        L = len(self.lab)
        same = (np.eye(L) if self.faces is None
                else (self.faces[:, None] == self.faces[None, :]).astype(float))
        Vf = np.kron(same, np.eye(2))
        return self.sigma_f**2 * Vf + self.sigma_h**2 * np.eye(2 * L), Vf

    @property
    def n_rows(self) -> int:
        return 3 * self.N + 2 * len(self.lab)

    def split(self, x):
        K = np.zeros((3, 3))
        K[_UPPER] = x[3:9]
        return x[:3], K, x[9:12], x[12:].reshape(self.N, 2)

    def predict(self, x):
        """``f_k`` (N, 3) and ``d f_k / d z_k`` (N, 3, 11), ``z_k = (K upper, phi, delta_k)``
        (the arrays of the last call again when ``x`` is the same: not to be modified)."""
        key = np.asarray(x, float).tobytes()
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        out = self._predict(x)
        self._last = (key, out)
        return out

    def values(self, x) -> np.ndarray:
        """``f_k`` (N, 3) alone, the same numbers as :meth:`predict`'s (what a residual
        evaluation needs; not to be modified)."""
        key = np.asarray(x, float).tobytes()
        if self._last is not None and self._last[0] == key:
            return self._last[1][0]
        if self._last_f is None or self._last_f[0] != key:
            _, K, phi, d = self.split(x)
            u, _ = self._directions(d)
            self._last_f = (key, self._values(np.linalg.inv(K), self._rotation(phi)[0], u))
        return self._last_f[1]

    def _values(self, Kinv, R, u):
        w = u @ R  # R^T u_k, rows
        return self.g * (w @ Kinv.T)  # g K^-1 w_k

    def _directions(self, d):
        """:func:`sphere_exp` at ``d`` (N, 2), cached."""
        key = d.tobytes()
        if self._dirs is None or self._dirs[0] != key:
            self._dirs = (key, sphere_exp(self.u0, self.T, d))
        return self._dirs[1]

    def _rotation(self, phi, derivative=False):
        """``R(phi)`` and, with ``derivative``, its central differences ``dR / dphi_c`` (a
        list of three 3x3), cached for the last ``phi``."""
        key = phi.tobytes()
        if self._rot is None or self._rot[0] != key:
            self._rot = (key, Rotation.from_rotvec(phi).as_matrix(), None)
        if derivative and self._rot[2] is None:
            h = 1e-6
            steps = np.repeat(h * np.eye(3), 2, axis=0) * np.array([1.0, -1.0] * 3)[:, None]
            Rs = Rotation.from_rotvec(phi + steps).as_matrix()  # phi +- h e_c, c = 0, 1, 2
            dR = [(Rs[2 * c] - Rs[2 * c + 1]) / (2 * h) for c in range(3)]
            self._rot = (key, self._rot[1], dR)
        return self._rot[1], self._rot[2]

    def _predict(self, x):
        _, K, phi, d = self.split(x)
        Kinv = np.linalg.inv(K)
        R, dR = self._rotation(phi, derivative=True)
        u, du = self._directions(d)
        z = (u @ R) @ Kinv.T  # K^-1 R^T u_k
        f = self.g * z  # as _values
        D = np.empty((self.N, 3, 11))
        for c, (i, j) in enumerate(zip(*_UPPER, strict=True)):
            D[:, :, c] = -self.g * Kinv[:, i][None, :] * z[:, j][:, None]  # d K^-1 = -K^-1 E K^-1
        for c in range(3):
            D[:, :, 6 + c] = self.g * (u @ dR[c]) @ Kinv.T
        D[:, :, 9:] = self.g * np.einsum("ij,kj,nkc->nic", Kinv, R, du)  # g K^-1 R^T du
        return f, D

    def residuals(self, x):
        B, _, _, d = self.split(x)
        f = self.values(x)
        e = self.a_n - B - f - self.offset
        r_meas = np.einsum("nij,nj->ni", self.W, e).ravel() / self.meas_scale
        return np.concatenate([r_meas, self.Wp2 @ d[self.lab].ravel()])

    def jacobian(self, x, sparse=False):
        _, D = self.predict(x)
        N = self.N
        W = self.W / self.meas_scale
        Jt = np.empty((N, 3, 12))
        Jt[:, :, :3] = -W
        Jt[:, :, 3:] = -np.einsum("nij,njc->nic", W, D[:, :, :9])
        Jd = -np.einsum("nij,njc->nic", W, D[:, :, 9:])
        rows_d, cols_d, pr_rows, pr_cols = self.layout()
        if sparse:
            pi, pj = np.nonzero(self.Wp2)
            r = np.concatenate([np.repeat(np.arange(3 * N), 12), rows_d.ravel(), pr_rows[pi]])
            c = np.concatenate([np.tile(np.arange(12), 3 * N), cols_d.ravel(), pr_cols[pj]])
            v = np.concatenate([Jt.ravel(), Jd.ravel(), self.Wp2[pi, pj]])
            return coo_matrix((v, (r, c)), shape=(self.n_rows, 12 + 2 * N)).tocsr()
        J = np.zeros((self.n_rows, 12 + 2 * N))
        J[: 3 * N, :12] = Jt.reshape(3 * N, 12)
        J[rows_d.ravel(), cols_d.ravel()] = Jd.ravel()
        J[np.ix_(pr_rows, pr_cols)] = self.Wp2
        return J

    def layout(self):
        """Rows and columns of the Jacobian's placement entries: each pose's 3 x 2 block
        ``(rows_d, cols_d)``, (N, 3, 2) each, and the prior rows' ``(pr_rows, pr_cols)``."""
        if self._layout is None:
            N, L = self.N, len(self.lab)
            rows_d = np.arange(3 * N).reshape(N, 3)[:, :, None].repeat(2, axis=2)
            cols_d = (12 + 2 * np.arange(N)[:, None, None] + np.arange(2)[None, None, :]).repeat(
                3, axis=1
            )
            pr_rows = 3 * N + np.arange(2 * L)
            pr_cols = 12 + (2 * self.lab[:, None] + np.arange(2)).ravel()
            self._layout = (rows_d, cols_d, pr_rows, pr_cols)
        return self._layout

    def marginalise(self, x, P):
        """Second-order marginalisation over the placement (what the Gaussian approximation at
        the estimate misses). Only the directions are random (the prior); given the frame
        rotation ``phi``, which the labels fix as a whole (a gauge of the data), ``delta_k``
        keeps an uncertainty ``P_k``. The prediction ``f_k`` then has mean ``f_k(delta_hat) +
        tr(P_k H_a) / 2`` and an extra covariance ``tr(H_a P_k H_b P_k) / 2`` (``H_a`` the
        Hessian of component a over ``delta_k``). Matters where the labels, not the data, fix a
        direction: on six faces the gains are otherwise biased by about ``sigma_p^2``
        (``E cos|delta| = 1 - E|delta|^2 / 2``)."""
        N = self.N
        cols = 12 + 2 * np.arange(N)[:, None] + np.arange(2)
        H = np.empty((N, 3, 2, 2))
        h = 1e-5
        for v in range(2):
            xp, xm = x.copy(), x.copy()
            xp[cols[:, v]] += h
            xm[cols[:, v]] -= h
            H[:, :, :, v] = (self.predict(xp)[1][:, :, 9:] - self.predict(xm)[1][:, :, 9:]) / (
                2 * h
            )
        H = 0.5 * (H + np.swapaxes(H, 2, 3))
        Pdd = P[cols[:, :, None], cols[:, None, :]]
        Pdf = P[cols[:, :, None], np.arange(9, 12)[None, None, :]]
        Pk = Pdd - Pdf @ np.linalg.solve(P[9:12, 9:12], np.swapaxes(Pdf, 1, 2))
        self.offset = 0.5 * np.einsum("npq,naqp->na", Pk, H)
        HP = np.einsum("naij,njk->naik", H, Pk)
        extra = 0.5 * np.einsum("naij,nbji->nab", HP, HP)
        self.W = whitening(self.cov_n + extra)

    def gauge_modes(self, x) -> np.ndarray:
        """The three directions of ``x`` that leave every prediction unchanged (a rotation of
        the frame ``phi`` and every direction together), (n_x, 3)."""
        _, _, phi, d = self.split(x)
        u, du = sphere_exp(self.u0, self.T, d)
        G = np.zeros((len(x), 3))
        h = 1e-6
        for c in range(3):
            w = np.zeros(3)
            w[c] = h
            rp = (Rotation.from_rotvec(w) * Rotation.from_rotvec(phi)).as_rotvec()
            rm = (Rotation.from_rotvec(-w) * Rotation.from_rotvec(phi)).as_rotvec()
            G[9:12, c] = (rp - rm) / (2 * h)
            move = np.cross(np.eye(3)[c], u)  # d u_k / d omega_c
            G[12:, c] = np.einsum("nij,nj->ni", np.linalg.pinv(du), move).ravel()
        return G

    def without_gauge(self, x, P) -> np.ndarray:
        """``P`` less its part along the gauge modes (what only the labels as a whole fix)."""
        G = self.gauge_modes(x)
        J = self.jacobian(x)
        JG = J @ G
        return P - G @ np.linalg.solve(JG.T @ JG, G.T)

    def groups(self) -> list[np.ndarray]:
        """Rows of each pose: its 3 measurement rows and, if labelled, its 2 prior rows."""
        out = [np.arange(3 * k, 3 * k + 3) for k in range(self.N)]
        for j, k in enumerate(self.lab):
            out[k] = np.r_[out[k], 3 * self.N + 2 * j, 3 * self.N + 2 * j + 1]
        return out


def design_jacobian(M: np.ndarray, u: np.ndarray, g: float) -> tuple[np.ndarray, np.ndarray]:
    """``d a_k / d theta`` and ``d a_k / d delta_k`` of (L2) at directions ``u`` (delta = 0).

    ``theta = (B, K upper, r)`` with ``M = R(r) K`` (r in degrees, as :data:`PARAM_NAMES`).
    Returns arrays (N, 3, 12) and (N, 3, 2), raw units per parameter unit."""
    K, Q = triangular_and_rotation(M)
    u = np.atleast_2d(np.asarray(u, float))
    N = len(u)
    prob = Problem(np.zeros((N, 3)), np.tile(np.eye(3), (N, 1, 1)), u, np.ones(N, bool), g, 1.0)
    phi = Rotation.from_matrix(Q).as_rotvec()
    x = np.concatenate([np.zeros(3), K[_UPPER], phi, np.zeros(2 * N)])
    _, D = prob.predict(x)
    Gt = np.empty((N, 3, 12))
    Gt[:, :, :3] = np.eye(3)
    Gt[:, :, 3:9] = D[:, :, :6]
    Gt[:, :, 9:] = D[:, :, 6:9] * np.radians(1.0)
    return Gt, D[:, :, 9:]
