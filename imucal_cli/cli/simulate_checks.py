"""The numeric options of `imucal simulate`, each checked against a physical bound before
anything is simulated, served or written.

A value that is not finite, negative where it means nothing, or beyond what any real MEMS part
(or a serial line) shows is refused with one line naming the option, the range and its unit
(exit 2).  The simulators keep their own checks (they are called from Python too); this table
only makes sure the command says what is wrong before it starts, served or written, in the
words and units of ``--help``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from imucal_cli.errors import InputError
from imucal_cli.simulate.rotations import MAX_PEAK_RATE_DPS

__all__ = ["BOUNDS", "Bound", "check_numbers"]

DAY_S = 86_400.0
"""A day, s: the longest hold, still period, move or tumble of a session."""

WEEK_S = 7 * DAY_S
"""A week, s: the longest --serve time (--duration, --stall-after, --vanish-after)."""


@dataclass(frozen=True)
class Bound:
    """The range of one option: ``low < x`` (``low <= x`` with ``closed``) and ``x <= high``.

    Attributes
    ----------
    flag : str
        The option as ``--help`` names it.
    unit : str
        Its unit, as ``--help`` gives it.
    low, high : float
        The range, in ``unit``.
    closed : bool
        Whether ``low`` itself is allowed (a noise of 0), else only values above it.
    why : str
        What the upper bound stands for, said after it ("about 1 g").
    """

    flag: str
    unit: str
    low: float
    high: float
    closed: bool = True
    why: str = ""

    def check(self, value: float) -> None:
        """Raise :class:`InputError` unless ``value`` is a finite number in the range."""
        x = float(value)
        above = x >= self.low if self.closed else x > self.low
        if math.isfinite(x) and above and x <= self.high:
            return
        low, high = _number(self.low), _number(self.high)
        span = f"from {low} to {high}" if self.closed else f"above {low} and at most {high}"
        why = f" ({self.why})" if self.why else ""
        raise InputError(f"{self.flag} must be a finite number {span} {self.unit}{why}, "
                         f"got {value:g}")  # fmt: skip


def _number(x: float) -> str:
    """``x`` as ``--help`` would print it: whole numbers in full (12000000), else ``:g``."""
    return f"{x:.0f}" if x == int(x) and abs(x) < 1e12 else f"{x:g}"


BOUNDS: dict[str, Bound] = {
    "rate": Bound("--rate", "Hz", 0.0, 100_000.0, closed=False,
                  why="no MEMS IMU samples faster than 100 kHz"),
    "hold": Bound("--hold", "s", 0.0, DAY_S, closed=False, why="a day"),
    "accel_noise": Bound("--accel-noise", "m/s^2", 0.0, 10.0,
                         why="about 1 g per sample; MEMS parts are below 0.5 m/s^2"),
    "jitter_deg": Bound("--jitter-deg", "deg", 0.0, 45.0),
    "peak_rate": Bound("--peak-rate", "deg/s", 0.0, MAX_PEAK_RATE_DPS, closed=False),
    "still": Bound("--still", "s", 0.0, DAY_S, closed=False, why="a day"),
    "sigma_counts": Bound("--sigma-counts", "counts", 0.0, 100.0,
                          why="5 % of the 2047-count ADC range; the paper used 0.7 and 1.5"),
    "g_sensitivity": Bound("--g-sensitivity", "rad/s per m/s^2", 0.0, 0.1, closed=False),
    "field_ut": Bound("--field-uT", "uT", 1.0, 1000.0, why="Earth: 20 to 70"),
    "inclination": Bound("--inclination-deg", "deg", -90.0, 90.0),
    "mag_noise": Bound("--mag-noise", "uT", 0.0, 100.0,
                       why="twice the Earth's field; magnetometers are below 2 uT"),
    "tumble": Bound("--tumble", "s", 0.0, DAY_S, why="a day"),
    "move": Bound("--move", "s", 0.0, DAY_S, closed=False, why="a day"),
    "duration": Bound("--duration", "s", 0.0, WEEK_S, closed=False, why="a week"),
    "stall_after": Bound("--stall-after", "s", 0.0, WEEK_S, why="a week"),
    "vanish_after": Bound("--vanish-after", "s", 0.0, WEEK_S, why="a week"),
    "imu_rotation": Bound("--imu-rotation", "deg", 0.0, 180.0),
    "imu_offset": Bound("--imu-offset", "ms", 0.0, 1000.0),
    "baud": Bound("--baud", "baud", 0.0, 12_000_000.0, closed=False,
                  why="the fastest USB serial bridges"),
    "malformed_every": Bound("--malformed-every", "lines", 1.0, 1e9),
}
"""Every numeric option of ``imucal simulate`` by parameter name, but the integers with their
own range (--seed, --imus, --mountings, --orientations, --samples, --rotations-per-axis,
--serve-imu) and --clock-ppm (within +-50000 ppm, checked where it is parsed)."""


def check_numbers(values: dict[str, float | None]) -> None:
    """Check each option of ``values`` (parameter name -> value; None: not given) that
    :data:`BOUNDS` names; the first one out of its range raises :class:`InputError`."""
    for name, value in values.items():
        bound = BOUNDS.get(name)
        if bound is not None and value is not None:
            bound.check(value)
