"""The gyro section of a known-angle calibration (:mod:`.known`): its parameters, the rows of
its turns, its sensitivity axes, and what it warns of (a disagreement with gravity, axes that
limit the rates, too few spare equations)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from imucal_cli.calibrate.common import rms
from imucal_cli.calibrate.gyro.full import design_warning, gain_std, parameter_rows, rate_std
from imucal_cli.calibrate.gyro.known_gravity import gravity_disagreement
from imucal_cli.calibrate.gyro.rotations import _frame, gyro_checks
from imucal_cli.calibrate.gyro.turns import AXES, MODEL_EQUATION_G, GyroData
from imucal_cli.errors import DesignError
from imucal_cli.estimators.gyro import known as gyro_known
from imucal_cli.model.calibration import MODEL_EQUATION, SensorCalibration
from imucal_cli.model.codec import build
from imucal_cli.model.gyro import GSensitivityTest, GyroCalibration, RotationRow
from imucal_cli.planning.information import axes_std


def _axes_limit(res, known, notes) -> str | None:
    """Why turns of known angle alone leave the gyro's rates uncertain, when their axes do it
    (issue 24.5: a Ferraris session's 3 full turns fix the gains to a fraction of a percent,
    its axes only as well as their labels were placed, 2-3 degrees by hand): the rate std
    the axes alone leave (each axis moved by its std across it, the turns' closed form
    refitted), said with the gains' std and what would tie the axes better. None where the
    axes are not what limits it."""
    if len(known.t) < 3 or not any("axis labelled" in n for n in notes):
        return None
    n = known.axis
    cov = np.zeros((9, 9))
    try:
        M0 = gyro_known.closed_form(known, res.b)
        for k in range(len(n)):
            t1 = np.cross(n[k], np.eye(3)[np.argmin(np.abs(n[k]))])
            t1 /= np.linalg.norm(t1)
            for t in (t1, np.cross(n[k], t1)):
                axis = n.copy()
                axis[k] = n[k] + known.axis_sigma[k] * t
                axis[k] /= np.linalg.norm(axis[k])
                dM = gyro_known.closed_form(replace(known, axis=axis), res.b) - M0
                cov += np.outer(dM.ravel(), dM.ravel())
    except DesignError:
        return None
    axes = rate_std(res.M, cov)
    total = rate_std(res.M, res.cov[3:12, 3:12])
    if axes < 0.5 * total:
        return None
    gains = np.linalg.norm(np.linalg.inv(res.M), axis=1)
    g_std = float(np.max(gain_std(res.M, res.cov[3:12, 3:12]) / gains))
    placed = float(np.degrees(np.sqrt(2) * np.max(known.axis_sigma)))
    return (f"the turns of known angle fix its gains to {100 * g_std:.2g} %, but its axes only "
            f"as well as their labels sit on the unit ({placed:.2g} deg RMS, as the "
            f"accelerometer's labelled poses measured the placement), which alone leaves "
            f"{100 * axes:.2g} %: place the unit square on each face (a square block against a "
            "ruler, a jig), or keep the moves between the faces as turns (imucal capture and "
            "imucal import without --sections segment them): gravity then ties the axes")


#: Fewer spare equations than this in the known turns alone: they cannot check each other.
MIN_SPARE = 3


def _spare_text(data: GyroData, known, used, assumed: bool, with_gravity: bool
                ) -> str | None:  # fmt: skip
    """Issue 10.3: known turns alone (no turns measured by gravity) with too few spare
    equations (3 per turn, 9 terms of the matrix; the still periods give the bias): their
    residuals cannot show a wrong angle or axis. A warning where the axes' std are assumed
    (no accelerometer): then nothing in the data checks the stated std; a note where the
    accelerometer measured them."""
    if with_gravity:
        return None
    spare = 3 * len(used) - 9
    if spare >= MIN_SPARE:
        return None
    axis_deg = float(np.degrees(np.sqrt(2) * np.max(known.axis_sigma)))
    angle_deg = float(np.degrees(np.max(known.angle_sigma)))
    basis = (f"the assumed errors (axis {axis_deg:.2g} deg, angle {angle_deg:.2g} deg), not on "
             "the data" if assumed else "the measured axes and the stated angle error "
             f"({angle_deg:.2g} deg)")  # fmt: skip
    return (f"{len(used)} turns of known angle for the 9 terms of the gyro's matrix: "
            f"{max(spare, 0)} spare equations, so the turns cannot check each other (a wrong "
            f"angle or axis would go unnoticed) and the stated std rest on {basis}; turn "
            "about each axis once more (or add turns between still periods) to check them")


def section(data: GyroData, res, known, used, g_test, uncertainty, assumed: bool, verdict
             ) -> SensorCalibration:  # fmt: skip
    units, n = data.units_in, len(res.std)
    parameters = parameter_rows(res, units)
    rotations = _rotation_rows(res, known, used, verdict)
    data.warnings += verdict.blocking
    data.notes += verdict.notes
    with_gravity = verdict.comparison.turns_between_still_periods == "used"
    undetermined = design_warning(data, uncertainty, len(used) + len(data.turns),
                                  why=None if with_gravity else _axes_limit(res, known, notes=
                                                                            data.notes))
    S = np.linalg.inv(res.M)
    gains = np.linalg.norm(S, axis=1)
    data.warnings += gyro_checks(data.session, data.cfg, gains, units)
    disagree = gravity_disagreement(data.session, data.accel_cal, used, known.axis, res.M,
                                    res.b, res.cov[3:12, 3:12], known.axis_sigma)  # fmt: skip
    if disagree:  # issue 24.5: named (a clipped known turn explains it), auto leaves it out
        clip = [w for w in data.warnings if w.startswith("a turn of known angle reaches")]
        disagree = f"{clip[0]}; so {disagree}" if clip else disagree
        data.warnings[:] = [disagree] + [w for w in data.warnings if w not in clip]
        undetermined = disagree if not undetermined else f"{disagree}; also {undetermined}"
    elif undetermined:
        data.warnings.append(undetermined)
    blocking = list(data.warnings)  # the rest are said, not refused (issue 10.3)
    spare = _spare_text(data, known, used, assumed, with_gravity)
    if spare and not assumed:  # std measured (the accelerometer's placement, the vertical)
        data.notes.append(spare)
        spare = None
    members = {
        "approach": "known-angle turns" + (" and turns between still periods" if with_gravity
                                           else ""),
        "model": MODEL_EQUATION if res.G is None else MODEL_EQUATION_G,
        "units_in": units,
        "variant": f"{n} parameters from turns of known angle"
                   + (" and turns measured by gravity" if with_gravity else ""),
        "frame": _frame(data.accel_cal),
        "parameters": parameters,
        **_axes_members(res, S, gains, units),
        "rotations": rotations,
        "rotation_rms_deg": float(rms(res.angle_error_deg)),
        "iterations": res.iterations, "chi2": res.chi2, "dof": res.dof,
        "noise_scale": res.noise_scale,
        "turn_excess_deg": float(np.degrees(res.tau)),
        "known_turn_check": verdict.comparison,
        "rate_std": uncertainty,
        "gyro_noise_raw": data.noise,
        "noise_basis": "pooled over the still periods",
        "notes": data.notes,
        "warnings": data.warnings + verdict.said + ([spare] if spare else []),
        "blocking": blocking,
    }  # fmt: skip
    if undetermined:
        members["undetermined"] = undetermined
    if res.G is not None:
        members["g_sensitivity"] = res.G
        members["g_sensitivity_unit"] = f"{units} per m/s^2 (raw - bias - g_sensitivity @ a)"
    if g_test is not None:
        members["g_sensitivity_test"] = build(GSensitivityTest, **g_test)
    return build(GyroCalibration, solver="gyro-known", units="rad/s",
                 bias=np.asarray(res.b, float), matrix=np.asarray(res.M, float),
                 residual_rms=rms(np.radians(res.angle_error_deg)), **members)  # fmt: skip


def _rotation_rows(res, known, used, verdict) -> list[RotationRow]:
    """Each known-angle turn's row (its known and measured angle, their difference, how far its
    axis is from the fitted one, the noise of both, degrees), then the gravity-measured turns'."""
    across = np.degrees(known.axis_sigma * np.abs(known.angle))
    return [
        RotationRow(segment=s.name, label=s.label, known_angle_deg=float(s.angle_deg),
                    measured_angle_deg=float(m), angle_error_deg=float(e),
                    axis_error_deg=float(ax), noise_deg=float(sg), axis_noise_deg=float(ac))
        for s, m, e, ax, sg, ac in zip(used, res.measured_angle_deg, res.angle_error_deg,
                                       res.axis_error_deg, res.angle_sigma_deg, across,
                                       strict=True)
    ] + verdict.gravity_rows  # fmt: skip


def _axes_members(res, S: np.ndarray, gains: np.ndarray, units: str) -> dict:
    """The section's sensitivity axes: ``gains`` (row norms of ``S = M^-1``, raw ``units`` per
    rad/s) and their std, the angles between the axes minus 90 degrees and their std (delta
    method, for targets: capture --until)."""
    s_axes = S / gains[:, None]
    return {
        "sensitivity": gains.tolist(),
        "sensitivity_std": gain_std(res.M, res.cov[3:12, 3:12]).tolist(),
        "sensitivity_unit": f"{units} per rad/s",
        "misalignment_deg": {
            f"{AXES[i]}{AXES[j]}": float(np.degrees(np.arccos(s_axes[i] @ s_axes[j])) - 90)
            for i, j in ((0, 1), (0, 2), (1, 2))
        },
        "misalignment_std_deg": dict(zip(("xy", "xz", "yz"), map(float, axes_std(
            res.M, res.cov[3:12, 3:12])[2]), strict=True)),
    }  # fmt: skip
