"""Per-axis gyro solvers (Qureshi & Golnaraghi III-B): ``static`` (eq. 18) and ``dynamic``
(eqs. 19-21), scale and bias per axis from turns about one sensor axis at a time.

The per-axis model ``omega_i = k_i (z_i - b_i)`` ignores the gyro's misalignment. Where the
session's turns also determine the full model, it is fitted too and the section says how far
the gyro's axes are from the accelerometer's and how much that moves the per-axis gains,
in their own standard deviations (issue 10.7).
"""

from __future__ import annotations

import numpy as np

from imucal_cli.calibrate.common import num, rms
from imucal_cli.calibrate.gyro.full import accel_directions, fit_full_model, turn_windows
from imucal_cli.calibrate.gyro.turns import AXES, GyroData, GyroFit, Turn
from imucal_cli.errors import DesignError, ImucalError
from imucal_cli.estimators.gyro import axes as gyro_axes
from imucal_cli.estimators.gyro.axes_misalignment import (
    misalignment_errors,
    misalignment_parts,
)
from imucal_cli.formats.session import Session
from imucal_cli.model.gyro import IgnoredMisalignment, RotationRow
from imucal_cli.model.parts import Parameter

#: A turn whose axis is further than this from the sensor axis it is attributed to is left out
#: (the full model takes any turn).
MAX_AXIS_ERROR_DEG = 15.0
#: Rotation residuals above this RMS mean the per-axis model does not fit.
MAX_PER_AXIS_RMS_DEG = 1.0
#: The ignored misalignment is a warning when it moves a gain by more than this many std.
MAX_GAIN_SHIFT_STD = 3.0


def fit_per_axis(data: GyroData, solver: str) -> GyroFit:
    """The static or dynamic solver on every axis, and what the misalignment it ignores does."""
    full, why = _full_fit(data)
    misaligned = _misalignment(full)
    # Pass 1 reads each angle about the nominal axis; pass 2 about the turn's own axis, the
    # rotation vector that the pass-1 calibration integrates (a hand is never exact).
    k = b = None
    for _ in range(2):
        first = None if k is None else (k, b)
        k, b, k_std, b_std, rotations, ci, k_mis = _per_axis(
            data, solver, data.notes if k is None else [], first,
            None if first is None else misaligned,
        )
    units = data.units_in
    parameters = [
        Parameter(f"b_{a}", float(b[i]), num(b_std[i]), units, ci95=num(ci[i, 1]))
        for i, a in enumerate(AXES)
    ] + [
        Parameter(f"k_{a}", float(k[i]), num(k_std[i]), f"rad/s per {units}",
                  ci95=num(ci[i, 0]))
        for i, a in enumerate(AXES)
    ]  # fmt: skip
    residual = np.radians([r.angle_error_deg for r in rotations])
    if np.degrees(rms(residual)) > MAX_PER_AXIS_RMS_DEG:
        data.warnings.append(
            f"the per-axis model does not fit these turns (angle residual RMS "
            f"{np.degrees(rms(residual)):.2f} deg): turn about one sensor axis at a time "
            '(x and y with z up, z on its side), or use [gyro] solver = "full"'
        )
    members = {"model_paper": "omega = K (omega_s - B), eq. (15)", "approach": solver,
               "ignored_misalignment": _ignored_misalignment(
                   data, full, why, k, np.sqrt(np.maximum(k_std**2 - k_mis**2, 0)))}
    return GyroFit(b, np.diag(k), parameters, rotations, residual, 1 / np.abs(k), members)


def _full_fit(data: GyroData) -> tuple[GyroFit | None, str]:
    """The full model on the same turns (None and the reason where they cannot measure it)."""
    try:
        return fit_full_model(GyroData(**{**vars(data), "notes": [], "warnings": []}),
                              g_sensitivity="off"), ""  # fmt: skip
    except ImucalError as exc:
        return None, str(exc)


def _misalignment(full: GyroFit | None) -> tuple | None:
    """``(M, b, sigma, dof)``: the full model on the same turns (matrix, rad/s per raw unit;
    bias, raw units), which gives the turns' true rotation vectors, and the RMS of the gyro's
    rotation from the accelerometer and of its axes' non-orthogonality (off-diagonal
    ``M_ij / M_ii``, rad; eq. 6's ``T_s``) as it measures them, less their estimation noise,
    with the dof of each square; None without a full fit. The per-axis std carry what such a
    misalignment does to the gains (:mod:`~imucal_cli.estimators.gyro.axes_misalignment`)."""
    if full is None:
        return None
    M = np.asarray(full.matrix, float)
    std = np.array([p.std for p in full.parameters[3:12]], float).reshape(3, 3)
    diag = np.diag(M)[:, None]
    sigma, dof = misalignment_parts(M / diag - np.eye(3), std / np.abs(diag))
    return (M, np.asarray(full.bias, float), sigma, dof) if np.any(sigma > 0) else None


