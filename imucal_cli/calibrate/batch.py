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
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imucal_cli.calibrate.imu_set import calibrate_set, set_suspect_error
from imucal_cli.calibrate.session import calibrate_session, default_output, suspect_error
from imucal_cli.calibrate.thermal import merge_sessions
from imucal_cli.errors import ImucalError, ImucalWarning, InputError, SolverError
from imucal_cli.formats.calibration import (
    calibration_to_json,
    read_calibration,
    write_calibration,
)
from imucal_cli.formats.config import Config
from imucal_cli.formats.output import check_output, same_file
from imucal_cli.formats.session import open_samples, read_session, store_calibration
from imucal_cli.model.accel import AccelCalibration
from imucal_cli.model.calibration import Calibration
from imucal_cli.model.gyro import GyroCalibration
from imucal_cli.model.mag import MagCalibration

__all__ = ["Figures", "SessionResult", "Stored", "calibrate_file", "calibrate_many",
           "default_jobs"]  # fmt: skip


@dataclass(frozen=True)
class Stored:
    """Where a calibration was also stored in its session (``--store``), or why not.

    Attributes
    ----------
    where : str or None
        ``SESSION:/calibrations/NAME``.
    why_not : str or None
        Why it could not be stored (the JSON is saved: ``calibrate`` exits 1 with it).
    """

    where: str | None = None
    why_not: str | None = None

    @property
    def failed(self) -> bool:
        return self.why_not is not None

    def words(self) -> str:
        """What follows the output's name in ``wrote OUT...``: `` and S:/calibrations/N``,
        `` (not stored in the session: why)`` or nothing."""
        if self.where is not None:
            return f" and {self.where}"
        if self.why_not is not None:
            return f" (not stored in the session: {self.why_not})"
        return ""


