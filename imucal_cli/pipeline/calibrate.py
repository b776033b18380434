"""The calibrate step: a session and a config in, a :class:`Calibration` with its diagnostics out.

The config chooses a solver per sensor; each lives in :mod:`imucal_cli.pipeline` and returns
the sensor's section of the calibration JSON (layout in DEVELOPERS.md). Nothing here prints.
"""

from __future__ import annotations

from pathlib import Path

from imucal_cli import __version__
from imucal_cli.errors import ConfigError, DesignError, SolverError
from imucal_cli.formats.calibration import Calibration, SensorCalibration
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session, utc_now_iso
from imucal_cli.pipeline.common import (  # noqa: F401 (re-exported for callers)
    StaticPoses,
    check_design,
    nominal_sensor,
    session_name,
    static_poses,
    with_segments,
)


def calibrate_accel(session: Session, cfg: Config) -> SensorCalibration | None:
    """Run the configured accelerometer solver (``[accel] solver``) on a session; ``"auto"``
    chooses (:mod:`imucal_cli.pipeline.choose`) and may find nothing to calibrate (None)."""
    solver = cfg.accel.solver
    if solver == "auto":
        from imucal_cli.pipeline.choose import auto_accel

        return auto_accel(session, cfg)
    if solver == "factorization":
        from imucal_cli.pipeline.factorization import calibrate_accel_factorization

        sec = calibrate_accel_factorization(session, cfg)
    elif solver == "labelled":
        from imucal_cli.pipeline.labelled import calibrate_accel_labelled

        sec = calibrate_accel_labelled(session, cfg)
    else:
        from imucal_cli.pipeline.gravity import calibrate_accel_gravity

        sec = calibrate_accel_gravity(session, cfg)
    sec.extra["choice"] = {"solver": sec.solver, "by": "config", "reason": "[accel] solver"}
    return sec


def calibrate_gyro(
    session: Session, cfg: Config, accel: SensorCalibration | None
) -> SensorCalibration | None:
    """Run the configured gyroscope solver (``[gyro] solver``); None when it is ``"none"``.

    The static, dynamic and full solvers measure each rotation with the accelerometer, so
    they need ``accel``, calibrated in the same run.
    """
    solver = cfg.gyro.solver
    if solver == "factorization":
        from imucal_cli.pipeline.factorization import calibrate_gyro_factorization

        return calibrate_gyro_factorization(session, cfg)
    if solver in ("static", "dynamic", "full"):
        if accel is None:
            raise ConfigError(
                f"[gyro] solver = {solver!r} measures each rotation with the calibrated "
                "accelerometer: set an [accel] solver too"
            )
        from imucal_cli.pipeline.gyro import calibrate_gyro_rotations

        return calibrate_gyro_rotations(session, cfg, accel)
    return None


def calibrate_session(session: Session, cfg: Config, *, name: str | None = None) -> Calibration:
    """Calibrate every sensor the config asks for; returns the calibration (not yet saved).

    ``name`` is what the calibration records as its session (default: the session's path).
    """
    if cfg.accel.solver == "none" and cfg.gyro.solver == "none":
        raise ConfigError("the config calibrates nothing: [accel] and [gyro] solver are both none")
    session, segmented = with_segments(session)
    accel = calibrate_accel(session, cfg) if cfg.accel.solver != "none" else None
    gyro = calibrate_gyro(session, cfg, accel)
    if accel is None and gyro is None:
        raise DesignError(
            f"{session_name(session)}: nothing to calibrate: no still poses with accelerometer "
            "data, and [gyro] solver is none"
        )
    for sec in (accel, gyro):
        if sec is not None and segmented:
            sec.extra.setdefault("notes", []).insert(0, segmented)
    extra = {"toolkit_version": __version__, "config": cfg.to_dict()}
    if session.sensor:
        extra["sensor"] = session.sensor
    if session.source:  # "simulator", "serial:...": the report's context (paper figures or not)
        extra["source"] = session.source
    return Calibration(
        accel=accel,
        gyro=gyro,
        session=name or session_name(session),
        created=utc_now_iso(),
        extra=extra,
    )


def suspect_error(cal: Calibration) -> SolverError | None:
    """A :class:`SolverError` describing the physical-sense warnings, or None when clean."""
    warnings = [w for sec in (cal.accel, cal.gyro) if sec for w in sec.extra.get("warnings", [])]
    if not warnings:
        return None
    more = f" (and {len(warnings) - 1} more)" if len(warnings) > 1 else ""
    return SolverError(
        f"result outside physical sense, not saved: {warnings[0]}{more}; "
        "check the units and the capture, or pass --force to save it with these warnings"
    )


def default_output(session_path: Path) -> Path:
    """``run3.h5`` -> ``run3.cal.json`` beside it."""
    return session_path.with_suffix(".cal.json")
