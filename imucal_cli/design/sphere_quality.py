"""How well calibrated magnetometer readings cover and fit the sphere: MotionCal-style figures.

The sphere is cut into 100 regions of equal area: a polar cap, 15 regions, 34 regions in each
hemisphere (equal-area bands: the cap holds 1/100 of the area, down to ``|z| = 0.98``; the next
band to ``|z| = 0.68``; the third to the equator).  From them:

- **gaps** (%): each empty region counts 1, a region with one reading 0.2, with two 0.01
  (MotionCal's weights): how much of the sphere the motion missed;
- **variance** (%): standard deviation of the calibrated magnitude over its mean;
- **wobble** (%): the vector mean, over the occupied regions, of each region's radial deviation
  ``(|c_r| - R) c_r / |c_r|`` (``c_r`` the mean of its readings, ``R`` the mean magnitude),
  relative to ``R``: a sphere that is off centre or lopsided;
- **fit error** (%): RMS of the held-out magnitude residual over the field (computed by the
  caller: readings predicted by a fit that did not see them).

MotionCal's goals are gaps < 15 %, variance < 4.5 %, wobble < 4 %, fit error < 5 %.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

__all__ = [
    "N_REGIONS",
    "SphereQuality",
    "gaps_pct",
    "region_centres",
    "region_counts",
    "region_index",
    "sphere_quality",
    "suggest_direction",
]

N_REGIONS = 100
# Bands from the +z pole: (z above which the band starts, regions in the band).
_BANDS = ((0.98, 1), (0.68, 15), (0.0, 34))


def region_index(directions: np.ndarray) -> np.ndarray:
    """Region (0..99) of each direction (N, 3); need not be unit length (zero rows: region 0)."""
    v = np.asarray(directions, float).reshape(-1, 3)
    norm = np.linalg.norm(v, axis=1)
    z = np.divide(v[:, 2], norm, out=np.ones(len(v)), where=norm > 0)
    lon = np.arctan2(v[:, 1], v[:, 0]) % (2 * np.pi)
    north = z >= 0
    az = np.abs(z)
    start = 0
    first = np.empty(len(v), dtype=int)
    count = np.empty(len(v), dtype=int)
    assigned = np.zeros(len(v), bool)
    for z_min, n in _BANDS:
        inside = ~assigned & (az > z_min) if z_min > 0 else ~assigned
        first[inside], count[inside] = start, n
        assigned |= inside
        start += n
    k = np.minimum((lon * count / (2 * np.pi)).astype(int), count - 1)
    return np.where(north, first + k, N_REGIONS - 1 - (first + k))


@lru_cache(maxsize=1)
def region_centres() -> np.ndarray:
    """Unit vector at the centre of each region, shape (100, 3)."""
    centres = []
    top = 1.0
    for z_min, n in _BANDS:
        z_mid = (top + z_min) / 2  # equal area: the middle z halves the band's area
        r = np.sqrt(1 - z_mid * z_mid)
        for k in range(n):
            lon = (k + 0.5) * 2 * np.pi / n
            centres.append([r * np.cos(lon), r * np.sin(lon), z_mid] if n > 1 else [0, 0, 1.0])
        top = z_min
    north = np.array(centres)
    south = north[::-1] * np.array([1.0, 1.0, -1.0])
    # region N-1-i of the south mirrors region i of the north (same longitude sector)
    return np.concatenate([north, south])


def region_counts(directions: np.ndarray) -> np.ndarray:
    """Readings per region, shape (100,)."""
    return np.bincount(region_index(directions), minlength=N_REGIONS)


def gaps_pct(counts: np.ndarray) -> float:
    """MotionCal's gap figure from the readings per region: 1 per empty region, 0.2 for one
    reading, 0.01 for two."""
    counts = np.asarray(counts)
    return float(np.sum(np.select([counts == 0, counts == 1, counts == 2], [1.0, 0.2, 0.01], 0.0)))


@dataclass(frozen=True)
class SphereQuality:
    """Coverage and fit figures of calibrated readings, percent (see the module notes).

    Attributes
    ----------
    gaps_pct, variance_pct, wobble_pct : float
    covered_fraction : float
        Fraction of the 100 regions holding at least 3 readings.
    counts : ndarray, shape (100,)
    """

    gaps_pct: float
    variance_pct: float
    wobble_pct: float
    covered_fraction: float
    counts: np.ndarray


def sphere_quality(calibrated: np.ndarray) -> SphereQuality:
    """Gaps, variance and wobble of calibrated readings (N, 3), any units."""
    h = np.asarray(calibrated, float).reshape(-1, 3)
    mag = np.linalg.norm(h, axis=1)
    regions = region_index(h)
    counts = np.bincount(regions, minlength=N_REGIONS)
    R = float(mag.mean()) if len(mag) else float("nan")
    variance = 100.0 * float(mag.std() / R) if len(mag) else float("nan")
    occupied = np.flatnonzero(counts)
    if len(occupied) and R > 0:
        sums = np.zeros((N_REGIONS, 3))
        np.add.at(sums, regions, h)
        c = sums[occupied] / counts[occupied, None]
        cn = np.linalg.norm(c, axis=1)
        radial = (cn - R)[:, None] * c / np.where(cn > 0, cn, 1.0)[:, None]
        wobble = 100.0 * float(np.linalg.norm(radial.mean(axis=0)) / R)
    else:
        wobble = float("nan")
    return SphereQuality(
        gaps_pct=gaps_pct(counts),
        variance_pct=variance,
        wobble_pct=wobble,
        covered_fraction=float(np.mean(counts >= 3)),
        counts=counts,
    )


def suggest_direction(counts: np.ndarray, current: np.ndarray | None = None) -> np.ndarray | None:
    """Where to point the field next: the centre of the emptiest neighbourhood of regions.

    Each region scores how many of its close neighbours (within 40 degrees) are empty; among
    the empty regions with the best score, the one nearest ``current`` (a direction, when
    given) wins, so that the person turns the unit as little as possible.  None when no region
    is empty.
    """
    counts = np.asarray(counts)
    empty = counts < 3
    if not empty.any():
        return None
    centres = region_centres()
    near = centres @ centres.T > np.cos(np.radians(40.0))
    score = near[:, empty].sum(axis=1).astype(float)
    score[~empty] = -1.0
    best = score >= score.max() - 1.0
    if current is not None and np.linalg.norm(current) > 0:
        cur = np.asarray(current, float) / np.linalg.norm(current)
        closeness = centres @ cur
        return centres[np.flatnonzero(best)[np.argmax(closeness[best])]]
    return centres[int(np.argmax(score))]
