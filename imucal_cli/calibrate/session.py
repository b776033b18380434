"""The calibrate step: a session and a config in, a :class:`Calibration` with its diagnostics out.

The config chooses a solver per sensor; each lives in :mod:`imucal_cli.calibrate` and returns
the sensor's section of the calibration JSON (layout in DEVELOPERS.md). Nothing here prints.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path

import numpy as np

from imucal_cli import __version__
from imucal_cli.calibrate.accel.estimators import AccelDesign
from imucal_cli.calibrate.channels import check_channels
from imucal_cli.calibrate.clock import correct_clock
from imucal_cli.calibrate.common import (  # noqa: F401 (re-exported for callers)
    StaticPoses,
    check_design,
    nominal_sensor,
    session_name,
    static_poses,
    stored_accel_hint,
    with_segments,
)
from imucal_cli.calibrate.gyro import partial as gyro_partial
from imucal_cli.calibrate.gyro.estimators import GyroDesign
from imucal_cli.calibrate.mag import MagDesign
from imucal_cli.calibrate.registry import NotChosen, choose
from imucal_cli.calibrate.thermal import (
    attach,
    compensate,
    given_accel,
    temperature_models,
    widen_accel,
)
from imucal_cli.design.poses import count_distinct, unit
from imucal_cli.errors import (
    ConfigError,
    DesignError,
    ImucalError,
    ImucalWarning,
    InputError,
    SolverError,
)
from imucal_cli.formats.calibration import calibration_from_json, read_calibration
from imucal_cli.formats.config import (
    AccelConfig,
    Config,
    GyroConfig,
    MagConfig,
    TemperatureConfig,
)
from imucal_cli.formats.session import Session, read_session, utc_now_iso
from imucal_cli.model.calibration import Calibration, SensorCalibration
from imucal_cli.model.codec import build
from imucal_cli.model.parts import By, Choice


def calibrate_accel(session: Session, cfg: Config, prior=None) -> SensorCalibration | None:
    """Run the configured accelerometer solver (``[accel] solver``) on a session; ``"auto"``
    chooses (:func:`~imucal_cli.calibrate.registry.choose`) and may find nothing to calibrate
    (None). ``prior``: an earlier calibration's prior (``--prior``) for the partial fit."""
    try:
        return _run_accel(session, cfg, prior)
    except DesignError as exc:  # name what the user already has (issue 9.6)
        hint = stored_accel_hint(session)
        if not hint:
            raise
        raise DesignError(f"{exc}{hint}") from None


def _run_accel(session: Session, cfg: Config, prior=None) -> SensorCalibration | None:
    solver = cfg.accel.solver
    if solver == "auto" and (session.accel is None or not session.static_segments()):
        return None
    design = AccelDesign(session, cfg, prior)
    chosen = choose("accel", design, solver, config_reason="[accel] solver")
    if isinstance(chosen, NotChosen):
        raise DesignError(design.refusal())
    sec = chosen.estimator.fit(design)
    sec.choice = chosen.choice
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
        return calibrate_gyro_auto(session, cfg, accel).section
    if solver == "none":
        return None
    design = GyroDesign(session, cfg, accel)
    return choose("gyro", design, solver).estimator.fit(design)


def calibrate_mag(
    session: Session, cfg: Config, accel: SensorCalibration | None
) -> SensorCalibration | None:
    """Run the ``[mag]`` solver when the session has ``/raw/mag`` (None otherwise, or with
    ``solver = "none"``); the accelerometer of the same run aligns it."""
    if session.mag is None or cfg.mag.solver == "none":
        return None
    design = MagDesign(session, cfg, accel)
    return choose("mag", design, cfg.mag.solver).estimator.fit(design)


@dataclass(frozen=True)
class Outcome:
    """What calibrating one sensor gave: its section, or why it was left out.

    Attributes
    ----------
    section : SensorCalibration or None
    note : str or None
        Why the sensor was left out (``"gyro not calibrated: ..."``), or said beside it.
    refusal : ImucalError or None
        The error to raise when nothing at all calibrates (the most telling one).
    undetermined : bool
        The solver ran and its result was left out (its std, the known angles against
        gravity): ``note`` says why, and no other reason replaces it.
    """

    section: SensorCalibration | None = None
    note: str | None = None
    refusal: ImucalError | None = None
    undetermined: bool = False  # the solver ran; its result was left out (``note`` says why)


