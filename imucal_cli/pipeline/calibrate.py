"""The calibrate step: a session and a config in, a :class:`Calibration` with its diagnostics out.

The config chooses a solver per sensor; each lives in :mod:`imucal_cli.pipeline` and returns
the sensor's section of the calibration JSON (layout in DEVELOPERS.md). Nothing here prints.
"""

from __future__ import annotations

import warnings
from dataclasses import fields, is_dataclass, replace
from pathlib import Path

import numpy as np

from imucal_cli import __version__
from imucal_cli.errors import (
    ConfigError,
    DesignError,
    ImucalError,
    ImucalWarning,
    InputError,
    SolverError,
)
from imucal_cli.formats.calibration import (
    Calibration,
    SensorCalibration,
    calibration_from_json,
    read_calibration,
)
from imucal_cli.formats.config import (
    AccelConfig,
    Config,
    GyroConfig,
    MagConfig,
    TemperatureConfig,
)
from imucal_cli.formats.session import Session, read_session, utc_now_iso
from imucal_cli.pipeline import magnetometer
from imucal_cli.pipeline.channels import check_channels
from imucal_cli.pipeline.choose import auto_accel
from imucal_cli.pipeline.clock import correct_clock
from imucal_cli.pipeline.common import (  # noqa: F401 (re-exported for callers)
    StaticPoses,
    check_design,
    nominal_sensor,
    session_name,
    static_poses,
    stored_accel_hint,
    with_segments,
)
from imucal_cli.pipeline.factorization import (
    calibrate_accel_factorization,
    calibrate_gyro_factorization,
    independent_constraints,
)
from imucal_cli.pipeline.gravity import calibrate_accel_gravity
from imucal_cli.pipeline.gyro import calibrate_gyro_rotations, gyro_alternatives
from imucal_cli.pipeline.gyro_known import calibrate_gyro_known
from imucal_cli.pipeline.labelled import calibrate_accel_labelled
from imucal_cli.pipeline.temperature import attach, compensate, given_accel, temperature_models
from imucal_cli.solvers.poses import count_distinct, unit


def calibrate_accel(session: Session, cfg: Config) -> SensorCalibration | None:
    """Run the configured accelerometer solver (``[accel] solver``) on a session; ``"auto"``
    chooses (:mod:`imucal_cli.pipeline.choose`) and may find nothing to calibrate (None)."""
    try:
        return _run_accel(session, cfg)
    except DesignError as exc:  # name what the user already has (issue 9.6)
        hint = stored_accel_hint(session)
        if not hint:
            raise
        raise DesignError(f"{exc}{hint}") from None


def _run_accel(session: Session, cfg: Config) -> SensorCalibration | None:
    solver = cfg.accel.solver
    if solver == "auto":
        return auto_accel(session, cfg)
    if solver == "factorization":
        sec = calibrate_accel_factorization(session, cfg)
    elif solver == "labelled":
        sec = calibrate_accel_labelled(session, cfg)
    else:
        sec = calibrate_accel_gravity(session, cfg)
    sec.extra["choice"] = {"solver": sec.solver, "by": "config", "reason": "[accel] solver"}
    return sec


def calibrate_gyro(
    session: Session, cfg: Config, accel: SensorCalibration | None
) -> SensorCalibration | None:
    """Run the configured gyroscope solver (``[gyro] solver``); None when it is ``"none"``.

    The static, dynamic and full solvers measure each rotation with the accelerometer, so
    they need ``accel``, calibrated in the same run; the known-angle solver needs it only for
    turns whose axis is not labelled (it measures the vertical), the factorization not at all.
    """
    solver = cfg.gyro.solver
    if solver == "auto":
        return calibrate_gyro_auto(session, cfg, accel)[0]
    if solver == "factorization":
        return calibrate_gyro_factorization(session, cfg)
    if solver in ("static", "dynamic", "full", "known"):
        if accel is None and solver != "known":  # known: labelled axes need no accelerometer
            raise ConfigError(
                f"[gyro] solver = {solver!r} measures each rotation with the calibrated "
                "accelerometer: set an [accel] solver too"
            )

        try:
            if solver == "known":
                return calibrate_gyro_known(session, cfg, accel)
            return calibrate_gyro_rotations(session, cfg, accel)
        except DesignError as exc:  # issue 9.6: what would work with what the session has
            alternatives = gyro_alternatives(session, solver)
            if not alternatives:
                raise
            raise DesignError(f"{exc}; with what this session has: "
                              f"{'; or '.join(alternatives)}") from None  # fmt: skip
    return None


