"""Which plan step a finished hold fulfils, and what a turn measured: pure functions."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal_cli.design.poses import angle_deg, describe_direction
from imucal_cli.design.stillness import integrate_rate, motion_span, rate_to_deg_s
from imucal_cli.plans import Step

from .samples import SampleHistory


@dataclass
class Taken:
    """A step taken: its plan index, segment kind and samples ``[start, stop)``.

    ``direction`` is a static step's measured up direction (None when it cannot be estimated);
    ``measured`` a turn's ``integral`` (raw units x s) and ``angle_deg``; ``turn`` the motion
    that led into a static pose (``(start, stop)``), recorded as a rotation segment before it.
    """

    step: int
    kind: str
    start: int
    stop: int
    direction: np.ndarray | None = None
    measured: dict = field(default_factory=dict)
    turn: tuple[int, int] | None = None


def match_hold(
    direction: np.ndarray | None,
    cur: int,
    cands: list[int],
    steps: list[Step],
    taken_poses: list[Taken],
    *,
    min_separation_deg: float,
    match_tolerance_deg: float,
    is_pose,
) -> tuple[int, str | None]:
    """The step a hold fulfils, and a refusal message (None when the hold is accepted).

    Parameters
    ----------
    direction : ndarray (3,) or None
        Measured up direction of the hold (None: poses are taken in plan order).
    cur : int
        The current step.
    cands : list of int
        Pending static steps the hold may fulfil, the current one first.
    steps : list of Step
        The plan's steps.
    taken_poses : list of Taken
        Static poses taken so far, with a measured direction.
    min_separation_deg, match_tolerance_deg : float
        A hold closer than ``min_separation_deg`` to a pose taken is refused unless the plan
        itself repeats that direction; it matches a labelled step within ``match_tolerance_deg``.
    is_pose : callable
        ``is_pose(i)``: step ``i`` is a gravity pose (not only the still period of a turn).
    """
    if not cands:
        return cur, None
    if direction is None:
        return cands[0], None
    close = sorted(
        ((float(angle_deg(direction, x.direction)), x) for x in taken_poses),
        key=lambda ax: ax[0],
    )
    close = [(a, x) for a, x in close if a < min_separation_deg]
    best, best_angle = None, np.inf
    for i in (i for i in cands if steps[i].up is not None):
        a = float(angle_deg(direction, np.asarray(steps[i].up, float)))
        if a < best_angle:
            best, best_angle = i, a

    def too_close() -> str:
        ang, x = close[0]
        return (
            f"too close to {steps[x.step].label}, already taken ({ang:.0f} deg "
            f"apart): turn the unit to another face or edge"
        )

    if best is not None and best_angle <= match_tolerance_deg:
        up = np.asarray(steps[best].up, float)
        repeat = any(
            steps[x.step].up is not None
            and float(angle_deg(up, np.asarray(steps[x.step].up, float))) < min_separation_deg
            for _, x in close
        )
        return best, (too_close() if close and not repeat else None)
    if close and is_pose(cands[0]):
        return cands[0], too_close()
    unlabelled = [i for i in cands if steps[i].up is None]
    if unlabelled:
        return unlabelled[0], None
    near = f"{steps[best].label}, {best_angle:.0f} deg away" if best is not None else ""
    return cands[0], (
        f"this pose (up {describe_direction(direction)}) matches no step left "
        f"(nearest: {near}; tolerance {match_tolerance_deg:g} deg): "
        "put the unit on one of the poses left"
    )


def measure_turn(
    hist: SampleHistory,
    pre_run: tuple[int, int],
    post_start: int,
    gyro_sd: np.ndarray | None,
    gyro_units: str | None,
    gyro_scale: float | None,
) -> tuple[int, int, dict]:
    """The samples of a turn and what the gyro measured over them.

    The turn lies between the still run ``pre_run`` before it and the still run starting at
    ``post_start`` after it; :func:`~imucal_cli.design.stillness.motion_span` narrows it to the
    motion seen by the gyro, whose bias-free rate is integrated over it.

    Returns
    -------
    start, stop : int
        Recorder sample indices of the turn, half-open.
    measured : dict
        ``integral`` (raw gyro units x s, per channel) and ``angle_deg`` when the units allow.
    """
    pre_s, pre_e = pre_run
    a, b = pre_e, post_start
    measured: dict = {}
    gyro = hist.gyro
    if gyro is not None and gyro_sd is not None:
        n_rest = max(2, pre_e - pre_s)
        lo = max(pre_e - n_rest, hist.first)
        rest = hist.rows(gyro, lo, pre_e).mean(axis=0)
        w0, w1 = max(pre_s, hist.first), hist.end
        span = motion_span(hist.rows(gyro, w0, w1), rest, gyro_sd)
        if span is not None:
            a, b = w0 + span[0], w0 + span[1]
        t = hist.rows(hist.time[:, None], w0, w1)[:, 0]
        vec = integrate_rate(t, hist.rows(gyro, w0, w1), rest, a - w0, b - w0)
        factor = rate_to_deg_s(gyro_units, gyro_scale)
        measured["integral"] = vec
        if factor is not None and np.linalg.norm(vec) > 0:
            measured["angle_deg"] = float(np.linalg.norm(vec) * factor)
    if b <= a:
        a, b = pre_e, max(post_start, pre_e + 1)
    return a, b, measured


def turn_warnings(step: Step, measured: dict, axis_tolerance_deg: float) -> list[str]:
    """What looks wrong with a measured turn against the plan's axis and angle."""
    out = []
    vec = measured.get("integral")
    if vec is None or len(vec) != 3 or not np.linalg.norm(vec) > 0:
        return out
    if step.axis is not None:
        axis = np.asarray(step.axis, float)
        off = float(angle_deg(vec, axis))
        if min(off, 180.0 - off) > axis_tolerance_deg:
            out.append(
                f"the turn looks like it was about {describe_direction(vec)}, not "
                f"{describe_direction(axis)}: r redoes it"
            )
    want, got = step.angle_deg, measured.get("angle_deg")
    if want is not None and got is not None and abs(got - abs(want)) > 20.0:
        out.append(f"turned {got:.0f} deg, the plan says {abs(want):g}: r redoes it")
    return out