@dataclass(frozen=True)
class Figures:
    """A saved calibration's figures for the summary table of several sessions (and the
    ``figures`` of ``calibrate --json`` with several: :meth:`to_dict`).

    Attributes
    ----------
    solvers : dict
        Each calibrated sensor's solver (``{"accel": "gravity", ...}``).
    accel_rms_after : float or None
        |a| - g RMS after calibration, m/s^2.
    gyro_rms_deg : float or None
        Turn angle residual RMS, deg.
    mag_rms_after : float or None
        |B| residual RMS, in ``mag_units``.
    mag_units : str or None
    mag_quality : str or None
        ``"pass"`` or ``"recapture"``.
    warnings : int
        Warnings of every section (and one for an accelerometer left out).
    accel_note : str or None
        Why the accelerometer was left out (issue 9.4).
    left_out : tuple of str
        Sensors of the session left out (issue 24.2); ``complete`` when none, and none
        ``assumed``.
    assumed : tuple of str
        Sensors calibrated only in part (issue 27.3: a section with ``partial``).
    """

    solvers: dict[str, str] = field(default_factory=dict)
    accel_rms_after: float | None = None
    gyro_rms_deg: float | None = None
    mag_rms_after: float | None = None
    mag_units: str | None = None
    mag_quality: str | None = None
    warnings: int = 0
    accel_note: str | None = None
    left_out: tuple[str, ...] = ()
    assumed: tuple[str, ...] = ()

    @property
    def complete(self) -> bool:
        return not self.left_out and not self.assumed

    def to_dict(self) -> dict:
        """The JSON figures (docs/commands.md): ``accel_solver``, ... where present."""
        out: dict = {f"{name}_solver": solver for name, solver in self.solvers.items()}
        for key in ("accel_rms_after", "gyro_rms_deg", "mag_rms_after", "mag_units",
                    "mag_quality"):  # fmt: skip
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.solvers or self.accel_note:
            out["warnings"] = self.warnings
        if self.accel_note:
            out["accel_note"] = self.accel_note
        out["complete"] = self.complete
        if self.left_out:
            out["left_out"] = list(self.left_out)
        return out


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
    stored : Stored or None
        Where it was also stored in the session, or why not (None: not saved).
    figures : Figures or None
        The saved calibration's figures (None: not saved).
    """

    session: str
    exit_code: int = 0
    output: str | None = None
    error: str | None = None
    stored: Stored | None = None
    figures: Figures | None = None


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
    prior=None,
    gyro_prior=None,
) -> tuple[Calibration, Path, str]:
    """Calibrate one session file, write its JSON and store it in the session.

    The output is refused before anything is solved when it exists (without ``force``) or is
    the session or one of ``inputs``; it is written through
    :func:`imucal_cli.formats.output.write_output`.  ``warmup``: still warm-up recordings of
    the unit (the bias temperature model); ``also``: more sessions of the unit, merged with this
    one (:func:`~imucal_cli.calibrate.thermal.merge_sessions`); ``prior``: an earlier
    accelerometer calibration's prior (``--prior``) for a design that cannot fix the model;
    ``gyro_prior``: its gyro's matrix, for a gyro whose turns cannot determine it.

    Returns
    -------
    cal : Calibration
    out : Path
        The JSON written.
    stored : Stored
        Where it was also stored in the session, or why not (both None: not asked).

    Raises
    ------
    ImucalError
        Whatever reading, calibrating or the physical-sense check (unless ``force``) refuses.
    """
    out = output or default_output(path)
    refuse_twice([path, *(also or [])])
    inputs = [path, *inputs]
    check_output(out, force=force, inputs=inputs)  # refuse before solving, not after
    session = read_session(path)
    if len(session.time) < 2:  # a capture a full disk stopped before its first samples
        raise InputError(f"{path}: the session holds {len(session.time)} samples: nothing to "
                         "calibrate; record it (capture --resume continues it)")  # fmt: skip
    if also:
        session = merge_sessions([session, *(read_session(p) for p in also)])
    warm = [read_session(p) for p in warmup] if warmup else None
    if session.imus and (accel is not None or warm or also or prior is not None
                         or gyro_prior is not None):  # issue 28
        raise InputError(f"{path}: a session of several IMUs takes no --accel, --prior, "
                         "--warmup or --with (each IMU is calibrated from the session itself)")
    try:
        if session.imus:
            cal = calibrate_set(session, cfg, name=path.name)
        else:
            cal = calibrate_session(session, cfg, name=path.name, accel=accel, warmup=warm,
                                    prior=prior, gyro_prior=gyro_prior)  # fmt: skip
    except np.linalg.LinAlgError as exc:  # issue 24.6: a one-line refusal, never a traceback
        raise SolverError(
            f"{path.name}: a solver met a singular system ({exc}): the data do not determine "
            "the model; check each sensor's readings (an axis that barely moves) and the poses"
        ) from None
    if also:
        cal.sessions = [path.name, *(p.name for p in also)]
    problem = set_suspect_error(cal) if session.imus else suspect_error(cal)
    if problem is not None and not force:
        raise problem
    write_calibration(out, cal, force=force, inputs=inputs)
    stored = Stored()
    if store:
        try:
            name = store_calibration(path, calibration_to_json(cal))
            stored = Stored(where=f"{path}:/calibrations/{name}")
        except Exception as exc:  # noqa: BLE001  the JSON is saved: exit 1 with the reason
            reason = str(exc)
            if not isinstance(exc, OSError | ImucalError):
                reason = f"{type(exc).__name__}: {reason}"
            stored = Stored(why_not=" ".join(reason.split()))
    return cal, out, stored


def _figures(cal: Calibration) -> Figures:
    """The figures of a saved calibration."""
    solvers, found, warnings = {}, {}, 0
    for name, sec in cal.sections().items():
        solvers[name] = sec.solver
        if isinstance(sec, AccelCalibration) and sec.rms_after is not None:
            found["accel_rms_after"] = float(sec.rms_after)
        if isinstance(sec, GyroCalibration) and sec.rotation_rms_deg is not None:
            found["gyro_rms_deg"] = float(sec.rotation_rms_deg)
        if isinstance(sec, MagCalibration):
            if sec.rms_after is not None:
                found["mag_rms_after"] = float(sec.rms_after)
                found["mag_units"] = sec.units
            if sec.quality is not None:
                found["mag_quality"] = sec.quality.verdict
        warnings += len(sec.warnings or [])
    note = cal.accel_note or None
    if note:  # the accel left out (issue 9.4): one more warning
        warnings += 1
    left_out = cal.left_out or {}
    assumed = tuple(name for name, sec in cal.sections().items()
                    if sec is not None and sec.partial is not None)  # fmt: skip
    return Figures(solvers, warnings=warnings, accel_note=note,
                   left_out=tuple(sorted(left_out)), assumed=assumed, **found)  # fmt: skip


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
    if stored.failed:
        result.exit_code = 1
        result.error = f"{path}: saved {out} but not stored in the session: {stored.why_not}"
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
    refuse_twice(paths)
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


def refuse_twice(paths: Sequence[Path], what: str = "session") -> None:
    """Refuse a file named twice (``calibrate A A``, ``--with A`` of A itself): calibrated twice,
    its JSON written twice and stored twice in it, or its data counted twice."""
    for i, p in enumerate(paths):
        for q in paths[:i]:
            if Path(p) == Path(q) or same_file(p, q):
                raise InputError(f"{p}: the {what} {q} given twice; name each once")


def warn_other_unit(session: Path, earlier: Path | None, option: str) -> None:
    """Warn when ``earlier`` (the calibration of ``--accel`` or ``--prior``: a JSON, or a
    session holding one) names another unit than ``session`` does (their ``sensor``): another
    unit's accelerometer measures this one's turns wrong (the gyro's angle residuals grew from
    0.04 to 3.7 deg, exit 0, said nowhere).  Nothing when either names none."""
    if earlier is None:
        return
    mine, theirs = _unit_of(Path(session)), _unit_of(Path(earlier))
    if mine and theirs and mine.casefold() != theirs.casefold():
        warnings.warn(f"{option} {earlier} was made on '{theirs}' but {session} is from "
                      f"'{mine}': a calibration belongs to one unit; give this unit's (or name "
                      "both the same with label --sensor if they are one)", ImucalWarning,
                      stacklevel=2)  # fmt: skip


def _unit_of(path: Path) -> str | None:
    """The unit (``sensor``) a session or a calibration JSON names, or None."""
    try:
        if path.suffix.lower() in (".h5", ".hdf5"):
            with open_samples(path) as samples:
                name = samples.sensor
        else:
            name = read_calibration(path).sensor
    except ImucalError:
        return None  # said by the command's own read
    return name.strip() if isinstance(name, str) else None


def default_jobs() -> int:
    """CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)