def calibrate_mag(
    session: Session, cfg: Config, accel: SensorCalibration | None
) -> SensorCalibration | None:
    """Run the ``[mag]`` solver when the session has ``/raw/mag`` (None otherwise, or with
    ``solver = "none"``); the accelerometer of the same run aligns it."""
    if session.mag is None or cfg.mag.solver == "none":
        return None

    return magnetometer.calibrate_mag(session, cfg, accel)


def _hk_design(turns) -> bool:
    """Hwangbo & Kanade IV-B: turns about labelled axes whose orthogonal pairs, per mounting,
    give the metric upgrade its 5 independent constraints, and one turn of known angle among
    them for the scale (eq. 31). Sweeps about the vertical there: gravity cannot see them."""
    if not any(s.angle_deg is not None and s.axis is not None for s in turns):
        return False

    return independent_constraints(turns) >= 5


def _known_axes(turns) -> bool:
    """Turns of known angle about labelled axes that span three dimensions (the Ferraris
    360-degree turns flat on each face): they determine the matrix without an accelerometer."""

    axes = [s.axis for s in turns if s.angle_deg is not None and s.axis is not None]
    return len(axes) >= 3 and np.linalg.matrix_rank(np.array(axes, float), tol=1e-3) == 3


def gyro_choice(session: Session, accel: SensorCalibration | None) -> tuple[str | None, str]:
    """``[gyro] solver = "auto"``: the solver for this session's turns, and why; ``(None,
    note)`` when none can run. Most accurate first (issue 10.7): a redundant gyro or Hwangbo
    & Kanade's sweeps in mountings (whose turns about the vertical gravity cannot measure):
    the factorization; turns of known angle: the known-angle solver (with the accelerometer,
    or on labelled axes without it); other turns with the accelerometer: the full model."""
    turns = session.rotation_segments()
    if session.gyro.shape[1] != 3:
        return "factorization", f"a redundant gyro ({session.gyro.shape[1]} channels)"
    if _hk_design(turns):
        return "factorization", ("turns about labelled axes in several mountings and one of "
                                 "known angle (Hwangbo & Kanade IV-B): the factorization uses "
                                 "their axes, which gravity cannot measure")  # fmt: skip
    if accel is None and _known_axes(turns):
        return "known", ("turns of a known angle about labelled axes spanning three "
                         "dimensions: their axes are the labels, no accelerometer needed")
    if accel is None and any(s.axis is not None for s in turns):
        return "factorization", "turns about labelled axes and no accelerometer calibration"
    if accel is None:
        return None, ("gyro not calibrated: the full gyro model needs the accelerometer "
                      "calibrated (an [accel] solver, or --accel CAL.json)")  # fmt: skip
    if any(s.angle_deg is not None for s in turns):
        return "known", ("turns of a known angle (with any turns between still periods), "
                         "accelerometer calibrated")  # fmt: skip
    return "full", "turns between still periods, accelerometer calibrated"


