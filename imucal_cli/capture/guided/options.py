"""The guided capture's options, and what its state machine tells the screen.

:class:`GuidedOptions` are a guided capture's settings; :class:`Message` (a line for the
person) and :class:`Prompt` (what to do now) are what :class:`~.state.GuidedState` hands the
screen (:mod:`.screen`).
"""

from __future__ import annotations

from dataclasses import dataclass

from imucal_cli.design.stillness import DEFAULT_ALPHA, StillnessDetector
from imucal_cli.plans import Plan

#: The hold a guided capture takes of each pose unless told (``imucal capture --hold``), s;
#: the stillness detector's default false-alarm rate is made for it.
DEFAULT_HOLD_S = 2.0


@dataclass(frozen=True)
class GuidedOptions:
    """The options of a guided capture (:func:`~imucal_cli.capture.guided.run_guided`).

    Attributes
    ----------
    hold_s : float
        Length of each static hold, s; a step's own ``hold_s`` (the ``still:MINUTES`` plan)
        takes precedence.
    min_separation_deg : float
        A pose closer than this to one already taken is refused (unless the plan itself asks
        for that direction again).
    nominal_bias, nominal_scale : optional
        How a raw accel mean becomes a gravity direction
        (:func:`~imucal_cli.capture.guided.direction.estimate_direction`).
    refresh_hz : float
        Live display refresh rate (terminal only).
    match_tolerance_deg : float
        A hold is matched to the nearest pending static step whose ``up`` is within this angle.
    accel_units, gyro_units : str, optional
        Raw units.
    gyro_scale : float, optional
        Raw gyro units per rad/s, to show measured turn angles for ``counts``/``V``.
    detector : StillnessDetector, optional
        Default: 0.25 s windows, false alarm 1e-4 per window, less for a plan with longer
        holds (:func:`detector_for`).
    warn_after_s : float
        A hold interrupted by motion after this long is reported ("moved during the hold");
        shorter still moments are handling.
    pre_still_s, settle_s : float
        A turn needs the unit still this long before it, and counts as ended when the unit is
        still again this long.
    axis_tolerance_deg : float
        Warn when a turn's measured axis is further than this from the plan's.
    tick_s : float
        Passed to ``recorder.blocks``.
    mag_goal : float
        With a magnetometer in the stream: the fraction of the field directions (100 equal
        areas, :mod:`.magnetic`) it must have seen; after the plan's last step the capture goes
        on, showing where to point the unit, until it has (or ``q``).
    """

    hold_s: float = DEFAULT_HOLD_S
    min_separation_deg: float = 15.0
    nominal_bias: object = None
    nominal_scale: object = None
    refresh_hz: float = 10.0
    match_tolerance_deg: float = 20.0
    accel_units: str | None = None
    gyro_units: str | None = None
    gyro_scale: float | None = None
    detector: StillnessDetector | None = None
    warn_after_s: float = 0.5
    pre_still_s: float = 0.5
    settle_s: float = 0.5
    axis_tolerance_deg: float = 30.0
    tick_s: float = 0.1
    mag_goal: float = 0.9

    def __post_init__(self) -> None:
        for name in _FLOATS:  # given as ints or numpy scalars: plain floats from here on
            object.__setattr__(self, name, float(getattr(self, name)))
        object.__setattr__(self, "refresh_hz", max(self.refresh_hz, 0.1))
        if not self.hold_s > 0:
            raise ValueError(f"hold_s must be > 0, got {self.hold_s!r}")


_FLOATS = ("hold_s", "min_separation_deg", "refresh_hz", "match_tolerance_deg", "warn_after_s",
           "pre_still_s", "settle_s", "axis_tolerance_deg", "tick_s", "mag_goal")  # fmt: skip


def detector_for(plan: Plan) -> StillnessDetector:
    """The stillness detector of a guided capture of ``plan``.  A false alarm restarts a hold
    with a probability of about ``alpha`` times the windows it spans: a plan with a longer
    hold (``warmup:MINUTES``, ``still:MINUTES``) tests each window at a proportionally smaller
    ``alpha``, so that its hold restarts no more often than a 2 s one (the served warm-up of
    seed 0 restarted twice in its 2 minutes at ``DEFAULT_ALPHA``; a real motion is still far
    above the threshold, 1.22 -> 1.28 x the noise for 2 minutes)."""
    longest = max([DEFAULT_HOLD_S, *(s.hold_s or 0.0 for s in plan.static_steps)])
    return StillnessDetector(alpha=DEFAULT_ALPHA * DEFAULT_HOLD_S / longest)


def duration_text(seconds: float) -> str:
    """``12 s``, ``2.5 min``."""
    return f"{seconds:g} s" if seconds < 120 else f"{seconds / 60:.3g} min"


@dataclass(frozen=True)
class Message:
    """One line for the person: ``text`` and a rich ``style`` (``""`` for plain)."""

    text: str
    style: str = ""


@dataclass(frozen=True)
class Prompt:
    """What the person should do now (drawn by the screen).

    Attributes
    ----------
    step : int or None
        The current step (0-based), None when every step is done or skipped.
    n_steps : int
        Steps in the plan.
    phase : str
        ``"wait"`` (waiting for the unit to be still), ``"hold"`` (holding), ``"move"`` (turn
        the unit to the next pose), ``"pre"``/``"turning"`` (a rotation step), ``"mag"``
        (every step done, the magnetometer still needs field directions), ``"check"`` (with
        targets: met on a refit without the last steps, refitted with them), ``"done"``.
    text : str
        The instruction line (a static step says how long to hold).
    hold_s : float
        The current step's hold, s.
    held_s : float
        Time held so far, s (``phase == "hold"``); ``hold_s - held_s`` is the countdown.
    serial : int
        Changes whenever the instruction must be told again (a new step, a redo).
    """

    step: int | None
    n_steps: int
    phase: str
    text: str
    hold_s: float
    held_s: float
    serial: int
