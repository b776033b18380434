"""Calibrating many sessions (a production line): ``imucal calibrate *.h5 --jobs N``.

Each session goes through exactly what ``imucal calibrate SESSION`` does (read, calibrate, the
physical-sense check, write ``SESSION.cal.json``, store it in the session); a session that
fails is reported with its one-line error and does not stop the others.  With ``jobs > 1`` the
sessions are shared out to a pool of worker processes (forked after the solvers are imported,
so no worker pays the import again).
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imucal_cli.errors import ImucalError, InputError, SolverError
from imucal_cli.formats.calibration import Calibration, calibration_to_json, write_calibration
from imucal_cli.formats.config import Config
from imucal_cli.formats.output import check_output
from imucal_cli.formats.session import read_session, store_calibration
from imucal_cli.pipeline.temperature import merge_sessions

from .calibrate import calibrate_session, default_output, suspect_error
from .imu_set import calibrate_set, set_suspect_error

__all__ = ["NOT_STORED", "SessionResult", "calibrate_file", "calibrate_many", "default_jobs"]


@dataclass
class SessionResult:
    """What calibrating one session gave.

    Attributes
    ----------
    session : str
        The session file.
    exit_code : int
        0 saved; 2 bad input; 1 solver failure or outside physical sense (as ``calibrate``).
    output : str or None
        The calibration JSON written.
    error : str or None
        The one-line error when not saved.
    figures : dict
        ``accel_solver``, ``accel_rms_after`` (m/s^2), ``gyro_solver``, ``gyro_rms_deg``,
        ``mag_solver``, ``mag_rms_after`` (in ``mag_units``), ``mag_quality`` (pass/recapture),
        ``warnings`` (count), ``accel_note`` (why the accel was left out), where present;
        ``complete`` (false when a sensor of the session was left out) and ``left_out`` (their
        names) when saved.
    """

    session: str
    exit_code: int = 0
    output: str | None = None
    error: str | None = None
    stored: str | None = None
    figures: dict = field(default_factory=dict)


NOT_STORED = " (not stored in the session: "


def calibrate_file(
    path: Path,
    cfg: Config,
    *,
    output: Path | None = None,
    force: bool = False,
    store: bool = True,
    inputs: Sequence[Path | None] = (),
    accel=None,
    warmup: list[Path] | None = None,
    also: list[Path] | None = None,
) -> tuple[Calibration, Path, str]:
    """Calibrate one session file, write its JSON and store it in the session.

    The output is refused before anything is solved when it exists (without ``force``) or is
    the session or one of ``inputs``; it is written through
    :func:`imucal_cli.formats.output.write_output`.  ``warmup``: still warm-up recordings of
    the unit (the bias temperature model); ``also``: more sessions of the unit, merged with this
    one (:func:`~imucal_cli.pipeline.temperature.merge_sessions`).

    Returns
    -------
    cal : Calibration
    out : Path
        The JSON written.
    stored : str
        Where it was also stored (``" and S:/calibrations/0001"``), or why not
        (:data:`NOT_STORED` ``+ reason + ")"``), or ``""``.

    Raises
    ------
    ImucalError
        Whatever reading, calibrating or the physical-sense check (unless ``force``) refuses.
    """
    out = output or default_output(path)
    inputs = [path, *inputs]
    check_output(out, force=force, inputs=inputs)  # refuse before solving, not after
    session = read_session(path)
    if also:
        session = merge_sessions([session, *(read_session(p) for p in also)])
    warm = [read_session(p) for p in warmup] if warmup else None
    if session.imus and (accel is not None or warm or also):  # several IMUs (issue 28)
        raise InputError(f"{path}: a session of several IMUs takes no --accel, --warmup or "
                         "--with (each IMU is calibrated from the session itself)")
    try:
        if session.imus:
            cal = calibrate_set(session, cfg, name=path.name)
        else:
            cal = calibrate_session(session, cfg, name=path.name, accel=accel, warmup=warm)
    except np.linalg.LinAlgError as exc:  # issue 24.6: a one-line refusal, never a traceback
        raise SolverError(
            f"{path.name}: a solver met a singular system ({exc}): the data do not determine "
            "the model; check each sensor's readings (an axis that barely moves) and the poses"
        ) from None
    if also:
        cal.extra["sessions"] = [path.name, *(p.name for p in also)]
    problem = set_suspect_error(cal) if session.imus else suspect_error(cal)
    if problem is not None and not force:
        raise problem
    write_calibration(out, cal, force=force, inputs=inputs)
    stored = ""
    if store:
        try:
            name = store_calibration(path, calibration_to_json(cal))
            stored = f" and {path}:/calibrations/{name}"
        except Exception as exc:  # noqa: BLE001  the JSON is saved: exit 1 with the reason
            reason = str(exc)
            if not isinstance(exc, OSError | ImucalError):
                reason = f"{type(exc).__name__}: {reason}"
            stored = f"{NOT_STORED}{' '.join(reason.split())})"
    return cal, out, stored


def _figures(cal: Calibration) -> dict:
    out: dict = {}
    for name, sec in cal.sections().items():
        out[f"{name}_solver"] = sec.solver
        x = sec.extra
        if name == "accel" and x.get("rms_after") is not None:
            out["accel_rms_after"] = float(x["rms_after"])
        if name == "gyro" and x.get("rotation_rms_deg") is not None:
            out["gyro_rms_deg"] = float(x["rotation_rms_deg"])
        if name == "mag":
            if x.get("rms_after") is not None:
                out["mag_rms_after"] = float(x["rms_after"])
                out["mag_units"] = sec.units
            if isinstance(x.get("quality"), dict):
                out["mag_quality"] = x["quality"].get("verdict")
        out["warnings"] = out.get("warnings", 0) + len(x.get("warnings", []))
    if cal.extra.get("accel_note"):  # the accel left out (issue 9.4): one more warning
        out["warnings"] = out.get("warnings", 0) + 1
        out["accel_note"] = cal.extra["accel_note"]
    left_out = cal.extra.get("left_out") or {}
    out["complete"] = not left_out  # issue 24.2
    if left_out:
        out["left_out"] = sorted(left_out)
    return out


def _one(args: tuple) -> SessionResult:
    path, cfg, force, store, accel = args
    result = SessionResult(session=path)
    try:
        cal, out, stored = calibrate_file(Path(path), cfg, force=force, store=store, accel=accel)
    except ImucalError as exc:
        result.exit_code, result.error = exc.exit_code, str(exc)
        return result
    except Exception as exc:  # noqa: BLE001  one bad file must not stop a production line
        result.exit_code, result.error = 1, f"{path}: internal error: {type(exc).__name__}: {exc}"
        return result
    result.output, result.stored, result.figures = str(out), stored, _figures(cal)
    if stored.startswith(NOT_STORED):
        result.exit_code = 1
        result.error = (
            f"{path}: saved {out} but not stored in the session: {stored[len(NOT_STORED) : -1]}"
        )
    return result


def calibrate_many(
    paths: Sequence[Path],
    cfg: Config,
    *,
    jobs: int = 1,
    force: bool = False,
    store: bool = True,
    progress: Callable[[SessionResult], None] | None = None,
    accel=None,
) -> list[SessionResult]:
    """Calibrate every session; one result per session, in the order given.

    Parameters
    ----------
    paths : sequence of Path
        Session files.
    cfg : Config
        The (validated) configuration, the same for all.
    jobs : int
        Worker processes (1: in this process; 0: one per CPU).
    force, store : bool
        As ``imucal calibrate``.
    accel : SensorCalibration, optional
        An accelerometer calibrated earlier (``--accel``), used for every session.
    progress : callable, optional
        Called with each result as it completes (any order).

    Raises
    ------
    InputError
        ``jobs`` < 0.
    """

    if jobs < 0:
        raise InputError(f"--jobs must be 0 (one per CPU) or more, got {jobs}")
    jobs = jobs or default_jobs()
    tasks = [(str(p), cfg, force, store, accel) for p in paths]
    if jobs == 1 or len(tasks) == 1:
        results = map(_one, tasks)
        pool = None
    else:
        method = "fork" if "fork" in multiprocessing.get_all_start_methods() else None
        context = multiprocessing.get_context(method)
        pool = ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=context)
        chunk = max(1, len(tasks) // (jobs * 8))
        results = pool.map(_one, tasks, chunksize=chunk)
    try:
        out = []
        for r in results:
            out.append(r)
            if progress is not None:
                progress(r)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    return out


def default_jobs() -> int:
    """CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)