def calibrate_gyro_auto(
    session: Session, cfg: Config, accel: SensorCalibration | None
) -> tuple[SensorCalibration | None, str | None]:
    """``[gyro] solver = "auto"``: the most accurate solver the session supports
    (:func:`gyro_choice`); None when the session has no gyro, or no rotations that it did not
    capture on purpose. A session with rotation segments that no solver can use is refused
    with the chosen solver's reason.

    Returns
    -------
    section : SensorCalibration or None
    note : str or None
        Why the gyro was left uncalibrated (None when it was calibrated).
    """

    if session.gyro is None:
        return None, "gyro not calibrated: the session has no /raw/gyro"
    choice, why = gyro_choice(session, accel)
    if choice is None:
        return None, why
    try:
        sec = calibrate_gyro(session, replace(cfg, gyro=replace(cfg.gyro, solver=choice)), accel)
    except ImucalError:
        if session.rotation_segments():
            raise  # turns captured on purpose: say why they cannot calibrate
        return None, ("gyro not calibrated: no usable rotations (the gyro needs turns "
                      "between still periods)")  # fmt: skip
    if sec is not None and sec.extra.get("undetermined"):  # issue 10.2: not saved silently
        return None, (f"gyro not calibrated: {sec.extra['undetermined']} (to save it with these "
                      f'std: [gyro] solver = "{choice}" and --force)')  # fmt: skip
    sec.extra.setdefault("notes", []).insert(0, f'solver "{choice}" chosen by [gyro] solver = '
                                                f'"auto": {why}')  # fmt: skip
    sec.extra["choice"] = {"solver": choice, "by": "auto", "reason": why}
    return sec, None


def load_accel(path: str | Path) -> SensorCalibration:
    """The accelerometer section of an earlier calibration (issue 9.5): a calibration JSON, or
    a session file whose newest stored calibration has one.

    Raises
    ------
    InputError
        Unreadable file, or no accelerometer section in it.
    """

    path = Path(path)
    if path.suffix.lower() in (".h5", ".hdf5"):
        stored = read_session(path).calibrations
        found = [calibration_from_json(stored[k], f"{path}:/calibrations/{k}").accel
                 for k in sorted(stored)]  # fmt: skip
        found = [a for a in found if a is not None]
        if not found:
            raise InputError(f"{path}: no stored calibration with an accelerometer section")
        accel = found[-1]
    else:
        accel = read_calibration(path).accel
        if accel is None:
            raise InputError(f"{path}: this calibration has no accelerometer section")
    accel.extra = {**accel.extra, "notes": [f"from {path} (not re-calibrated here)"]
                   + list(accel.extra.get("notes", [])), "warnings": []}  # fmt: skip
    return accel


def _accel_or_refusal(session: Session, cfg: Config):
    """The accelerometer calibrated here, or ``(None, refusal)`` when ``[accel] solver =
    "auto"`` finds the poses cannot determine it but the gyro may calibrate without it (the
    facade calibrates what the session determines, issue 9.4); any other refusal is raised."""
    if cfg.accel.solver == "none":
        return None, None
    try:
        return calibrate_accel(session, cfg), None
    except DesignError as exc:
        if session.gyro is None or cfg.gyro.solver == "none" or not (
            session.rotation_segments() or cfg.gyro.solver in ("full", "static", "dynamic")
        ):
            raise
        refusal = DesignError(
            f"{exc}; to calibrate only the gyro from this session, pass an earlier calibration "
            "of this unit's accelerometer: --accel CAL.json (or a session file that stores one)"
        )
        if cfg.accel.solver != "auto":
            raise refusal from None
        return None, (exc, refusal)


def _gyro_without_accel(session: Session, cfg: Config, refusal):
    """The gyro of a session whose accelerometer ``"auto"`` could not determine: the gyro
    section (None when it cannot do without the accelerometer either: the facade then raises
    the accelerometer's refusal) and the note that says why the accelerometer was left out
    and what would determine it (issue 9.6)."""

    exc, _ = refusal
    try:
        if cfg.gyro.solver == "auto":
            gyro, _ = calibrate_gyro_auto(session, cfg, None)
        else:
            gyro = calibrate_gyro(session, cfg, None)
    except ImucalError:
        gyro = None
    reason = _reason(session, exc)
    if gyro is None:
        return None, (f"accel not calibrated: {reason}; with an earlier calibration of this "
                      "unit's accelerometer (--accel CAL.json) the rest of the session may "
                      "calibrate the gyro")  # fmt: skip
    frame = gyro.extra.get("frame") or "the frame of the turns' labelled axes"
    note = (f"accel not calibrated; the gyro was calibrated without it, in {frame}. To "
            "calibrate the accelerometer with this session, pass an earlier calibration of "
            f"this unit's: --accel CAL.json. Why: {reason}")  # fmt: skip
    return gyro, note


