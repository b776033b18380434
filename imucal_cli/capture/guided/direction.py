"""The gravity ("up") direction of a hold from its raw mean, without a calibration."""

from __future__ import annotations

import numpy as np

from imucal_cli.design.poses import unit

ADC_WORDS = (8, 10, 12, 14, 16, 18, 20, 24, 32)
"""Standard ADC word lengths, bits (for the mid-scale of an unsigned ADC)."""


def _adc_mid_scale(data_min: float, data_max: float, mean: np.ndarray) -> float | None:
    """Mid-scale of an unsigned ADC, or None when the data look signed (see
    :func:`estimate_direction`)."""
    if data_min < 0:
        return None
    for bits in ADC_WORDS:
        if data_max <= 2**bits - 1:
            if np.all(mean >= 2 ** (bits - 2)):
                return float(2 ** (bits - 1))
            return None
    return None


def estimate_direction(
    mean: np.ndarray,
    units: str | None,
    *,
    nominal_bias=None,
    nominal_scale=None,
    data_min: float | None = None,
    data_max: float | None = None,
) -> np.ndarray | None:
    """Unit gravity ("up") direction of a hold from its raw mean, without a calibration.

    ``up = unit(M @ (mean - b))``: the raw mean minus a nominal zero-g offset ``b``, mapped by a
    nominal matrix ``M`` onto the fixture axes.  The offset and scale errors of a MEMS part
    (a few % and tens of mg) tilt this direction by a few degrees at most, far less than the
    45 degrees between the poses of a plan, which is all the matching needs.

    - ``b`` is ``nominal_bias`` when given (one number or one per channel).  Otherwise 0 for
      ``g``, ``m/s^2`` and signed ``counts``; for ``counts`` from an unsigned ADC, mid-scale
      ``2^(bits-1)``: the data are taken as unsigned when every sample seen so far is >= 0
      (``data_min``) and every channel's mean is above a quarter of the smallest standard word
      that holds ``data_max`` (a signed part lying flat reads about 0 on two axes).  For ``V``
      (analog parts sit at an unknown mid-supply) no default exists: None is returned.
    - ``M`` is ``nominal_scale``: None (identity; needs 3 channels), one number or one per
      channel (a diagonal), or a 3 x n matrix (redundant units: n channels onto 3 axes).

    Parameters
    ----------
    mean : ndarray, shape (n,)
        Mean raw accel of the hold.
    units : str or None
        Raw accel units (``counts``, ``V``, ``g``, ``m/s^2``).
    nominal_bias, nominal_scale : optional
        See above.
    data_min, data_max : float, optional
        Smallest and largest raw accel value seen so far (default: those of ``mean``).

    Returns
    -------
    ndarray, shape (3,), or None
        None when the direction cannot be estimated (``V`` without a nominal bias, more than
        3 channels without a matrix, a zero vector).
    """
    m = np.asarray(mean, dtype=float).reshape(-1)
    n = len(m)
    if nominal_bias is not None:
        b = np.broadcast_to(np.asarray(nominal_bias, float), (n,))
    elif units == "V":
        return None
    elif units in (None, "counts"):
        lo = float(m.min()) if data_min is None else float(data_min)
        hi = float(m.max()) if data_max is None else float(data_max)
        mid = _adc_mid_scale(lo, hi, m)
        b = np.zeros(n) if mid is None else np.full(n, mid)
    else:
        b = np.zeros(n)
    x = m - b
    if nominal_scale is None:
        if n != 3:
            return None
        v = x
    else:
        s = np.asarray(nominal_scale, dtype=float)
        if s.ndim == 2:
            if s.shape != (3, n):
                return None
            v = s @ x
        else:
            if n != 3:
                return None
            v = x / np.broadcast_to(s, (3,))
    if not np.all(np.isfinite(v)) or np.linalg.norm(v) == 0:
        return None
    return unit(v[None, :])[0]
