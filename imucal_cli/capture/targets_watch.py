"""Unattended capture with targets (``imucal capture --no-prompt --until``, issue 27).

:class:`TargetWatcher` looks at the recording while it grows: whenever the motion shows a new
still period (:func:`~imucal_cli.capture.unattended.segment_recording`, as the recording will
be segmented at the end), it refits the recording so far (the ``refit`` callable: the
calibrate step) and compares each target's std with it; the capture stops once every target
is met.  Nobody is told what to do next (no keyboard, maybe no one at the bench): the status
goes to the status lines.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from imucal_cli.formats.session import Segment, Session, utc_now_iso
from imucal_cli.formats.targets import Targets, TargetStatus, brief, measure

__all__ = ["TargetWatcher"]


class TargetWatcher:
    """Refits the recording after each new still period; :meth:`update` is True once every
    target is met.

    Parameters
    ----------
    targets : Targets
    refit : callable
        ``refit(session)`` -> an object with ``calibration`` and ``notes`` (the guided
        capture's :class:`~imucal_cli.capture.guided.Refit`).
    segment : callable
        ``segment(time, accel, gyro)`` -> the segments: ``(kind, start, stop, attrs)``, the
        attributes of the plan step each matches (``{}`` when none).
    units : tuple of str or None
        The raw accel and gyro units.
    gravity : float
        m/s^2.
    """

    def __init__(self, targets: Targets, refit: Callable, segment: Callable, *,
                 units: tuple[str | None, str | None], gravity: float) -> None:  # fmt: skip
        self.targets, self.refit, self.segment = targets, refit, segment
        self.units, self.gravity = units, gravity
        self.statuses: list[TargetStatus] = measure(None, targets)
        self.n_still = 0
        self.refits = 0

    @property
    def met(self) -> bool:
        return all(s.met for s in self.statuses)

    def update(self, time: np.ndarray, accel: np.ndarray | None, gyro: np.ndarray | None,
               say: Callable[[str], None]) -> bool:  # fmt: skip
        """Refit when the recording shows a new still period; True once every target is met."""
        if accel is None or len(time) < 10:
            return False
        spans = self.segment(time, accel, gyro)
        n_still = sum(1 for kind, *_ in spans if kind == "static")
        if n_still <= self.n_still:
            return False
        self.n_still = n_still
        segments = [Segment(f"{k:04d}", kind, int(a), int(b), **attrs)
                    for k, (kind, a, b, attrs) in enumerate(spans)]  # fmt: skip
        rate = (len(time) - 1) / float(time[-1] - time[0]) if time[-1] > time[0] else None
        session = Session(time=time.copy(), accel=accel.copy(),
                          gyro=None if gyro is None else gyro.copy(), temperature=None,
                          segments=segments, created=utc_now_iso(), source="capture (so far)",
                          sample_rate_hz=rate, gravity=self.gravity, accel_units=self.units[0],
                          gyro_units=self.units[1])  # fmt: skip
        result = self.refit(session)
        self.refits += 1
        self.statuses = measure(result.calibration, self.targets, result.notes)
        say(f"{n_still} still periods; std/target: {brief(self.statuses)}")
        return self.met