def _reason(session: Session, exc: Exception) -> str:
    """A refusal's message without the session's name in front."""
    return str(exc).removeprefix(f"{session_name(session)}: ")


def _gyro_or_note(session: Session, cfg: Config, accel: SensorCalibration | None):
    """The gyro (``[gyro] solver``), or, with ``"auto"``, ``(None, note, refusal)`` when the
    session's turns cannot determine it (issue 24.2: the other sensors are still saved; the
    note says why and which capture would add it)."""
    if cfg.gyro.solver != "auto":
        return calibrate_gyro(session, cfg, accel), None, None
    try:
        gyro, note = calibrate_gyro_auto(session, cfg, accel)
    except DesignError as exc:
        return None, f"gyro not calibrated: {_reason(session, exc)}", exc
    return gyro, note, None


def _mag_or_note(session: Session, cfg: Config, accel: SensorCalibration | None):
    """The magnetometer, or ``(None, note, refusal)`` when its readings cannot determine it
    (too little of the sphere, clipped, in one plane): the other sensors are still saved."""
    try:
        return calibrate_mag(session, cfg, accel), None, None
    except DesignError as exc:
        return None, f"mag not calibrated: {_reason(session, exc)}", exc


def _gyro_and_mag(session: Session, cfg: Config, accel, refusal, with_mag: bool):
    """The gyro and magnetometer sections (each None when left out) and the notes per sensor
    (``{"accel", "gyro", "mag"}``: why it was left out); the most telling refusal when
    nothing at all calibrates (issue 24.2: otherwise what calibrates is saved)."""
    gyro_refusal, accel_note = None, None
    if refusal is not None:
        (gyro, accel_note), gyro_note = _gyro_without_accel(session, cfg, refusal), None
        if gyro is None and cfg.gyro.solver != "none":
            gyro_note = ("gyro not calibrated: its turns are measured with the accelerometer, "
                         "which this session does not determine (see accel): pass an earlier "
                         "calibration of it, --accel CAL.json")  # fmt: skip
    else:
        gyro, gyro_note, gyro_refusal = _gyro_or_note(session, cfg, accel)
    mag, mag_note, mag_refusal = _mag_or_note(session, cfg, accel) if with_mag else (None,) * 3
    if accel is None and gyro is None and mag is None:
        if refusal is not None and cfg.gyro.solver != "none":
            _refuse_turn_session(session, cfg, _reason(session, refusal[0]))
        for failed in (refusal and refusal[1], gyro_refusal, mag_refusal):
            if failed is not None:
                raise failed from None
        raise DesignError(
            f"{session_name(session)}: nothing to calibrate: no still poses with accelerometer "
            f"data, and the gyro was not calibrated ({gyro_note or '[gyro] solver is none'})"
        )
    return gyro, mag, {"accel": accel_note, "gyro": gyro_note, "mag": mag_note}


def _refuse_turn_session(session: Session, cfg: Config, why: str) -> None:
    """A session of turns between still periods (qureshi-axes, free:N: a gyro procedure,
    Qureshi & Golnaraghi Fig. 2, with the accelerometer calibrated first) whose still periods
    do not determine the accelerometer, so that nothing calibrates: refused with what the
    turns are for and what would calibrate them (issue 24.7d: the accelerometer's refusal
    spoke of poses and plan random:12 alone; ``why`` is that refusal, kept at the end).
    Returns where the session is not such."""
    turns = session.rotation_segments()
    statics = session.static_segments()
    if 2 * len(turns) < 9 or session.accel is None or not statics:
        return
    means = np.array([session.accel[s.start : s.stop].mean(axis=0) for s in statics])
    distinct = count_distinct(unit(means), cfg.accel.min_separation_deg)
    raise DesignError(
        f"{session_name(session)}: its {len(turns)} turns between still periods calibrate the "
        "gyro against an accelerometer calibration, which this session cannot give (its "
        f"{len(statics)} still periods point in {distinct} distinct directions, the "
        "gravity-magnitude model needs 9): pass an earlier calibration of this unit's "
        "accelerometer, --accel CAL.json (plan six or qureshi18), or capture turns whose still "
        "periods point in 9 or more directions, which calibrate both (plan qureshi-axes:3 or "
        f"more, free:12 or more). The accelerometer: {why}"
    )


