"""The guided capture's magnetometer: which field directions the unit has shown it, live, and
where to point it next.  No terminal: :class:`MagCoverage` takes the magnetometer rows of each
block and answers with figures, a map and words.

Readings sit on a sphere only once the hard iron is taken out, so the centre is fitted as the
readings come (a sphere fit, linear in centre and radius; refitted every
:data:`REFIT_EVERY` new readings); until the readings span enough of the sphere for that fit
(:data:`MIN_SPAN`), the coverage is not told.  Coverage is that of the calibration's own
figures (:mod:`imucal_cli.design.sphere_quality`): 100 regions of equal area, a region counts
once it holds 3 readings.  The next direction is the centre of the emptiest neighbourhood
nearest to where the field is now, said as the side of the unit (in the magnetometer's axes)
to point towards the field.
"""

from __future__ import annotations

import numpy as np

from imucal_cli.design.poses import describe_direction
from imucal_cli.design.sphere_quality import (
    gaps_pct,
    region_centres,
    region_index,
    suggest_direction,
)

__all__ = ["MAX_POINTS", "MIN_SPAN", "REFIT_EVERY", "MagCoverage"]

REFIT_EVERY = 50
"""New distinct readings between two fits of the centre."""
MIN_SPAN = 0.4
"""The centre is trusted once the readings' thinnest principal spread is this fraction of
their widest (a cap of about 70 degrees or more)."""
MAX_POINTS = 20_000
"""Readings kept for the fit (every other one is dropped beyond)."""


def _sphere_fit(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius of ``|m - c| = r`` by linear least squares (``|m|^2 = 2 c.m + d``)."""
    mean = points.mean(axis=0)
    p = points - mean
    A = np.column_stack([2 * p, np.ones(len(p))])
    sol, *_ = np.linalg.lstsq(A, np.sum(p * p, axis=1), rcond=None)
    c = sol[:3]
    r2 = sol[3] + c @ c
    return mean + c, float(np.sqrt(r2)) if r2 > 0 else 0.0


class MagCoverage:
    """Live coverage of the field directions a magnetometer has seen.

    Parameters
    ----------
    goal : float
        Fraction of the 100 regions (3 readings each) that makes the coverage good.
    """

    def __init__(self, goal: float = 0.9) -> None:
        self.goal = float(goal)
        self.points = np.empty((0, 3))
        self._last: np.ndarray | None = None
        self._since_fit = 0
        self.centre: np.ndarray | None = None
        self.radius = 0.0
        self.counts = np.zeros(100, dtype=int)
        self.current: np.ndarray | None = None

    # ------------------------------------------------------------------------ input
    def update(self, mag: np.ndarray | None) -> None:
        """The magnetometer rows of one block (raw units); repeats and NaN rows are skipped."""
        if mag is None or len(mag) == 0:
            return
        m = np.asarray(mag, float)
        m = m[np.isfinite(m).all(axis=1)]
        if not len(m):
            return
        before = np.vstack([self._last if self._last is not None else np.full(3, np.nan),
                            m[:-1]])  # fmt: skip
        keep = np.any(m != before, axis=1)
        self._last = m[-1]
        new = m[keep]
        if not len(new):
            return
        self.points = np.concatenate([self.points, new])
        if len(self.points) > MAX_POINTS:
            self.points = self.points[::2]
        self._since_fit += len(new)
        if self.centre is None or self._since_fit >= REFIT_EVERY:
            self._refit()
        elif self.centre is not None:
            np.add.at(self.counts, region_index(new - self.centre), 1)
        if self.centre is not None:
            self.current = m[-1] - self.centre

    def _refit(self) -> None:
        self._since_fit = 0
        if len(self.points) < 20:
            return
        spread = np.sqrt(np.clip(np.linalg.eigvalsh(np.cov(self.points, rowvar=False)), 0, None))
        if spread[-1] == 0 or spread[0] < MIN_SPAN * spread[-1]:
            return
        self.centre, self.radius = _sphere_fit(self.points)
        self.counts = np.bincount(region_index(self.points - self.centre), minlength=100)

    # ------------------------------------------------------------------------ output
    @property
    def ready(self) -> bool:
        """Whether the centre is known (the readings span enough of the sphere)."""
        return self.centre is not None

    @property
    def fraction(self) -> float:
        """Fraction of the regions holding at least 3 readings."""
        return float(np.mean(self.counts >= 3)) if self.ready else 0.0

    @property
    def done(self) -> bool:
        return self.ready and self.fraction >= self.goal

    def next_direction(self) -> np.ndarray | None:
        """Unit direction (magnetometer axes) the field should come from next, or None."""
        if not self.ready:
            return None
        return suggest_direction(self.counts, self.current)

    def status(self) -> str:
        """One line: how much is covered and what to do."""
        if not self.ready:
            return (
                f"magnetometer: learning its offset ({len(self.points)} readings): turn the unit "
                "slowly about two or more axes"
            )
        text = (
            f"magnetometer: {100 * self.fraction:.0f}% of the field directions seen "
            f"(gaps {gaps_pct(self.counts):.0f}%)"
        )
        target = self.next_direction()
        if self.done or target is None:
            return text + ": enough"
        return text + "; " + self.hint(target)

    def hint(self, target: np.ndarray) -> str:
        """Words for pointing the unit so that the field comes along ``target``."""
        side = describe_direction(target)
        text = f"next: point the unit's {side} side (magnetometer axes) towards north and down"
        if self.current is not None and np.linalg.norm(self.current) > 0:
            cur = self.current / np.linalg.norm(self.current)
            angle = float(np.degrees(np.arccos(np.clip(cur @ target, -1.0, 1.0))))
            text += f", about {angle:.0f} deg from now"
        return text

    def map_directions(self) -> list[list[float]]:
        """One direction per covered region (3 readings or more), for a coverage map."""
        if not self.ready:
            return []
        return region_centres()[self.counts >= 3].tolist()
