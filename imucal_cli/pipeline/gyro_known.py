"""Turns of a known angle in the calibrate step (issue 9.3): :mod:`imucal_cli.solvers.gyro_known`.

Rotation segments with ``angle_deg`` are turns of a known angle. Each one's axis, in the
calibrated accelerometer's frame: for a turn about the vertical (gravity stays put in the body:
the Ferraris 360-degree turns, a turntable), the gravity direction the accelerometer reads
during it; otherwise its labelled ``axis``, where the accelerometer's frame is the labels' (the
labelled-pose solver) and with the placement error as its uncertainty. The turns between still
periods whose angle is not given join the same fit (gravity measures them).
"""

from __future__ import annotations

import numpy as np

from imucal_cli.errors import DesignError
from imucal_cli.formats.calibration import MODEL_EQUATION, SensorCalibration
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.solvers import gyro_full, gyro_known

from .common import rms, session_name, with_segments
from .gyro import (
    AXES,
    MODEL_EQUATION_G,
    GyroData,
    _frame,
    _saturation_limit,
    gyro_checks,
    still_periods,
    turns_between,
)
from .gyro_full import (
    design_warning,
    gain_std,
    parameter_rows,
    rate_std,
    rotations_and_stills,
)

#: A turn whose measured gravity direction stays within this RMS angle of its mean (deg) is
#: about the vertical: its axis is measured.
VERTICAL_DEG = 25.0
#: Least std of a measured vertical axis (deg): the centripetal acceleration of a unit held
#: a few cm off the axis tilts the vertical it reads by about this much, and its magnitude
#: barely shows it.
AXIS_FLOOR_DEG = 0.5
#: A labelled axis further than this from the vertical a turn was about (deg) is not its axis.
MAX_LABEL_OFF_DEG = 15.0
#: Placement error of a labelled axis when the config states none (deg).
PLACEMENT_DEG = 2.0


def _labels_frame(accel_cal: SensorCalibration) -> bool:
    """Is the accelerometer's frame the labels' (so that a labelled axis is in it)?"""
    return "upper-triangular" not in str(accel_cal.extra.get("gauge", ""))


def _vertical_axis(d: np.ndarray, mag: np.ndarray, g: float, duration: float):
    """The mean gravity direction over a turn (its axis, if the turn is about the vertical),
    the RMS angle of the direction from it (deg), and the axis' std (rad: linear acceleration
    tilts the measured vertical by about ``| |a| - g | / g``, at least AXIS_FLOOR_DEG)."""
    u = d.mean(axis=0)
    u /= np.linalg.norm(u)
    spread = float(np.degrees(np.sqrt(np.mean(np.arccos(np.clip(d @ u, -1, 1)) ** 2))))
    sigma = max(float(np.sqrt(np.mean((mag - g) ** 2)) / g / np.sqrt(max(duration, 1.0))),
                np.radians(AXIS_FLOOR_DEG))  # fmt: skip
    return u, spread, sigma


def _placement(cfg: Config, accel_cal: SensorCalibration) -> float:
    """Std of a labelled axis per tangent component (rad): how well the unit sits square to
    its labels, as the accelerometer's labelled poses measured it (a turn flat on a table
    is about the face's normal as well as a pose on that face is up), else the config's."""
    est = (accel_cal.extra.get("placement") or {}).get("rms_deg")
    deg = est or cfg.accel.labelled.placement_deg or PLACEMENT_DEG
    return float(np.radians(deg) / np.sqrt(2))