def _prepare(
    session: Session, cfg: Config, warmup: list[Session] | None
) -> tuple[Session, dict, dict]:  # fmt: skip
    """The session the solvers see: the sample clock corrected (issue 17.2) and the raw data
    compensated to the temperature model's reference (issue 17.1). Returns it, the
    temperature models per sensor, and root fields (the clock estimate, notes)."""

    session, clock = correct_clock(session, cfg)
    models, note = temperature_models(session, cfg, warmup)
    root: dict = {}
    if clock is not None:
        root["sample_clock"] = clock
    if note:
        root["temperature_note"] = note
    return (compensate(session, models) if models else session), models, root


def calibrate_session(
    session: Session, cfg: Config, *, name: str | None = None,
    accel: SensorCalibration | None = None, warmup: list[Session] | None = None,
) -> Calibration:  # fmt: skip
    """Calibrate every sensor the config asks for; returns the calibration (not yet saved).

    The magnetometer is calibrated whenever the session has one (``[mag] solver = "none"``
    turns it off); a session with a magnetometer and no accelerometer skips the accelerometer.
    ``name`` is what the calibration records as its session (default: the session's path).
    ``accel``: an accelerometer calibrated earlier (``--accel``): used as it is, and copied
    into the result, instead of calibrating the accelerometer from this session.
    ``warmup``: still warm-up recordings of the same unit that give the bias temperature
    model (:mod:`imucal_cli.pipeline.temperature`).
    """

    warn_absent_sensors(session, cfg, accel_given=accel is not None, warmup=bool(warmup))
    with_mag = session.mag is not None and cfg.mag.solver != "none"
    if cfg.accel.solver == "none" and cfg.gyro.solver == "none" and accel is None and not with_mag:
        raise ConfigError("the config calibrates nothing: [accel] and [gyro] solver are both none")

    check_channels(session, cfg, skip=("accel",) if accel is not None else ())  # issue 24.6
    session, segmented = with_segments(session)
    session, models, root = _prepare(session, cfg, warmup)
    given, refusal = accel, None
    if accel is None:
        run_accel = cfg.accel.solver != "none" and not (session.accel is None and with_mag)
        accel, refusal = _accel_or_refusal(session, cfg) if run_accel else (None, None)
        segmented_accel = True
    else:
        session, accel = given_accel(session, accel)
        segmented_accel = False
    gyro, mag, notes = _gyro_and_mag(session, cfg, accel, refusal, with_mag)
    for sec in (accel if segmented_accel else None, gyro, mag):
        if sec is not None and segmented:
            sec.extra.setdefault("notes", []).insert(0, segmented)
    attach(accel if segmented_accel else None, models.get("accel"))
    attach(gyro, models.get("gyro"))
    if gyro is not None and root.get("sample_clock", {}).get("applied"):
        gyro.extra["sample_clock_scale"] = root["sample_clock"]["scale"]
        gyro.extra["sample_clock"] = root["sample_clock"]
    extra = {"toolkit_version": __version__, "config": cfg.to_dict(), **root}
    for kind, note in notes.items():
        if note:
            extra[f"{kind}_note"] = note
    extra.update(completeness(session, {"accel": accel if given is None else given,
                                        "gyro": gyro, "mag": mag}, notes))  # fmt: skip
    if session.sensor:
        extra["sensor"] = session.sensor
    if session.source:  # "simulator", "serial:...": the report's context (paper figures or not)
        extra["source"] = session.source
    return Calibration(
        accel=accel if given is None else given,
        gyro=gyro,
        mag=mag,
        session=name or session_name(session),
        created=utc_now_iso(),
        extra=extra,
    )