def calibrate_gyro_auto(
    session: Session, cfg: Config, accel: SensorCalibration | None, gyro_prior=None
) -> Outcome:
    """``[gyro] solver = "auto"``: the most accurate solver the session supports
    (:mod:`imucal_cli.calibrate.gyro.estimators`); no section when the session has no gyro, or
    no rotations that it did not capture on purpose (the note says why). A session with
    rotation segments that no solver can use is refused with the chosen solver's reason.
    Still periods without usable rotations: the bias measured, the matrix assumed
    (:func:`partial_gyro`, ``gyro_prior``: ``--prior``'s gyro)."""

    if session.gyro is None:
        return Outcome(note="gyro not calibrated: the session has no /raw/gyro")
    design = GyroDesign(session, cfg, accel)
    chosen = choose("gyro", design, "auto")
    if isinstance(chosen, NotChosen):
        why = chosen.refusals["full"]
        return Outcome(note=f"gyro not calibrated: {why.reason} ({why.capture})")
    solver, why = chosen.choice.solver, chosen.choice.reason
    try:
        sec = chosen.estimator.fit(design)
    except ImucalError:
        if session.rotation_segments():
            raise  # turns captured on purpose: say why they cannot calibrate
        return partial_gyro(session, cfg, gyro_prior, "no usable rotations (the gyro needs "
                            "turns between still periods)")  # fmt: skip
    if sec.undetermined:  # issue 10.2: not saved silently
        return Outcome(note=f"gyro not calibrated: {sec.undetermined} (to save it with "
                            f'these std: [gyro] solver = "{solver}" and --force)',
                       undetermined=True)  # fmt: skip
    sec.notes = [f'solver "{solver}" chosen by [gyro] solver = "auto": {why}',
                 *(sec.notes or [])]  # fmt: skip
    sec.choice = chosen.choice
    return Outcome(sec)


def partial_gyro(session: Session, cfg: Config, gyro_prior, why: str,
                 extra: str | None = None) -> Outcome:  # fmt: skip
    """The gyro of a session whose turns cannot determine its model (issue 27.3,
    :mod:`imucal_cli.calibrate.gyro.partial`): the bias measured by the still periods, the
    matrix held at ``gyro_prior`` (``--prior``'s gyro) or at nominal values; left out (the
    note: ``why``, the bias measured and what would save it) where no nominal sensitivity is
    known, or with no still period. ``extra``: what the turns are for (capture words)."""
    note = f"gyro not calibrated: {why}"
    if session.gyro is None or cfg.gyro.solver != "auto" or not session.static_segments():
        return Outcome(note=note)
    prior = gyro_prior
    if prior is None:
        s = gyro_partial.nominal_sensitivity(session, cfg)
        if s is None:
            words = gyro_partial.bias_words(session, cfg)
            return Outcome(note=f"{note}; {words}" if words else note)
        prior = gyro_partial.nominal_prior(s)
    sec = gyro_partial.partial_gyro_section(session, cfg, prior, why, extra)
    sec.choice = Choice("partial", By.AUTO, f"the turns cannot determine the gyro's model "
                        f"({why}): the still periods' bias measured, the matrix "
                        "assumed")  # fmt: skip
    return Outcome(sec)


def load_accel(path: str | Path) -> SensorCalibration:
    """The accelerometer section of an earlier calibration (issue 9.5): a calibration JSON, or
    a session file whose newest stored calibration has one.

    Raises
    ------
    InputError
        Unreadable file, or no accelerometer section in it.
    """

    path = Path(path)
    accel = _earlier_section(path, "accel")
    if accel is None:
        raise InputError(f"{path}: no stored calibration with an accelerometer section"
                         if _is_session(path) else
                         f"{path}: this calibration has no accelerometer section")  # fmt: skip
    accel.notes = [f"from {path} (not re-calibrated here)", *(accel.notes or [])]
    accel.warnings = []
    return accel