def known_turns(session: Session, cfg: Config, accel_cal: SensorCalibration, segments, b0):
    """The solver's view of the known-angle turns, and notes on how each axis was found.

    A labelled axis is used where the accelerometer's frame is the labels' and the turn is
    about it (within MAX_LABEL_OFF_DEG of the vertical it turned about, or not about the
    vertical at all): a unit turned flat on a table turns about its face's normal. Otherwise
    the measured vertical of a turn about the vertical."""
    keep, t, z, a, ang, axis, ax_sigma, notes = [], [], [], [], [], [], [], []
    g = cfg.gravity or session.gravity
    labels = _labels_frame(accel_cal)
    for seg in segments:
        sl = slice(seg.start, seg.stop)
        acc = accel_cal.apply(session.accel[sl])
        mag = np.linalg.norm(acc, axis=1)
        d = acc / mag[:, None]
        tt = session.time[sl]
        raw = session.gyro[sl] - b0
        name = seg.label or seg.name
        u, spread, sigma = _vertical_axis(d, mag, g, tt[-1] - tt[0])
        vertical = spread < VERTICAL_DEG
        lab = None if seg.axis is None else np.asarray(seg.axis, float) / np.linalg.norm(seg.axis)
        off = None if lab is None else float(np.degrees(np.arccos(min(abs(u @ lab), 1.0))))
        if lab is not None and labels and (not vertical or off < MAX_LABEL_OFF_DEG):
            n, sigma, how = lab, _placement(cfg, accel_cal), "labelled"
        elif vertical:
            if lab is not None:  # the labelled axis gives the sign
                n = u if float(u @ lab) >= 0 else -u
            else:  # the gyro's own sign (raw axes named as the accelerometer's)
                n = u * np.sign(float(u @ np.trapezoid(raw, tt, axis=0))) \
                    * np.sign(seg.angle_deg)  # fmt: skip
            how = f"the measured vertical (the turn within {spread:.1f} deg RMS of it)"
        else:
            notes.append(f"turn {name}: known angle but neither about the vertical nor with an "
                         "axis in the accelerometer's frame: left out")  # fmt: skip
            continue
        keep.append(seg)
        t.append(tt)
        z.append(session.gyro[sl])
        a.append(acc)
        ang.append(np.radians(seg.angle_deg))
        axis.append(n)
        ax_sigma.append(max(sigma, 1e-6))
        notes.append(f"turn {name}: {seg.angle_deg:g} deg, axis {how}")
    known = gyro_known.KnownTurns(
        t, z, np.array(ang), np.array(axis).reshape(-1, 3), np.array(ax_sigma),
        np.full(len(t), np.radians(cfg.gyro.known.angle_std_deg)), a,
    )  # fmt: skip
    return known, keep, notes


def _g_choice(cfg, fit):
    """The fit with or without g-sensitivity per ``[gyro.full] g_sensitivity``."""
    mode = cfg.gyro.full.g_sensitivity
    base = fit(False)
    if mode == "off":
        return base, None
    try:
        with_g = fit(True)
    except DesignError:
        if mode == "on":
            raise
        return base, {"included": False, "observable": False}
    dof = with_g.dof
    drop = max(base.chi2 - with_g.chi2, 0.0)
    F = float(drop / 9 / (with_g.chi2 / dof))
    p = float(gyro_full.fdtrc(9, dof, F))
    test = {"included": mode == "on" or p < gyro_full.G_SELECT_P, "observable": True, "F": F,
            "dof": [9, dof], "p_value": p}  # fmt: skip
    return (with_g if test["included"] else base), test


