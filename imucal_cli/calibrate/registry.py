"""One solver interface and one registry for every sensor (issue 25.3).

An :class:`Estimator` says what it needs, what a design lets it determine (:meth:`assess`: the
bound it would reach, or a :class:`Refusal` with the reason and what to capture) and fits.
:func:`choose` is the one choice of every sensor: the config's solver, or with ``"auto"`` the
best assessment of the session's design (never the output of a fit).

The rule of ``"auto"``: the estimators a design determines, in the order of their
:attr:`Determined.tier` (the kind of design each was made for first, then the order of
registration, most accurate first, issue 10.7); a later one replaces the first only when both
predict a bound on the same parameters and the later one's is measurably smaller: the mean
ratio of their variances below :data:`WORTH` (issue 9.1: the labels are used when they make
the fit measurably more precise than gravity magnitude alone).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from imucal_cli.model.parts import By, Choice

#: A later estimator replaces an earlier one only when the mean ratio of their predicted
#: variances (the key parameters, at the design) is below this.
WORTH = 0.8

SENSORS = ("accel", "gyro", "mag", "temperature", "clock")


@dataclass(frozen=True)
class Needs:
    """What an estimator needs of a session (for the user's documentation and refusals).

    Attributes
    ----------
    channels : tuple of (int, int or None)
        The raw channels it calibrates: at least ``channels[0]``, at most ``channels[1]``
        (None: no limit).
    labels : bool
        Labelled poses (``up``) or turns (``axis``, ``angle_deg``).
    turns : bool
        Rotation segments between still periods.
    accel : bool
        The accelerometer calibrated (in the same run, or ``--accel CAL.json``).
    """

    channels: tuple[int, int | None] = (3, 3)
    labels: bool = False
    turns: bool = False
    accel: bool = False


@dataclass(frozen=True)
class Bound:
    """The precision a design lets an estimator reach: the predicted variance (Cramer-Rao
    bound at the design) of its key parameters.

    Attributes
    ----------
    variance : ndarray, shape (k,)
        Predicted variance of each key parameter.
    of : str
        What the parameters are (bounds compare only when they are of the same).
    groups : tuple of (str, slice)
        Names of parts of ``variance`` for the reason of a choice (``("the bias",
        slice(0, 3))``).
    """

    variance: np.ndarray
    of: str
    groups: tuple[tuple[str, slice], ...] = ()


@dataclass(frozen=True)
class Determined:
    """A design the estimator can calibrate, and why (words for the user).

    Attributes
    ----------
    reason : str
    bound : Bound or None
        The precision it predicts, where it can say (None: not compared).
    tier : int
        The kind of design (0: what the estimator was made for; higher: a fallback); the
        ``auto`` choice takes the lowest tier first.
    compared_with : str
        How the reason names this estimator when another is compared with it (``"gravity
        magnitude alone"``).
    """

    reason: str
    bound: Bound | None = None
    tier: int = 0
    compared_with: str = ""


@dataclass(frozen=True)
class Refusal:
    """A design the estimator cannot calibrate.

    Attributes
    ----------
    reason : str
        Why not (one sentence, no session name).
    capture : str
        What to capture (or pass) so that it can; may be empty.
    """

    reason: str
    capture: str = ""


Assessment = Determined | Refusal


class Estimator(Protocol):
    """A solver for one sensor.

    Attributes
    ----------
    name : str
        As the config names it (``[accel] solver = "gravity"``).
    sensor : str
        One of :data:`SENSORS`.
    needs : Needs
    """

    name: str
    sensor: str
    needs: Needs

    def assess(self, design: Any) -> Assessment:
        """What this estimator would determine from ``design`` (the sensor's design
        analysis), without fitting the output."""
        ...

    def fit(self, design: Any) -> Any:
        """The sensor's calibration section from ``design`` (raises the solver's errors)."""
        ...


#: Every estimator by ``(sensor, name)``, in the order of registration (most accurate first).
REGISTRY: dict[tuple[str, str], Estimator] = {}


def register(estimator: Estimator) -> Estimator:
    """Add an estimator to :data:`REGISTRY` (a later registration of a name replaces it)."""
    REGISTRY[(estimator.sensor, estimator.name)] = estimator
    return estimator


def estimators(sensor: str) -> list[Estimator]:
    """The estimators of ``sensor``, in registration order."""
    return [e for (s, _), e in REGISTRY.items() if s == sensor]


@dataclass(frozen=True)
class Chosen:
    """The estimator for a sensor and the choice the section records."""

    estimator: Estimator
    choice: Choice


@dataclass(frozen=True)
class NotChosen:
    """Every estimator refused the design (``auto``): each one's refusal, by name."""

    refusals: dict[str, Refusal] = field(default_factory=dict)


def choose(sensor: str, design: Any, solver: str, *, config_reason: str = "") -> Chosen | NotChosen:
    """The estimator for ``sensor``: the config's ``solver``, or with ``"auto"`` the best
    assessment of ``design`` (module notes).

    A named solver is not assessed (its own fit refuses a design it cannot calibrate, with
    its own words); ``config_reason`` is what its choice says (``"[accel] solver"``).

    Raises
    ------
    KeyError
        ``solver`` is neither ``"auto"`` nor a registered name of ``sensor``.
    """
    if solver != "auto":
        est = REGISTRY[(sensor, solver)]
        return Chosen(est, Choice(solver, By.CONFIG, config_reason))
    determined, refusals = [], {}
    for est in estimators(sensor):
        found = est.assess(design)
        if isinstance(found, Refusal):
            refusals[est.name] = found
        else:
            determined.append((est, found))
    if not determined:
        return NotChosen(refusals)
    determined.sort(key=lambda item: item[1].tier)  # stable: registration order in a tier
    best, why = determined[0]
    reason = why.reason
    for est, other in determined[1:]:
        gain = _gain(why.bound, other.bound)
        if gain is not None:
            best, reason = est, f"{other.reason}: {_more_precise(gain, other.bound, why)}"
            break
    return Chosen(best, Choice(best.name, By.AUTO, reason))


def _gain(first: Bound | None, other: Bound | None) -> np.ndarray | None:
    """The ratios of ``other``'s variances to ``first``'s when ``other`` is measurably more
    precise (:data:`WORTH`), else None (also when they cannot be compared)."""
    if first is None or other is None or first.of != other.of:
        return None
    ratios = np.asarray(other.variance, float) / np.asarray(first.variance, float)
    return ratios if float(np.mean(ratios)) < WORTH else None


def _more_precise(ratios: np.ndarray, bound: Bound, first: Determined) -> str:
    """``"using them makes the bias 1.3x and the gains and axes 1.1x more precise than
    gravity magnitude alone (Cramer-Rao bounds of both designs)"``."""
    parts = " and ".join(f"{name} {1 / np.sqrt(np.mean(ratios[part])):.1f}x"
                         for name, part in bound.groups)  # fmt: skip
    return (f"using them makes {parts} more precise than {first.compared_with} (Cramer-Rao "
            "bounds of both designs)")  # fmt: skip
