"""The calibrate step on a capture's session so far (``imucal capture --until``, issue 27).

:func:`refit` runs :func:`~imucal_cli.calibrate.session.calibrate_session` as ``imucal
calibrate`` would on the samples and segments captured so far, and never raises for a design
that does not determine a sensor yet: it returns what calibrated (None when nothing did) and,
per sensor, why it did not.  Warnings are the capture's to give at the end, not after every
hold: they are kept out.

A solver that fails on a design it should refuse (a numerical error instead of a one-line
refusal) does not end the capture: the refit says so as that sensor's note, the capture goes on
with the next hold, and the saved session keeps every sample for ``imucal calibrate`` (where the
failure is the solver's to fix, and said as it is).

The gyroscope's turns are measured with the accelerometer calibration: while its axes are
known only to worse than :data:`GYRO_WAITS_DEG` (the first poses, fitted with their labels'
2-degree placement), the gyro could not come out better than that either, and its fit (which
then propagates the accelerometer's uncertainty by refitting at sigma points, seconds) is left
for a later hold.  The held-out residuals of the accelerometer's poses are a report's, not a
std's: left out too.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from imucal_cli.errors import ImucalError, SolverError
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.model.calibration import Calibration

from .session import calibrate_session

__all__ = ["GYRO_WAITS_DEG", "refit"]

GYRO_WAITS_DEG = 0.5
"""The gyro is refitted once the accelerometer's axes are known to this (1 std), degrees."""


def _quiet(session: Session, cfg: Config, accel=None) -> Calibration:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return calibrate_session(session, cfg, name="capture so far", accel=accel)
        except ImucalError:
            raise
        except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:  # a solver's bug
            raise SolverError(f"a solver failed on the session so far ({type(exc).__name__}: "
                              f"{exc}); the next hold is refitted anew") from exc


def refit(session: Session, cfg: Config) -> tuple[Calibration | None, dict[str, str]]:
    """The calibration of ``session`` (None: nothing calibrates yet) and why each sensor that
    is not in it is not (``{"accel": ..., "gyro": ...}``)."""
    cfg = replace(cfg, accel=replace(cfg.accel, gravity=replace(cfg.accel.gravity,
                                                                leave_one_out=False)))
    wants_gyro = cfg.gyro.solver != "none" and session.gyro is not None
    first = replace(cfg, gyro=replace(cfg.gyro, solver="none")) if wants_gyro else cfg
    try:
        cal = _quiet(session, first)
    except ImucalError as exc:
        why = str(exc).removeprefix("session: ")
        return None, {"accel": why, "gyro": why}
    if cal.accel is not None and cal.accel.partial is not None:
        # a design that determines the accelerometer only in part (issue 27.3): to a capture
        # it is not determined yet (its proposals and targets read the labelled model)
        why = next((n.removeprefix("why not the whole model: ") for n in cal.accel.notes or []
                    if n.startswith("why not the whole model: ")), "determined only in part")
        cal = replace(cal, accel=None)
        if not cal.sections():
            return None, {"accel": why, "gyro": why}
        notes_early = {"accel": why}
    else:
        notes_early = {}
    notes = dict(notes_early)
    if wants_gyro:
        worst = max((cal.accel.misalignment_std_deg or {}).values(),
                    default=float("inf")) if cal.accel is not None else float("inf")
        if worst <= GYRO_WAITS_DEG:
            try:  # the accelerometer as fitted (the gyro's turns measured with it)
                cal = _quiet(session, cfg, cal.accel)
            except ImucalError as exc:
                notes["gyro"] = str(exc).removeprefix("session: ")
        else:
            notes["gyro"] = (f"waits for the accelerometer's axes to be known to "
                             f"{GYRO_WAITS_DEG:g} deg (now {worst:.2g} deg)")
    if cal.gyro is not None and cal.gyro.partial is not None:
        # still periods without turns so far: the bias measured, the matrix assumed (issue
        # 27.3); to a capture the gyro is not determined yet, as a partial accelerometer
        notes["gyro"] = "determined only in part (the bias; the matrix needs turns)"
        cal = replace(cal, gyro=None)
    for sensor in ("accel", "gyro"):
        note = cal.note(sensor) or (cal.left_out or {}).get(sensor)
        if note and sensor not in notes:
            notes[sensor] = str(note)
    return cal, notes