def _ignored_misalignment(data: GyroData, full: GyroFit | None, why: str, k: np.ndarray,
                          k_std: np.ndarray) -> IgnoredMisalignment:  # fmt: skip
    """The full model on the same turns (``full``; None: ``why`` it cannot be fitted): the
    gyro axes' angles from the accelerometer's, and the shift of each per-axis gain that
    ignoring them causes, in ``k_std``, the gains' std without the misalignment's share (note;
    warning when large: the full model would remove what the per-axis std now allow for)."""
    if full is None:
        data.notes.append(f"the per-axis model ignores the gyro's misalignment; these turns "
                          f"cannot measure it ({why}), so the gains' std leave it out")
        return IgnoredMisalignment(measured=False)
    M = full.matrix
    shift = k / np.diag(M) - 1
    in_std = np.abs(k - np.diag(M)) / k_std
    angles = full.members["axis_to_accel_frame_deg"]
    text = (
        "the per-axis model ignores the gyro's misalignment: the full model on these turns puts "
        f"the x, y, z axes {', '.join(f'{angles[a]:.2f}' for a in AXES)} deg off the "
        f"accelerometer's, which moves the per-axis gains by "
        f"{', '.join(f'{100 * s:+.3f}' for s in shift)} % ({', '.join(f'{v:.1f}' for v in in_std)}"
        " std of their noise)"
    )
    if in_std.max() > MAX_GAIN_SHIFT_STD:
        data.warnings.append(text + '; [gyro] solver = "full" (or "auto") models it')
    else:
        data.notes.append(text)
    return IgnoredMisalignment(measured=True, axis_to_accel_frame_deg=angles,
                               gain_shift=[float(s) for s in shift],
                               gain_shift_std=[float(v) for v in in_std])  # fmt: skip


def _per_axis(data: GyroData, solver: str, notes: list[str], first, misaligned=None):
    """Per-axis fits (static or dynamic) of every axis; ``first`` = (k, b) of a previous pass
    whose calibration gives each turn's actual axis; ``misaligned``: what the full model says
    of the misalignment the fits leave out (:func:`_misalignment`), or None."""
    per_axis, oblique = _turns_by_axis(data, notes, first)
    return _fit_axes(data, solver, per_axis, oblique, misaligned)


def _turns_by_axis(data: GyroData, notes: list[str], first):
    """Each usable turn under the sensor axis it is about, with gravity's reading of its angle.

    Returns
    -------
    per_axis : dict of int to list
        Per axis ``i``: ``(turn, x_i, T, angle, moved, x, sign, g0)``, the raw integral of
        channel ``i`` (raw units s), the turn's duration (s), the angle channel ``i`` sees
        (rad), how it moves along the accelerometer's error directions (rad,
        :func:`_angle_moves`), the raw integrals of all three channels (raw units s), the
        labelled axis's sign and the calibrated gravity before the turn (m/s^2).
    oblique : int
        Turns left out for being further than :data:`MAX_AXIS_ERROR_DEG` from every axis (a
        note each in ``notes``, as for turns about the vertical).
    """
    session, turns, stills, cfg = data.session, data.turns, data.stills, data.cfg
    bias_still = data.bias_still
    min_lev = np.sin(np.radians(cfg.gyro.rotations.min_tilt_deg)) ** 2
    per_axis = {i: [] for i in range(3)}
    oblique = 0
    dirs = accel_directions(data)
    for turn, window in zip(turns, turn_windows(data), strict=True):
        x, T = _integral(session, window)  # from the still period it leaves to the one it reaches
        i = _axis_of(turn, x, bias_still, T)
        sign = np.sign(turn.segment.axis[i]) if turn.segment.axis is not None else 1.0
        axis = np.eye(3)[i] * sign
        # The per-axis model holds for turns about one sensor axis only: the turn's own axis
        # (raw integral in pass 1, calibrated in pass 2) must be near it.
        turned = (x - bias_still * T) if first is None else first[0] * (x - first[1] * T)
        off = np.degrees(np.arccos(min(1.0, abs(turned[i]) / max(np.linalg.norm(turned), 1e-300))))
        if off > MAX_AXIS_ERROR_DEG:
            oblique += 1
            notes.append(
                f"{turn.segment.label or turn.segment.name}: turned {off:.0f} deg away from the "
                f"{AXES[i]} axis, not about one sensor axis: left out of the per-axis fit"
            )
            continue
        if first is not None:
            rotvec = first[0] * (x - first[1] * T)
            axis = rotvec / np.linalg.norm(rotvec) * np.sign(rotvec[i]) * sign
        g0, g1 = stills[turn.before].g, stills[turn.after].g
        angle, lev = gyro_axes.rotation_angle_about_axis(g0, g1, axis)
        if lev < min_lev:
            notes.append(
                f"{turn.segment.label or turn.segment.name}: axis within "
                f"{cfg.gyro.rotations.min_tilt_deg:g} deg of vertical, invisible to gravity: "
                "skipped"
            )
            continue
        # Channel i sees the rotation vector's component along i: the angle times the axis's
        # i-th component (1 for a turn exactly about the axis; the paper assumes that).
        moved = _angle_moves(dirs, turn, g0, g1, axis, angle)
        per_axis[i].append((turn, x[i], T, sign * angle * abs(axis[i]),
                            sign * abs(axis[i]) * moved, x, sign, g0))  # fmt: skip
    return per_axis, oblique


