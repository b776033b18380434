"""Geometry of a set of static poses: how many distinct gravity directions, how well they cover
the sphere, and whether they can determine an accelerometer model.

All functions take unit direction vectors, shape (N, 3), in any one frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np


def unit(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` scaled to unit length. Shape (N, 3) -> (N, 3)."""
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def angle_deg(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle between unit vectors (row-wise), degrees, numerically safe near 0 and 180."""
    u, v = np.asarray(u, float), np.asarray(v, float)
    cross = np.linalg.norm(np.cross(u, v), axis=-1)
    dot = np.sum(u * v, axis=-1)
    return np.degrees(np.arctan2(cross, dot))


def count_distinct(directions: np.ndarray, min_separation_deg: float = 10.0) -> int:
    """Number of directions that differ from every other counted one by more than
    ``min_separation_deg`` (greedy clustering, in the given order)."""
    u = unit(directions)
    cos_min = np.cos(np.radians(min_separation_deg))
    near = (u @ u.T) >= cos_min  # near[i, j]: j within the separation of i
    kept = np.zeros(len(u), bool)
    for i in range(len(u)):  # greedy in order: i counts unless a counted one is near it
        kept[i] = not np.any(near[i, :i] & kept[:i])
    return int(kept.sum())


def spread_deg(directions: np.ndarray) -> float:
    """Largest angle between any direction and the mean direction, degrees.

    A small spread (every pose within a few tens of degrees of one direction) cannot
    separate bias from scale.
    """
    u = unit(directions)
    m = u.sum(axis=0)
    if np.linalg.norm(m) < 1e-9:
        return 180.0
    return float(np.max(angle_deg(u, unit(m)[None, :])))


@lru_cache(maxsize=4)
def _sphere_grid(n: int) -> np.ndarray:
    """Fibonacci lattice: n nearly uniform unit vectors."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z * z)
    phi = np.pi * (1 + 5**0.5) * i
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


@dataclass(frozen=True)
class Coverage:
    """How the gravity directions of a session cover the sphere.

    Attributes
    ----------
    fraction : float
        Fraction of the sphere's area within ``cap_deg`` of some pose direction (0..1).
    largest_gap_deg : float
        Angle from the direction farthest from every pose to its nearest pose, degrees.
    weakest_direction : ndarray, shape (3,)
        The direction least represented by the poses (smallest eigenvalue of their scatter
        ``sum u u^T``); capture poses along or against it to improve the design.
    cap_deg : float
        The cap half-angle used for ``fraction``.
    """

    fraction: float
    largest_gap_deg: float
    weakest_direction: np.ndarray
    cap_deg: float


def coverage(directions: np.ndarray, cap_deg: float = 45.0, grid: int = 2000) -> Coverage:
    """Coverage of the sphere of gravity directions by a set of poses."""
    u = unit(directions)
    g = _sphere_grid(grid)
    nearest = np.max(g @ u.T, axis=1).clip(-1, 1)
    fraction = float(np.mean(nearest >= np.cos(np.radians(cap_deg))))
    largest_gap = float(np.degrees(np.arccos(nearest.min())))
    w, V = np.linalg.eigh(u.T @ u)
    weakest = V[:, 0]
    return Coverage(fraction, largest_gap, weakest, cap_deg)


def describe_direction(v: np.ndarray) -> str:
    """Human words for a direction: the nearest face or edge, e.g. ``"+X"`` or ``"+X/-Z"``."""
    v = unit(np.asarray(v, float)[None, :])[0]
    order = np.argsort(-np.abs(v))
    names = "XYZ"
    first = f"{'+' if v[order[0]] >= 0 else '-'}{names[order[0]]}"
    if abs(v[order[1]]) > 0.5 * abs(v[order[0]]):
        return f"{first}/{'+' if v[order[1]] >= 0 else '-'}{names[order[1]]}"
    return first
