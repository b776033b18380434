"""A text map of measured gravity directions on the sphere (two equal-area hemispheres)."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np


def coverage_map(
    directions: list[list[float]], radius_cols: int = 11, radius_rows: int = 5,
    marks: list | tuple = (),
) -> list[str]:
    """Text map of unit directions on the sphere: two hemispheres side by side.

    Each hemisphere is an azimuthal equal-area projection about its pole (+Z left, -Z right),
    both drawn as seen from +Z (x to the right, y up), so an empty area of the disc is an
    uncovered area of the sphere.  ``.`` is the disc, ``+`` the pole, ``o`` one pose, a digit
    several poses in one cell.

    Parameters
    ----------
    directions
        Unit vectors (normalised here); z >= 0 goes to the +Z map.
    radius_cols, radius_rows
        Disc radius in character columns and rows (characters are about twice as tall as wide).
    marks
        More unit directions, drawn as ``*`` over the poses (the guide's next pose).

    Returns
    -------
    list of str
        Lines of text, the first a caption.
    """
    upper, lower = [], []
    marked_upper, marked_lower = [], []
    for d in directions:
        norm = np.linalg.norm(d)
        if not norm > 0:
            continue
        x, y, z = np.asarray(d, dtype=float) / norm
        # Equal-area: distance from the pole r = 2 sin(polar angle / 2), here scaled to 1 at
        # the equator, i.e. r = sqrt(1 - |z|).
        r = math.sqrt(max(0.0, 1.0 - abs(z)))
        rho = math.hypot(x, y)
        point = (r * x / rho, r * y / rho) if rho > 0 else (0.0, 0.0)
        (upper if z >= 0 else lower).append(point)
    for d in marks:
        point, z = _projected(d)
        if point is not None:
            (marked_upper if z >= 0 else marked_lower).append(point)
    left = _hemisphere(upper, radius_cols, radius_rows, marked_upper)
    right = _hemisphere(lower, radius_cols, radius_rows, marked_lower)
    width = 2 * radius_cols + 1
    gap = " " * 4
    caption = f"{'+Z side (z >= 0)':^{width}}{gap}{'-Z side (z < 0)':^{width}}"
    rows = [f"{a}{gap}{b}" for a, b in zip(left, right, strict=True)]
    note = f"{'x ->, y up, both seen from +Z':^{2 * width + len(gap)}}"
    return [caption, *rows, note]


def _projected(d) -> tuple[tuple[float, float] | None, float]:
    """A direction's point on its hemisphere's disc (as :func:`coverage_map` draws it)."""
    norm = np.linalg.norm(d)
    if not norm > 0:
        return None, 0.0
    x, y, z = np.asarray(d, dtype=float) / norm
    r = math.sqrt(max(0.0, 1.0 - abs(z)))
    rho = math.hypot(x, y)
    return ((r * x / rho, r * y / rho) if rho > 0 else (0.0, 0.0)), float(z)


def _hemisphere(points: list[tuple[float, float]], radius_cols: int, radius_rows: int,
                marks: list[tuple[float, float]] = ()) -> list[str]:  # fmt: skip
    """One disc of the coverage map with the projected points marked."""
    height, width = 2 * radius_rows + 1, 2 * radius_cols + 1
    grid = [[" "] * width for _ in range(height)]
    half_u, half_v = 0.5 / radius_cols, 0.5 / radius_rows
    for i in range(height):
        for j in range(width):
            # A cell belongs to the disc when any of it does, so every projected point's cell
            # is drawn inside.
            u = max(abs(j - radius_cols) / radius_cols - half_u, 0.0)
            v = max(abs(radius_rows - i) / radius_rows - half_v, 0.0)
            if u * u + v * v <= 1.0:
                grid[i][j] = "."
    grid[radius_rows][radius_cols] = "+"
    counts = Counter(
        (round(radius_rows - radius_rows * py), round(radius_cols + radius_cols * px))
        for px, py in points
    )
    for (i, j), n in counts.items():
        grid[i][j] = "o" if n == 1 else (str(n) if n < 10 else "#")
    for px, py in marks:
        grid[round(radius_rows - radius_rows * py)][round(radius_cols + radius_cols * px)] = "*"
    return ["".join(row) for row in grid]


# Number formatting