def _angle_moves(dirs, turn, g0, g1, axis, angle) -> np.ndarray:
    """How a turn's measured angle moves along each square-root direction of the
    accelerometer calibration's covariance (rad, (m,); :func:`~.full.accel_directions`, its
    frame left out: the angles are read about the gyro's own axes); zeros without one."""
    if dirs is None:
        return np.zeros(1)
    out = np.empty(dirs.shape[2])
    for j in range(dirs.shape[2]):
        a, _ = gyro_axes.rotation_angle_about_axis(g0 + dirs[turn.before, :, j],
                                                   g1 + dirs[turn.after, :, j], axis)
        out[j] = (a - angle + np.pi) % (2 * np.pi) - np.pi
    return out


def _fit_axes(data: GyroData, solver: str, per_axis: dict, oblique: int, misaligned=None):
    """Qureshi & Golnaraghi's static (eq. 18) or dynamic (eqs. 19-21) fit of each axis's
    turns (:func:`_turns_by_axis`): ``(k, b, k_std, b_std, rotations, ci, k_mis)``, scale
    (rad/s per raw unit), bias (raw units), their std, (3,) each, the rotation rows, the 95 %
    half-widths (3, 2) and the misalignment's share of ``k_std`` (3,). The std carry the
    turns' noise on its known shape (:func:`_turn_noise`) and, with ``misaligned``, the
    misalignment eq. (15) leaves out (:func:`_model_errors`).

    Raises
    ------
    DesignError
        An axis with fewer usable turns than the solver needs (2 static, 3 dynamic).
    """
    bias_still, b_still_std = data.bias_still, data.b_still_std
    k, b, k_std, b_std = np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
    ci = np.zeros((3, 2))  # 95 % half-widths of k and b
    k_mis = np.zeros(3)
    rotations = []
    for i in range(3):
        rows = per_axis[i]
        _enough_turns(data, solver, i, len(rows), oblique)
        x = np.array([r[1] for r in rows])
        T = np.array([r[2] for r in rows])
        ang = _unwrap(np.array([r[3] for r in rows]), x - bias_still[i] * T)
        D = np.array([r[4] for r in rows])
        cov = D @ D.T  # the accelerometer's error moves every angle together
        noise = _turn_noise(data, rows, T)
        model = None if misaligned is None else _model_errors(rows, i, misaligned)
        if solver == "static":
            fit = gyro_axes.fit_axis_static(x, T, ang, bias_still[i], b_still_std, cov, noise,
                                            model)  # fmt: skip
        else:
            fit = gyro_axes.fit_axis_dynamic(x, T, ang, cov, noise, model)
        k[i], b[i], k_std[i], b_std[i] = fit.k, fit.b, fit.k_std, fit.b_std
        ci[i], k_mis[i] = (fit.k_ci95, fit.b_ci95), fit.k_misalignment_std
        for (turn, xi, Ti, ai, *_), res in zip(rows, fit.residuals_rad, strict=True):
            rotations.append(RotationRow(
                segment=turn.segment.name, label=turn.segment.label, axis=AXES[i],
                known_angle_deg=float(np.degrees(ai)),
                measured_angle_deg=float(np.degrees(fit.k * (xi - fit.b * Ti))),
                angle_error_deg=float(np.degrees(-res)),
            ))  # fmt: skip
    return k, b, k_std, b_std, rotations, ci, k_mis