def load_gyro(path: str | Path) -> SensorCalibration | None:
    """The gyro section of an earlier calibration (``--prior``: its matrix the prior of a gyro
    whose turns cannot determine it), or None where it has none: a calibration JSON, or a
    session file's newest stored calibration with one."""
    return _earlier_section(Path(path), "gyro")


def _is_session(path: Path) -> bool:
    return path.suffix.lower() in (".h5", ".hdf5")


def _earlier_section(path: Path, sensor: str) -> SensorCalibration | None:
    """Section ``sensor`` of a calibration JSON, or of the newest calibration stored in a
    session file that has one; None where there is none."""
    if not _is_session(path):
        return getattr(read_calibration(path), sensor)
    stored = read_session(path).calibrations
    found = [getattr(calibration_from_json(stored[k], f"{path}:/calibrations/{k}"), sensor)
             for k in sorted(stored)]  # fmt: skip
    found = [sec for sec in found if sec is not None]
    return found[-1] if found else None


def _accel_outcome(session: Session, cfg: Config, prior=None) -> Outcome:
    """The accelerometer calibrated here; or, when ``[accel] solver = "auto"`` finds the poses
    cannot determine it but the gyro may calibrate without it (the facade calibrates what the
    session determines, issue 9.4), no section, the reason as its note and the refusal (raised
    when nothing else calibrates); any other refusal is raised."""
    if cfg.accel.solver == "none":
        return Outcome()
    try:
        return Outcome(calibrate_accel(session, cfg, prior))
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
        return Outcome(note=_reason(session, exc), refusal=refusal)


def _gyro_without_accel(session: Session, cfg: Config, accel: Outcome
                        ) -> tuple[Outcome, Outcome]:  # fmt: skip
    """The accelerometer and gyro of a session whose accelerometer ``"auto"`` could not
    determine: the gyro calibrated without it where it can (else left out: the facade then
    raises the accelerometer's refusal), and the accelerometer's note saying why it was left
    out and what would determine it (issue 9.6)."""

    left = Outcome()
    try:
        if cfg.gyro.solver == "auto":
            left = calibrate_gyro_auto(session, cfg, None)
            gyro = left.section
        else:
            gyro = calibrate_gyro(session, cfg, None)
    except ImucalError:
        gyro = None
    reason = accel.note
    if gyro is None and left.undetermined:  # its turns calibrated it, and it was left out
        return Outcome(note=f"accel not calibrated: {reason}", refusal=accel.refusal), left
    if gyro is None:
        return Outcome(
            note=f"accel not calibrated: {reason}; with an earlier calibration of this unit's "
            "accelerometer (--accel CAL.json) the rest of the session may calibrate the gyro",
            refusal=accel.refusal,
        ), Outcome(note=None if cfg.gyro.solver == "none" else (
            "gyro not calibrated: its turns are measured with the accelerometer, which this "
            "session does not determine (see accel): pass an earlier calibration of it, "
            "--accel CAL.json"))  # fmt: skip
    frame = gyro.frame or "the frame of the turns' labelled axes"
    note = (f"accel not calibrated; the gyro was calibrated without it, in {frame}. To "
            "calibrate the accelerometer with this session, pass an earlier calibration of "
            f"this unit's: --accel CAL.json. Why: {reason}")  # fmt: skip
    return Outcome(note=note, refusal=accel.refusal), Outcome(gyro)


def _gyro_beside_partial(session: Session, cfg: Config, gyro_prior=None) -> Outcome:
    """The gyro of a session whose accelerometer is calibrated only in part (issue 27.3):
    calibrated as without an accelerometer (:func:`_gyro_without_accel`), since the assumed
    terms are not measurements to measure its turns with: the gyro comes out as it did before
    the partial fit existed; where that leaves it out, its bias measured by the still periods
    and its matrix assumed (:func:`partial_gyro`), the words of what its turns are for (a
    turn session, issue 24.7d) in what would determine the rest."""
    why = "its poses determine the accelerometer only in part"
    _, gyro = _gyro_without_accel(session, cfg, Outcome(note=why, refusal=DesignError(why)))
    if gyro.section is not None or not gyro.note:
        return gyro
    if gyro.undetermined:  # the solver's own reason (known angles that gravity contradicts)
        return partial_gyro(session, cfg, gyro_prior,
                            gyro.note.removeprefix("gyro not calibrated: "))  # fmt: skip
    turns_for = None
    if cfg.gyro.solver != "none":
        try:  # a session of turns between still periods: what they are for (issue 24.7d)
            _refuse_turn_session(session, cfg, why)
        except DesignError as exc:
            turns_for = _reason(session, exc)
    reason = turns_for or gyro.note.removeprefix("gyro not calibrated: ").replace(
        "which this session does not determine (see accel)",
        "which this session determines only in part (see accel)")  # fmt: skip
    return partial_gyro(session, cfg, gyro_prior, reason, turns_for)


