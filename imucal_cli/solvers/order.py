"""Medians and quantiles as numpy computes them, without numpy's masked-array module.

``np.median``, ``np.nanmedian`` and ``np.quantile`` import ``numpy.ma`` on their first call, 0.01 s
of a command's start-up (issue 14). These select the order statistics with ``np.partition`` and
combine them with numpy's own arithmetic, so they return numpy's numbers bit for bit
(``tests/test_order.py``) for float64 (and, for the median, integer) input; an empty input or
another type is left to numpy.
"""

from __future__ import annotations

import math

import numpy as np


def median(a, axis: int | None = None):
    """``np.median(a, axis)``: the middle value, or the mean of the two middle values, of the
    flattened array or along ``axis``; NaN where a NaN is present.

    Parameters
    ----------
    a : array_like
    axis : int, optional

    Returns
    -------
    float64 scalar, or ndarray of the shape of ``a`` without ``axis``
    """
    a = np.asarray(a)
    if a.dtype != np.float64 and a.dtype.kind not in "iu":
        return np.median(a, axis=axis)  # float32, longdouble...: numpy keeps their type
    a = a.astype(np.float64, copy=False)
    if axis is None:
        a, axis = a.ravel(), 0
    n = a.shape[axis]
    if n == 0:
        return np.median(a, axis=axis)
    part = np.partition(np.moveaxis(a, axis, -1), [*_kth(n), n - 1], axis=-1)  # NaN sorts last
    out = _middle(part)
    nan = np.isnan(part[..., -1])
    if np.any(nan):
        out = np.where(nan, np.nan, out)
    return out[()]  # a scalar where numpy gives one (``[..., h]`` of 1-D is 0-d)


def middle_in_place(work: np.ndarray) -> np.ndarray:
    """The median of each row of ``work`` (float64, without NaN), as ``np.median(work,
    axis=-1)`` gives it, by partitioning ``work`` in place (no copy: the caller's own)."""
    work.partition(_kth(work.shape[-1]), axis=-1)
    return _middle(work)


def _kth(n: int) -> list[int]:
    """The order statistics a median of ``n`` values needs."""
    return [n // 2] if n % 2 else [n // 2 - 1, n // 2]


def _middle(part: np.ndarray) -> np.ndarray:
    """The median of each row of ``part``, partitioned at :func:`_kth`: numpy's mean of the
    middle value(s), a sum that starts from +0.0 (so -0.0 becomes 0.0)."""
    n = part.shape[-1]
    h = n // 2
    if n % 2:
        return part[..., h] + 0.0
    return (0.0 + part[..., h - 1] + part[..., h]) / 2.0


def nanmedian(a):
    """``np.nanmedian(a)`` of the flattened array: the median of its values that are not NaN."""
    a = np.asarray(a)
    if a.dtype != np.float64:
        return np.nanmedian(a)
    a = a.ravel()
    kept = a[~np.isnan(a)]
    return median(kept) if len(kept) else np.nanmedian(a)


def quantile(a, q: float):
    """``np.quantile(a, q)`` (its default, linear interpolation) of the flattened array, for
    one ``q`` in [0, 1]; NaN when a NaN is present."""
    a = np.asarray(a)
    if a.dtype != np.float64 or a.size == 0 or not 0.0 <= q <= 1.0:
        return np.quantile(a, q)
    a = a.ravel()
    n = len(a)
    virtual = (n - 1) * q
    if virtual >= n - 1:
        below = above = n - 1
    else:
        below = int(math.floor(virtual))
        above = below + 1
    part = np.partition(a, sorted({0, below, above, n - 1}))
    if np.isnan(part[-1]):
        return np.float64(np.nan)
    lo, hi = part[below], part[above]
    gamma = np.float64(virtual - (below if virtual < n - 1 else -1))  # numpy's t
    diff = hi - lo
    return hi - diff * (1 - gamma) if gamma >= 0.5 else lo + diff * gamma


def distinct(a) -> np.ndarray:
    """``np.unique(a)``: the sorted distinct values of the flattened array (NaNs, as numpy
    keeps them, each apart)."""
    a = np.sort(np.asarray(a).ravel())
    if a.size == 0:
        return a
    if a.dtype.kind in "fc" and np.isnan(a[-1]):
        return np.unique(a)  # numpy's handling of NaN (equal_nan)
    keep = np.empty(a.shape, dtype=bool)
    keep[0] = True
    np.not_equal(a[1:], a[:-1], out=keep[1:])
    return a[keep]