def _changed(value, default, path: str = "") -> list[str]:
    """The dotted keys where a config (a dataclass) differs from its defaults."""

    if is_dataclass(value):
        return [k for f in fields(value)
                for k in _changed(getattr(value, f.name), getattr(default, f.name),
                                  f"{path}.{f.name}" if path else f.name)]  # fmt: skip
    return [] if value == default else [path]


def warn_absent_sensors(session: Session, cfg: Config, *, accel_given: bool = False,
                        warmup: bool = False) -> None:
    """Warn (:class:`ImucalWarning`, ``imucal: warning: ...``) about options for a sensor the
    session has no data for (issue 24.7): a ``[gyro]`` section for a session without
    ``/raw/gyro``, ``[mag] field_uT`` without ``/raw/mag``, ``--model`` or ``gravity`` without
    an accelerometer, ``--accel CAL.json`` for a session with neither a gyro nor a
    magnetometer (nothing uses it). They change nothing; the user should know. With
    ``warmup`` recordings the ``[temperature]`` options shape their model: not warned."""

    where = session_name(session)
    checks = [("accel", session.accel, cfg.accel, AccelConfig(), "accelerometer"),
              ("gyro", session.gyro, cfg.gyro, GyroConfig(), "gyroscope"),
              ("mag", session.mag, cfg.mag, MagConfig(), "magnetometer"),
              ("temperature", session.temperature if not warmup else True, cfg.temperature,
               TemperatureConfig(), "temperature")]  # fmt: skip
    flags = {"accel.gravity.model": " (--model)"}
    for name, data, section, default, what in checks:
        keys = [f"[{name}] {k}{flags.get(f'{name}.{k}', '')}" for k in _changed(section, default)]
        if name == "accel" and cfg.gravity is not None:
            keys.append("gravity (--gravity)")
        if data is None and keys:
            raw = "raw/temperature" if name == "temperature" else f"raw/{name}"
            warnings.warn(f"{where} has no {what} (/{raw}): {', '.join(keys)} ignored",
                          ImucalWarning, stacklevel=2)  # fmt: skip
    if accel_given and session.gyro is None and session.mag is None:
        warnings.warn(f"{where} has neither a gyroscope nor a magnetometer: --accel CAL.json "
                      "(used to measure turns and align a magnetometer) is only copied into "
                      "the calibration", ImucalWarning, stacklevel=2)  # fmt: skip


def completeness(session: Session, sections: dict, notes: dict) -> dict:
    """``{"complete": bool, "left_out": {sensor: note}}`` (issue 24.2): a sensor the session
    has data for (``/raw/accel``, ``/raw/gyro``, ``/raw/mag``) that was asked for (its solver
    is not ``"none"``) and is not in the calibration is left out, with the note that says why
    and which capture would add it. ``complete`` is true when none is."""
    has = {"accel": session.accel, "gyro": session.gyro, "mag": session.mag}
    left = {kind: note for kind, note in notes.items()
            if note and sections.get(kind) is None and has[kind] is not None}  # fmt: skip
    return {"complete": not left, "left_out": left}


def suspect_error(cal: Calibration) -> SolverError | None:
    """A :class:`SolverError` describing what stops a save (results outside physical sense, a
    fit far above the noise), or None when clean. A section that lists ``blocking`` warnings
    stops on those only (its other warnings are said, not refused); otherwise every warning
    stops it."""
    blocking = [
        w
        for sec in cal.sections().values()
        for w in sec.extra.get("blocking", sec.extra.get("warnings", []))
    ]
    if not blocking:
        return None
    more = f" (and {len(blocking) - 1} more)" if len(blocking) > 1 else ""
    return SolverError(
        f"result outside physical sense, not saved: {blocking[0]}{more}; "
        "check the units and the capture, or pass --force to save it with these warnings"
    )


def default_output(session_path: Path) -> Path:
    """``run3.h5`` -> ``run3.cal.json`` beside it."""
    return session_path.with_suffix(".cal.json")
