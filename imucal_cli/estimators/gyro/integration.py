"""Integration of gyro rates over many rotations at once, and its sensitivity to the rates.

All rotations are stacked end to end (:class:`Stack`); one pass computes every sample
interval's rotation increment, and a segmented prefix product (``ceil(log2 L)`` vectorised
passes for segments of at most ``L`` samples) gives each sample's attitude relative to the
start of its rotation. Time and memory are linear in the number of samples. The products
are taken on quaternions held as pairs of complex numbers (:func:`qmul`: four numpy passes
a product where sixteen real products and twelve sums took 28).

Increment over one sample interval ``h`` with the rate linear between samples ``w0``, ``w1``
(Bortz's rotation-vector equation to second order, the "two-sample coning" form):

    phi = h/2 (w0 + w1) + h^2/12 (w0 x w1)

exact for turns about a fixed axis, and within ``h^4 |w|^2 |w1 - w0| / 96`` rad per step
otherwise (below 1e-7 rad per step for hand turns at 100 Hz).

The sensitivity of a rotation's end attitude to a rate perturbation ``d omega(t)`` is the
small rotation (body frame at the end) ``d phi = integral R(t -> end) d omega(t) dt``,
evaluated with trapezoid weights over the samples.

Time enters only through ``clock``: every sample interval is ``clock * diff(t)``, so a sample
clock correction scales the whole integration through that one factor.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import factorial

import numpy as np


def qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions held as complex pairs (2, ...): ``w + x i`` and
    ``y + z i`` (``q = (w + x i) + (y + z i) j``, the Cayley-Dickson form). Four complex
    products instead of sixteen real ones and twelve sums (one numpy pass each):

        (a1 + b1 j)(a2 + b2 j) = (a1 a2 - b1 conj(b2)) + (a1 b2 + b1 conj(a2)) j
    """
    a1, b1 = p
    a2, b2 = q
    out = np.empty(p.shape, dtype=complex)  # p and q of one shape
    np.multiply(a1, a2, out=out[0])
    out[0] -= b1 * b2.conj()
    np.multiply(a1, b2, out=out[1])
    out[1] += b1 * a2.conj()
    return out


def from_pairs(c: np.ndarray) -> np.ndarray:
    """(2, N) complex pairs -> (4, N) quaternions ``[w, x, y, z]``."""
    out = np.empty((4,) + c.shape[1:])
    out[0::2], out[1::2] = c.real, c.imag
    return out


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(4, N) unit quaternions -> (N, 3, 3) rotation matrices."""
    return np.ascontiguousarray(matrix_rows(q).T).reshape(-1, 3, 3)


def matrix_rows(q: np.ndarray) -> np.ndarray:
    """(4, N) unit quaternions -> (9, N) rotation matrices, row-major entries first."""
    w_, x, y, z = q
    xx, yy, zz, xy, xz, yz = x * x, y * y, z * z, x * y, x * z, y * z
    wx, wy, wz = w_ * x, w_ * y, w_ * z
    R = np.empty((9,) + q.shape[1:])
    # Written into R row by row (no list of nine temporaries stacked afterwards):
    # 1 - 2 (yy + zz), 2 (xy - wz), 2 (xz + wy), 2 (xy + wz), 1 - 2 (xx + zz), 2 (yz - wx),
    # 2 (xz - wy), 2 (yz + wx), 1 - 2 (xx + yy)
    for row, (a, b, op) in enumerate(
        [(yy, zz, None), (xy, wz, np.subtract), (xz, wy, np.add),
         (xy, wz, np.add), (xx, zz, None), (yz, wx, np.subtract),
         (xz, wy, np.subtract), (yz, wx, np.add), (xx, yy, None)]
    ):  # fmt: skip
        out = R[row : row + 1]  # a view also where q is one quaternion (4,)
        if op is None:  # 1 - 2 (a + b)
            np.add(a, b, out=out)
            out *= 2
            np.subtract(1, out, out=out)
        else:  # 2 (a -+ b)
            op(a, b, out=out)
            out *= 2
    return R


def rotvec_to_quat(phi: np.ndarray) -> np.ndarray:
    """(3, N) rotation vectors -> (4, N) unit quaternions."""
    return from_pairs(_rotvec_pairs(phi))


def _rotvec_pairs(phi: np.ndarray) -> np.ndarray:
    """(3, N) rotation vectors -> (2, N) unit quaternions as complex pairs (:func:`qmul`):
    ``(cos(theta/2), sin(theta/2)/theta phi)``, both factors by their Taylor series in
    ``(theta/2)^2`` (:data:`SERIES_MAX`; numpy's sin and cos, several times slower, for the
    rare longer steps)."""
    theta = np.sqrt(np.einsum("in,in->n", phi, phi))
    x2 = theta * theta / 4
    c, s = _series(x2, COS_SERIES), _series(x2, SIN_SERIES)
    big = np.flatnonzero(theta > SERIES_MAX)
    if len(big):
        half = theta[big] / 2
        c[big] = np.cos(half)
        s[big] = np.sin(half) / theta[big]
    out = np.empty((2, phi.shape[1]), dtype=complex)
    out.real[0], out.imag[0] = c, phi[0] * s
    out.real[1], out.imag[1] = phi[1] * s, phi[2] * s
    return out


#: Rotation angles (rad) up to which :func:`_rotvec_pairs` sums the series: the first term
#: left out, ``(theta/2)^14 / 14!``, is below 1e-19 (a hand turn at 100 Hz moves about 0.05
#: rad a sample, the start's coarse integrator four times as much).
SERIES_MAX = 0.5
#: ``cos(x) = sum_k (-1)^k x^2k / (2k)!`` and ``sin(x) / (2x) = sum_k (-1)^k x^2k / (2k+1)! / 2``
#: (``sin(theta/2) / theta`` with ``x = theta/2``), k = 0..6.
COS_SERIES = tuple((-1) ** k / factorial(2 * k) for k in range(7))
SIN_SERIES = tuple((-1) ** k / factorial(2 * k + 1) / 2 for k in range(7))


def _series(x2: np.ndarray, coef: tuple[float, ...]) -> np.ndarray:
    """``sum_k coef[k] x2^k`` by Horner's rule, in place on one array."""
    p = np.full_like(x2, coef[-1])
    for c in coef[-2::-1]:
        p *= x2
        p += c
    return p


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of (3, N) vectors."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