def _enough_turns(data: GyroData, solver: str, i: int, n: int, oblique: int) -> None:
    """Raise :class:`DesignError` when axis ``i`` has fewer than the solver's turns."""
    if n >= (2 if solver == "static" else 3):
        return
    raise DesignError(
        f"{data.where}: {n} usable rotation(s) about {AXES[i]}; the {solver} "
        f"approach needs {'2' if solver == 'static' else '3'} or more per axis (the "
        f"paper turns 18 times per axis; {AXES[i]} turns need {AXES[i]} horizontal)"
        + (
            f"; {oblique} turn(s) not about one sensor axis were left out: "
            '[gyro] solver = "full" takes any turn'
            if oblique
            else ""
        )
    )


def _turn_noise(data: GyroData, rows: list, T: np.ndarray) -> gyro_axes.TurnNoise:
    """The shape of the turns' noise (eqs. 17, 20): each raw integral's gyro white noise
    (``sigma_z^2 dt T``, raw units^2 s^2: a slow turn integrates more of it) and each angle's
    from the two still means it is read between (``g_sigma^2`` each, rad^2; a still period
    between two turns moves one angle up and the other down)."""
    t = data.session.time
    dt = float(t[-1] - t[0]) / max(len(t) - 1, 1)
    turns = [r[0] for r in rows]  # each angle is about +axis (the label's sign taken out)
    g_var = np.nan_to_num(np.array([s.g_sigma for s in data.stills], float) ** 2)
    cov = np.zeros((len(rows), len(rows)))
    for p, tp in enumerate(turns):
        for q, tq in enumerate(turns):
            # angle = phi(after) - phi(before): +var for a shared end, -var for the middle
            shared = (g_var[tp.after] * ((tp.after == tq.after) - (tp.after == tq.before))
                      + g_var[tp.before] * ((tp.before == tq.before) - (tp.before == tq.after)))
            cov[p, q] = shared
    return gyro_axes.TurnNoise(data.noise**2 * dt * T, cov)


def _model_errors(rows: list, i: int, misaligned) -> gyro_axes.ModelErrors:
    """The angle errors of eq. (15) where the gyro has eq. (6)'s misalignment at the RMS the
    full model measures, on these turns: their rotation vectors as the full model integrates
    them (``misaligned`` = (M, b, sigma, dof), :func:`_misalignment`; the per-axis
    calibration's own would tilt each by the misalignment once more) and gravity before each."""
    M, b, sigma, dof = misaligned
    rotvec = np.array([M @ (r[5] - b * r[2]) for r in rows])
    g0 = np.array([r[7] for r in rows])
    return misalignment_errors(rotvec, g0, np.array([r[6] for r in rows]), i, sigma, dof=dof)


def _unwrap(angle: np.ndarray, integral: np.ndarray) -> np.ndarray:
    """Gravity gives each angle only modulo 360 degrees: a turn of 179 degrees may read -181.
    Take the branch nearest the gyro's own estimate (a rough scale from the turns clear of
    +-180 degrees times each turn's bias-free integral)."""
    clear = np.abs(angle) < np.radians(150)
    if not clear.any():
        return angle
    k = np.median(angle[clear] / integral[clear])
    return angle + 2 * np.pi * np.round((k * integral - angle) / (2 * np.pi))


def _integral(session: Session, window: slice) -> tuple[np.ndarray, float]:
    """A turn's raw integral over ``window`` (raw units s) and its duration (s)."""
    t = session.time[window]
    return np.trapezoid(session.gyro[window], t, axis=0), float(t[-1] - t[0])


def _axis_of(turn: Turn, x: np.ndarray, bias: np.ndarray, T: float) -> int:
    """The gyro axis a turn is about: its labelled axis, else the dominant raw channel."""
    if turn.segment.axis is not None:
        return int(np.argmax(np.abs(turn.segment.axis)))
    return int(np.argmax(np.abs(x - bias * T)))