def _reason(session: Session, exc: Exception) -> str:
    """A refusal's message without the session's name in front."""
    return str(exc).removeprefix(f"{session_name(session)}: ")


def _gyro_outcome(session: Session, cfg: Config, accel: SensorCalibration | None,
                  gyro_prior=None) -> Outcome:
    """The gyro (``[gyro] solver``), or, with ``"auto"``, no section, a note and the refusal
    when the session's turns cannot determine it (issue 24.2: the other sensors are still
    saved; the note says why and which capture would add it)."""
    if cfg.gyro.solver != "auto":
        return Outcome(calibrate_gyro(session, cfg, accel))
    try:
        return calibrate_gyro_auto(session, cfg, accel, gyro_prior)
    except DesignError as exc:
        return Outcome(note=f"gyro not calibrated: {_reason(session, exc)}", refusal=exc)


def _mag_outcome(session: Session, cfg: Config, accel: SensorCalibration | None) -> Outcome:
    """The magnetometer, or no section, a note and the refusal when its readings cannot
    determine it (too little of the sphere, clipped, in one plane): the other sensors are
    still saved."""
    try:
        return Outcome(calibrate_mag(session, cfg, accel))
    except DesignError as exc:
        return Outcome(note=f"mag not calibrated: {_reason(session, exc)}", refusal=exc)