#: Samples per block of the blocked prefix product.
BLOCK = 16


@dataclass
class Stack:
    """Rotation segments stacked end to end.

    Attributes
    ----------
    t : ndarray (N,)
        Sample times, s.
    start, stop : ndarray of int (K,)
        Each segment's rows ``start:stop``.
    seg : ndarray of int (N,)
        Segment of each row.
    pos : ndarray of int (N,)
        Row index within its segment.
    weights : ndarray (N,)
        Trapezoid weights of each sample in its segment's time integral, s (``clock`` 1).
    """

    t: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    seg: np.ndarray
    pos: np.ndarray
    weights: np.ndarray
    _blocks: tuple | None = field(default=None, repr=False)
    _src: np.ndarray | None = field(default=None, repr=False)
    _pad: np.ndarray | None = field(default=None, repr=False)

    @classmethod
    def of(cls, t: list[np.ndarray]) -> Stack:
        lengths = np.array([len(x) for x in t], dtype=np.int64)
        if np.any(lengths < 2):
            raise ValueError("every rotation needs at least 2 samples")
        stop = np.cumsum(lengths)
        start = stop - lengths
        seg = np.repeat(np.arange(len(t)), lengths)
        pos = np.arange(stop[-1]) - start[seg]
        tt = np.concatenate(t).astype(float)
        h = np.diff(tt)
        h[stop[:-1] - 1] = 0.0  # no interval across two segments
        weights = np.zeros(len(tt))
        weights[:-1] += h / 2
        weights[1:] += h / 2
        return cls(tt, start, stop, seg, pos, weights)

    @property
    def n_segments(self) -> int:
        return len(self.start)

    def blocks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """Layout of the blocked prefix product (computed once): each row's block, its flat
        index in a (BLOCK, n_blocks) array, each block's index within its segment, and the
        most blocks of one segment."""
        if self._blocks is None:
            lengths = self.stop - self.start
            n_blocks = -(-lengths // BLOCK)
            first = np.cumsum(n_blocks) - n_blocks
            block = first[self.seg] + self.pos // BLOCK
            nb = int(n_blocks.sum())
            flat = (self.pos % BLOCK) * nb + block
            bpos = np.arange(nb) - np.repeat(first, n_blocks)
            self._blocks = (block, flat, bpos, int(n_blocks.max()))
        return self._blocks

    def _gathering(self) -> None:
        """Each slot of the (BLOCK, nb) layout's source row (computed once), and the padding."""
        if self._src is None:
            _, flat, bpos, _ = self.blocks()
            src = np.zeros(BLOCK * len(bpos), dtype=np.int64)
            filled = np.zeros(len(src), bool)
            src[flat], filled[flat] = np.arange(len(flat)), True
            self._src, self._pad = src, np.flatnonzero(~filled)

    def gather(self, a: np.ndarray) -> np.ndarray:
        """Per-row values (k, N) laid out as the blocked product wants them, (k, BLOCK, nb)
        (a gather: cheaper than scattering into that layout); the padding after each
        segment's last row repeats some row and is to be overwritten (:attr:`padding`)."""
        self._gathering()
        return a.take(self._src, axis=1).reshape(len(a), BLOCK, -1)

    @property
    def padding(self) -> np.ndarray:
        """Flat indices of the padding slots in the (BLOCK, nb) layout."""
        self._gathering()
        return self._pad


def attitudes(stack: Stack, w: np.ndarray, clock: float = 1.0) -> np.ndarray:
    """Attitude of every sample relative to the start of its segment, (4, N) quaternions.

    Parameters
    ----------
    stack : Stack
    w : ndarray (3, N)
        Body rate, rad/s (per second of ``clock * t``), linear between samples; component-major
        like every per-sample array here (contiguous rows make the vector passes fast).
    clock : float
        Factor on every time interval (sample-clock correction).

    Returns
    -------
    ndarray (4, N)
        ``q_i`` (component-major) with ``R(q_i)`` the body frame at sample ``i`` expressed in
        the body frame at its segment's first sample.
    """
    w0, w1 = w[:, :-1], w[:, 1:]
    h = clock * np.diff(stack.t) * (stack.pos[1:] > 0)  # zero across a segment boundary
    phi = np.zeros((3, len(stack.t)))
    # Increment into row i from row i-1; rows at a segment start keep the identity.
    phi[:, 1:] = h / 2 * (w0 + w1) + h * h / 12 * _cross(w0, w1)
    return compose(stack, phi)


def compose(stack: Stack, phi: np.ndarray) -> np.ndarray:
    """Attitudes (4, N) from rotation-vector increments ``phi`` (3, N), each the body rotation
    from the previous row to this one (zero at every segment's first row)."""
    return from_pairs(_prefix_product(stack, phi))


def compose_ends(stack: Stack, phi: np.ndarray) -> np.ndarray:
    """The attitude at the end of each segment only, (4, K) quaternions, from rotation-vector
    increments ``phi`` (3, N) as :func:`compose` takes them: a segmented product (each block's
    product by pairwise halving, ``log2`` of :data:`BLOCK` passes, then the blocks' products
    within each segment), about one quaternion product per sample and no per-sample output."""
    block, _, bpos, n_blocks = stack.blocks()
    Qb = _blocked_increments(stack, phi)
    while Qb.shape[1] > 1:  # adjacent pairs, in order
        Qb = qmul(Qb[:, 0::2], Qb[:, 1::2])
    T = _block_scan(Qb[:, 0], bpos, n_blocks)
    return from_pairs(_normalised(T.take(block[stack.stop - 1], axis=1)))


def _block_scan(T: np.ndarray, bpos: np.ndarray, n_blocks: int) -> np.ndarray:
    """Inclusive scan (Hillis-Steele) of block products (2, nb) within each segment, in place:
    ``log2`` of the most blocks of one segment vector passes."""
    d = 1
    while d < n_blocks:
        T[:, d:] = np.where(bpos[d:] >= d, qmul(T[:, :-d], T[:, d:]), T[:, d:])
        d *= 2
    return T


def _blocked_increments(stack: Stack, phi: np.ndarray) -> np.ndarray:
    """Rotation-vector increments (3, N) as quaternions in the blocked layout (2, BLOCK, nb),
    the padding the identity."""
    Qb = _rotvec_pairs(stack.gather(phi).reshape(3, -1))
    Qb[:, stack.padding] = [[1.0], [0.0]]
    return Qb.reshape(2, BLOCK, -1)


def _prefix_product(stack: Stack, phi: np.ndarray) -> np.ndarray:
    """Segmented inclusive prefix product of the quaternions of rotation-vector increments
    ``phi`` (3, N), normalised, as complex pairs (2, N) (:func:`qmul`).

    Blocked scan: each segment is cut into blocks of :data:`BLOCK` samples; a running product
    within every block at once (``BLOCK`` vector passes), a segmented Hillis-Steele scan over
    the block totals (``log2`` of the blocks per segment passes over a ``1/BLOCK`` array), and
    one pass that puts each block's preceding total in front. About three quaternion products
    per sample, whatever the segments' lengths.
    """
    block, flat, bpos, n_blocks = stack.blocks()
    nb = len(bpos)
    Qb = _blocked_increments(stack, phi)
    for j in range(1, BLOCK):
        Qb[:, j] = qmul(Qb[:, j - 1], Qb[:, j])
    T = _block_scan(Qb[:, -1].copy(), bpos, n_blocks)  # block totals within each segment
    before = np.zeros((2, 1, nb), dtype=complex)  # product of the blocks before each block
    before[0] = 1.0
    later = np.flatnonzero(bpos > 0)
    before[:, 0, later] = T[:, later - 1]
    out = qmul(np.broadcast_to(before, Qb.shape), Qb).reshape(2, -1).take(flat, axis=1)
    return _normalised(out)


def _normalised(q: np.ndarray) -> np.ndarray:
    """Quaternions as complex pairs (2, N) scaled to unit norm, in place: ``(w^2 + x^2) +
    (y^2 + z^2)`` from one pass of squares (an einsum over the strided pairs took 4 times
    as long)."""
    re = q.view(float).reshape(2, -1, 2)  # (w, x) and (y, z) pairs
    sq = re * re
    norm2 = sq[0, :, 0] + sq[0, :, 1]
    norm2 += sq[1, :, 0] + sq[1, :, 1]
    re /= np.sqrt(norm2)[None, :, None]
    return q


def end_sensitivity(
    stack: Stack, R9: np.ndarray, v: np.ndarray | None = None, clock: float = 1.0
) -> np.ndarray:
    """How each segment's end attitude moves with a rate perturbation, summed with weights.

    With ``E_i = R_end^T R_i`` (carrying a small rotation at sample ``i`` to the segment's
    end), returns ``sum_i w_i E_i`` (shape (K, 3, 3)) when ``v`` is None, else
    ``sum_i w_i E_i[a, c] v_i[j]`` (shape (K, 3, 3, 3), indices ``a, c, j``): the end rotation
    caused by ``d omega_i = dA v_i`` for a 3 x 3 ``dA`` is ``S[:, :, c, j] dA[c, j]``.

    Parameters
    ----------
    R9 : ndarray (9, N)
        Attitudes (:func:`matrix_rows` of :func:`attitudes`).
    v : ndarray (3, N), optional
        A per-sample vector (the bias-free raw rate, the specific force...).
    """
    R_end = R9[:, stack.stop - 1].T.reshape(-1, 3, 3)
    w = clock * stack.weights
    if v is None:
        S = np.add.reduceat(R9 * w, stack.start, axis=1).T.reshape(-1, 3, 3)
        return np.einsum("kba,kbc->kac", R_end, S)
    S = np.stack(
        [np.add.reduceat(R9 * (w * v[j]), stack.start, axis=1).T.reshape(-1, 3, 3)
         for j in range(3)], axis=3,
    )  # fmt: skip
    return np.einsum("kba,kbcj->kacj", R_end, S)


def integrate_rotations(
    t: list[np.ndarray], w: list[np.ndarray], *, clock: float = 1.0
) -> np.ndarray:
    """Body rotation over each segment, all segments at once.

    Parameters
    ----------
    t : list of ndarray (n_k,)
        Sample times, s.
    w : list of ndarray (n_k, 3)
        Body angular rate, rad/s, linearly interpolated between samples.
    clock : float
        Factor on every time interval.

    Returns
    -------
    ndarray (K, 3, 3)
        ``R_k``: the body frame at the end expressed in the body frame at the start.
    """
    stack = Stack.of(t)
    q = attitudes(stack, np.concatenate(w).T.copy(), clock)
    return quat_to_matrix(q[:, stack.stop - 1])