def calibrate_gyro_known(session: Session, cfg: Config, accel_cal: SensorCalibration):
    """Gyro calibration from turns of known angle, with the session's other turns between
    still periods in the same fit.

    Raises
    ------
    DesignError
        No turn of known angle, or the turns do not determine the model.
    """
    where = session_name(session)
    session, _ = with_segments(session)
    if session.gyro is None or session.accel is None:
        raise DesignError(f"{where}: turns of known angle need /raw/gyro and /raw/accel")
    segs = [s for s in session.rotation_segments() if s.angle_deg is not None]
    if not segs:
        raise DesignError(f"{where}: no rotation segment states its angle (angle_deg)")
    statics = session.static_segments()
    if not statics:
        raise DesignError(f"{where}: the gyro's bias needs still periods (none in this session)")
    stills, noise = still_periods(session, accel_cal, cfg, statics)
    n = sum(s.segment.stop - s.segment.start for s in stills)
    b0 = np.sum([s.z_mean * (s.segment.stop - s.segment.start) for s in stills], axis=0) / n
    known, used, notes = known_turns(session, cfg, accel_cal, segs, b0)
    limit = _saturation_limit(session, cfg)
    others = [s for s in session.rotation_segments() if s not in used]
    turns, _ = turns_between(session, stills, others, cfg.gyro.rotations.max_gap_s)
    data = GyroData(session, cfg, where, accel_cal, stills, turns, max(noise, 1e-12), b0,
                    noise / np.sqrt(n), session.gyro_units or "unknown",
                    notes=[f"{len(known.t)} turn(s) of known angle, {len(turns)} between still "
                           "periods measured by gravity"] + notes)  # fmt: skip
    if limit is not None and any(np.any((z <= limit[0]) | (z >= limit[1])) for z in known.z):
        data.warnings.append("a turn of known angle reaches the end of the gyro's range: its "
                             "integral is wrong; turn more slowly")  # fmt: skip
    rot, st = rotations_and_stills(data) if turns else (None, None)
    if st is None:
        st = gyro_full.Stills(
            g=np.array([s.g for s in stills]), g_sigma=np.array([s.g_sigma for s in stills]),
            z_mean=np.array([s.z_mean for s in stills]),
            z_sigma=np.array([max(s.z_sigma, 1e-12) for s in stills]),
        )  # fmt: skip
    x0 = None
    if len(known.t) < 3 and rot is not None and 2 * len(turns) >= 9:
        full = gyro_full.fit_full(rot, st, data.noise, b0)
        x0 = np.r_[full.b, full.M.ravel()]

    def fit(with_g):
        return gyro_known.fit_known(known, st, data.noise, b0, rot=rot, x0=x0,
                                    g_sensitivity=with_g)  # fmt: skip

    res, g_test = _g_choice(cfg, fit)
    noise_total = rate_std(res.M, res.cov[3:12, 3:12])
    cov_a = _accel_part(session, cfg, accel_cal, segs, statics, res, data, rot)
    res.cov = res.cov + cov_a
    uncertainty = {"total": rate_std(res.M, res.cov[3:12, 3:12]), "noise": noise_total,
                   "accel_calibration": rate_std(res.M, cov_a[3:12, 3:12]),
                   "meaning": "relative std of a calibrated rate in its worst direction"}
    return _section(data, res, known, used, g_test, uncertainty)


def _accel_part(session, cfg, accel_cal, segs, statics, res, data, rot) -> np.ndarray:
    """Covariance from the accelerometer calibration (it measures the axes and the still
    directions): refits with its parameters moved by one std along each eigenvector."""
    cov = accel_cal.extra.get("covariance")
    n = len(res.cov)
    if cov is None or np.shape(accel_cal.matrix) != (3, 3):
        data.notes.append("the accelerometer calibration states no covariance: the gyro's std "
                          "leave out its uncertainty")  # fmt: skip
        return np.zeros((n, n))
    C = np.asarray(cov["values"], float)
    lam, V = np.linalg.eigh((C + C.T) / 2)
    x = np.r_[res.b, res.M.ravel(), [] if res.G is None else res.G.ravel()]
    th0 = np.r_[accel_cal.bias, np.ravel(accel_cal.matrix)]
    out = np.zeros((n, n))
    for lam_i, v in zip(lam, V.T, strict=True):
        if lam_i <= 0:
            continue
        d = []
        for sgn in (1, -1):
            th = th0 + sgn * np.sqrt(lam_i) * v
            moved = SensorCalibration(solver=accel_cal.solver, units=accel_cal.units,
                                      bias=th[:3], matrix=th[3:].reshape(3, 3),
                                      extra={"gauge": accel_cal.extra.get("gauge")})  # fmt: skip
            d.append(_refit(session, cfg, moved, segs, statics, res, data, rot, x))
        dx = (d[0] - d[1]) / 2
        out += np.outer(dx, dx)
    return out