def _outcomes(session: Session, cfg: Config, accel: Outcome, with_mag: bool,
              gyro_prior=None) -> dict[str, Outcome]:  # fmt: skip
    """Every sensor's outcome (``{"accel", "gyro", "mag"}``: its section, or why it was left
    out), given the accelerometer's; the most telling refusal raised when nothing at all
    calibrates (issue 24.2: otherwise what calibrates is saved)."""
    accel_why = accel.note if accel.refusal is not None else None  # the accelerometer's own
    if accel.refusal is not None:
        accel, gyro = _gyro_without_accel(session, cfg, accel)
    elif accel.section is not None and accel.section.partial is not None:
        gyro = _gyro_beside_partial(session, cfg, gyro_prior)
    else:
        gyro = _gyro_outcome(session, cfg, accel.section, gyro_prior)
    mag = _mag_outcome(session, cfg, accel.section) if with_mag else Outcome()
    found = {"accel": accel, "gyro": gyro, "mag": mag}
    if all(o.section is None for o in found.values()):
        if accel_why is not None and cfg.gyro.solver != "none":
            _refuse_turn_session(session, cfg, accel_why)
        for o in found.values():
            if o.refusal is not None:
                raise o.refusal from None
        raise DesignError(
            f"{session_name(session)}: nothing to calibrate: no still poses with accelerometer "
            f"data, and the gyro was not calibrated ({gyro.note or '[gyro] solver is none'})"
        )
    return found


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
    temperature models per sensor, and members of the calibration's root (the clock estimate,
    notes)."""

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
    prior=None, gyro_prior=None,
) -> Calibration:  # fmt: skip
    """Calibrate every sensor the config asks for; returns the calibration (not yet saved).

    The magnetometer is calibrated whenever the session has one (``[mag] solver = "none"``
    turns it off); a session with a magnetometer and no accelerometer skips the accelerometer.
    ``name`` is what the calibration records as its session (default: the session's path).
    ``accel``: an accelerometer calibrated earlier (``--accel``): used as it is, and copied
    into the result, instead of calibrating the accelerometer from this session.
    ``warmup``: still warm-up recordings of the same unit that give the bias temperature
    model (:mod:`imucal_cli.calibrate.thermal`).
    ``prior``: an earlier accelerometer calibration of the unit as a prior
    (:func:`~imucal_cli.calibrate.accel.partial.calibration_prior`, ``--prior``): where the
    poses cannot fix the whole model, what they do not determine is held at its values and
    std instead of the nominal ones (issue 27.3); unused (a warning) where they can.
    ``gyro_prior``: an earlier gyro calibration's matrix as the prior
    (:func:`~imucal_cli.calibrate.gyro.partial.calibration_prior`, ``--prior``) of a gyro
    whose turns cannot determine it: the matrix held there instead of nominal values.
    """

    warn_absent_sensors(session, cfg, accel_given=accel is not None, warmup=bool(warmup))
    with_mag = session.mag is not None and cfg.mag.solver != "none"
    if cfg.accel.solver == "none" and cfg.gyro.solver == "none" and accel is None and not with_mag:
        raise ConfigError("the config calibrates nothing: [accel] and [gyro] solver are both none")

    check_channels(session, cfg, skip=("accel",) if accel is not None else ())  # issue 24.6
    session, segmented = with_segments(session)
    session, models, root = _prepare(session, cfg, warmup)
    given = accel
    if accel is None:
        run_accel = cfg.accel.solver != "none" and not (session.accel is None and with_mag)
        found = _accel_outcome(session, cfg, prior) if run_accel else Outcome()
        widen_accel(found.section, models.get("accel"))  # before the gyro reads it
        segmented_accel = True
        if prior is not None and found.section is not None and found.section.partial is None:
            warnings.warn(f"{session_name(session)}: its poses determine the whole "
                          "accelerometer model, so --prior was not used", ImucalWarning,
                          stacklevel=2)  # fmt: skip
    else:
        session, accel = given_accel(session, accel)
        found, segmented_accel = Outcome(accel), False
    outcomes = _outcomes(session, cfg, found, with_mag, gyro_prior)
    accel, gyro, mag = (outcomes[k].section for k in ("accel", "gyro", "mag"))
    notes = {kind: o.note for kind, o in outcomes.items()}
    for sec in (accel if segmented_accel else None, gyro, mag):
        if sec is not None and segmented:
            sec.notes = [segmented, *(sec.notes or [])]
    attach(accel if segmented_accel else None, models.get("accel"))
    attach(gyro, models.get("gyro"))
    if gyro is not None and "sample_clock" in root and root["sample_clock"].applied:
        gyro.sample_clock_scale = root["sample_clock"].scale
        gyro.sample_clock = root["sample_clock"]
    root.update({f"{kind}_note": note for kind, note in notes.items() if note})
    root.update(completeness(session, {"accel": accel if given is None else given,
                                       "gyro": gyro, "mag": mag}, notes))  # fmt: skip
    cal = build(
        Calibration,
        accel=accel if given is None else given,
        gyro=gyro,
        mag=mag,
        session=name or session_name(session),
        created=utc_now_iso(),
        toolkit_version=__version__,
        config=cfg.to_dict(),
        **root,
    )
    cal.sensor = session.sensor or None
    cal.source = session.source or None  # "simulator", "serial:...": the report's context
    return cal


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
    and which capture would add it. ``complete`` is true when none is, and no section holds
    assumed parameters (``partial``, issue 27.3: a design that determines part of a model)."""
    has = {"accel": session.accel, "gyro": session.gyro, "mag": session.mag}
    left = {kind: note for kind, note in notes.items()
            if note and sections.get(kind) is None and has[kind] is not None}  # fmt: skip
    partly = any(getattr(sec, "partial", None) is not None for sec in sections.values())
    return {"complete": not left and not partly, "left_out": left}


def suspect_error(cal: Calibration) -> SolverError | None:
    """A :class:`SolverError` describing what stops a save (results outside physical sense, a
    fit far above the noise), or None when clean. A section that lists ``blocking`` warnings
    stops on those only (its other warnings are said, not refused); otherwise every warning
    stops it."""
    blocking = [
        w
        for sec in cal.sections().values()
        for w in (sec.blocking if sec.blocking is not None else sec.warnings or [])
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