def _refit(session, cfg, accel_cal, segs, statics, res, data, rot, x) -> np.ndarray:
    stills, _ = still_periods(session, accel_cal, cfg, statics)
    known, _, _ = known_turns(session, cfg, accel_cal, segs, data.bias_still)
    st = gyro_full.Stills(
        g=np.array([s.g for s in stills]), g_sigma=np.array([s.g_sigma for s in stills]),
        z_mean=np.array([s.z_mean for s in stills]),
        z_sigma=np.array([max(s.z_sigma, 1e-12) for s in stills]),
    )  # fmt: skip
    fit = gyro_known.fit_known(known, st, data.noise, data.bias_still, rot=rot, x0=x[:12],
                               g_sensitivity=res.G is not None)  # fmt: skip
    return np.r_[fit.b, fit.M.ravel(), [] if fit.G is None else fit.G.ravel()]


def _section(data: GyroData, res, known, used, g_test, uncertainty) -> SensorCalibration:
    units, n = data.units_in, len(res.std)
    parameters = parameter_rows(res, units)
    sigma = np.degrees(np.sqrt(known.angle_sigma**2 + (known.axis_sigma * known.angle) ** 2))
    rotations = [
        {"segment": s.name, "label": s.label, "known_angle_deg": float(s.angle_deg),
         "measured_angle_deg": float(m), "angle_error_deg": float(e),
         "axis_error_deg": float(ax), "noise_deg": float(sg)}
        for s, m, e, ax, sg in zip(used, res.measured_angle_deg, res.angle_error_deg,
                                   res.axis_error_deg, sigma, strict=True)
    ]  # fmt: skip
    level = float(np.sqrt(np.median(res.known_chi2) / 2.366))  # chi^2_3 median
    if level > data.cfg.gyro.max_residual_ratio:
        worst = int(np.argmax(res.known_chi2))
        data.warnings.append(
            f"the turns of known angle miss their angles by {level:.0f} times what the noise "
            f"predicts (worst: {rotations[worst]['label'] or rotations[worst]['segment']}, "
            f"{rotations[worst]['angle_error_deg']:+.2f} deg): check each turn's angle and "
            "sign (angle_deg), and that the unit was still before and after"
        )
    undetermined = design_warning(data, uncertainty, len(used) + len(data.turns))
    S = np.linalg.inv(res.M)
    gains = np.linalg.norm(S, axis=1)
    data.warnings += gyro_checks(data.session, data.cfg, gains, units)
    if undetermined:
        data.warnings.append(undetermined)
    s_axes = S / gains[:, None]
    extra = {
        "approach": "known-angle turns" + (" and turns between still periods" if data.turns
                                           else ""),
        "model": MODEL_EQUATION if res.G is None else MODEL_EQUATION_G,
        "units_in": units,
        "variant": f"{n} parameters from turns of known angle"
                   + (" and turns measured by gravity" if data.turns else ""),
        "frame": _frame(data.accel_cal),
        "parameters": parameters,
        "sensitivity": gains.tolist(),
        "sensitivity_std": gain_std(res.M, res.cov[3:12, 3:12]).tolist(),
        "sensitivity_unit": f"{units} per rad/s",
        "misalignment_deg": {
            f"{AXES[i]}{AXES[j]}": float(np.degrees(np.arccos(s_axes[i] @ s_axes[j])) - 90)
            for i, j in ((0, 1), (0, 2), (1, 2))
        },
        "rotations": rotations,
        "rotation_rms_deg": float(rms(res.angle_error_deg)),
        "iterations": res.iterations, "chi2": res.chi2, "dof": res.dof,
        "noise_scale": res.noise_scale,
        "rate_std": uncertainty,
        "gyro_noise_raw": data.noise,
        "noise_basis": "pooled over the still periods",
        "notes": data.notes,
        "warnings": data.warnings,
    }  # fmt: skip
    if undetermined:
        extra["undetermined"] = undetermined
    if res.G is not None:
        extra["g_sensitivity"] = res.G.tolist()
        extra["g_sensitivity_unit"] = f"{units} per m/s^2 (raw - bias - g_sensitivity @ a)"
    if g_test is not None:
        extra["g_sensitivity_test"] = g_test
    return SensorCalibration(solver="gyro-known", units="rad/s", bias=np.asarray(res.b, float),
                             matrix=np.asarray(res.M, float), residual_rms=rms(np.radians(
                                 res.angle_error_deg)), extra=extra)  # fmt: skip

