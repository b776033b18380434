"""Turns of a known angle in the calibrate step (issue 9.3):
:mod:`imucal_cli.estimators.gyro.known`.

Rotation segments with ``angle_deg`` are turns of a known angle. Each one's axis, in the
calibrated accelerometer's frame: for a turn about the vertical (gravity stays put in the body:
the Ferraris 360-degree turns, a turntable), the gravity direction the accelerometer reads
during it; otherwise its labelled ``axis``, where the accelerometer's frame is the labels' (the
labelled-pose solver) and with the placement error as its uncertainty. The turns between still
periods whose angle is not given join the same fit (gravity measures them).

Without an accelerometer calibration (a session whose poses cannot determine it: plan
gyro-axes) the labelled axes are the frame: each turn's axis is its label, with the configured
(or default) placement error, the bias comes from the still periods, and no g-sensitivity or
gravity-measured turn is fitted.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.special import fdtrc

from imucal_cli.calibrate.common import session_name, with_segments
from imucal_cli.calibrate.gyro import known_checks as checks
from imucal_cli.calibrate.gyro.full import (
    accel_directions_and_frame,
    rate_std,
    rotations_and_stills,
    solver_stills,
)
from imucal_cli.calibrate.gyro.known_section import section as _section
from imucal_cli.calibrate.gyro.rotations import (
    calibrate_gyro_rotations,
    clipped_known,
    rounding,
    rounding_of_mean,
    still_periods,
    turns_between,
)
from imucal_cli.calibrate.gyro.turn_windows import rest_to_rest, settle_turns
from imucal_cli.calibrate.gyro.turns import GyroData
from imucal_cli.errors import DesignError
from imucal_cli.estimators.accel.frame import frame_free
from imucal_cli.estimators.gyro import full as gyro_full
from imucal_cli.estimators.gyro import known as gyro_known
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.model.accel import AccelCalibration
from imucal_cli.model.calibration import SensorCalibration
from imucal_cli.model.gyro import (
    RateStd,
)

#: A turn whose measured gravity direction stays within this RMS angle of its mean (deg), and
#: within VERTICAL_SHARE of its angle, is about the vertical: its axis is measured.
VERTICAL_DEG = 25.0
#: A turn by ``theta`` about a horizontal axis sweeps gravity through ``theta`` (RMS about a
#: third of it from the mean): a turn of 60 degrees about x with +Z up stays within 21 deg
#: RMS, and was taken for a turn about the vertical (issue 24.5). About the vertical, only the
#: hand's acceleration moves it, whatever the angle.
VERTICAL_SHARE = 0.1
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
    return "upper-triangular" not in (accel_cal.gauge or "")


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


def _placement(cfg: Config, accel_cal: SensorCalibration | None) -> float:
    """Std of a labelled axis per tangent component (rad): how well the unit sits square to
    its labels, as the accelerometer's labelled poses measured it (a turn flat on a table
    is about the face's normal as well as a pose on that face is up), else the config's."""
    placement = accel_cal.placement if isinstance(accel_cal, AccelCalibration) else None
    est = None if placement is None else placement.rms_deg
    deg = est or cfg.accel.labelled.placement_deg or PLACEMENT_DEG
    return float(np.radians(deg) / np.sqrt(2))


def _turn_axis(seg, acc, raw, tt, g, cfg, accel_cal, vertical_first: bool = False):
    """A known turn's unit axis, its std (rad), how it was found, and whether that std is
    assumed (no accelerometer: the config's or the default placement, nothing measured it;
    with one, its labelled poses measured the placement, or the vertical is measured).
    None when neither a label in the accelerometer's frame nor the measured vertical gives
    it (see :func:`known_turns`). ``acc``: the turn's calibrated accel (None without one)."""
    lab = None if seg.axis is None else np.asarray(seg.axis, float) / np.linalg.norm(seg.axis)
    if acc is None:  # no accelerometer: the labels' frame is the gyro's, the axis body-fixed
        if lab is None:
            return None
        return lab, _placement(cfg, None), "labelled (the frame of the labels)", True
    mag = np.linalg.norm(acc, axis=1)
    u, spread, sigma = _vertical_axis(acc / mag[:, None], mag, g, tt[-1] - tt[0])
    vertical = spread < min(VERTICAL_DEG, VERTICAL_SHARE * abs(seg.angle_deg))
    off = None if lab is None else float(np.degrees(np.arccos(min(abs(u @ lab), 1.0))))
    if vertical_first and vertical:  # the alternative a check tries: the measured vertical
        lab_ok = False
    else:
        lab_ok = not vertical or (off is not None and off < MAX_LABEL_OFF_DEG)
    if lab is not None and _labels_frame(accel_cal) and lab_ok:
        return lab, _placement(cfg, accel_cal), "labelled", False
    if not vertical:
        return None
    if lab is not None:  # the labelled axis gives the sign
        n = u if float(u @ lab) >= 0 else -u
    else:  # the gyro's own sign (raw axes named as the accelerometer's)
        n = u * np.sign(float(u @ np.trapezoid(raw, tt, axis=0))) * np.sign(seg.angle_deg)
    return n, sigma, f"the measured vertical (the turn within {spread:.1f} deg RMS of it)", False


def known_turns(session: Session, cfg: Config, accel_cal: SensorCalibration | None, segments,
                b0, vertical_first: bool = False):  # fmt: skip
    """The solver's view of the known-angle turns, and notes on how each axis was found.

    A labelled axis is used where the accelerometer's frame is the labels' and the turn is
    about it (within MAX_LABEL_OFF_DEG of the vertical it turned about, or not about the
    vertical at all): a unit turned flat on a table turns about its face's normal. Otherwise
    the measured vertical of a turn about the vertical. Without an accelerometer calibration
    (``accel_cal`` None) only labelled axes, in the labels' frame: a turn about a body-fixed
    axis integrates to ``angle * axis`` whatever the attitude, so no accelerometer is needed."""
    keep, t, z, a, ang, axis, ax_sigma, notes, labelled = [], [], [], [], [], [], [], [], []
    assumed = False
    g = cfg.gravity or session.gravity
    for seg in segments:
        sl = rest_to_rest(session, seg)  # from the still sample it leaves to the one it reaches
        acc = None if accel_cal is None else accel_cal.apply(session.accel[sl])
        tt = session.time[sl]
        found = _turn_axis(seg, acc, session.gyro[sl] - b0, tt, g, cfg, accel_cal,
                           vertical_first)  # fmt: skip
        name = seg.label or f"turn {seg.name}"
        if found is None:
            why = ("no labelled axis, and no accelerometer calibration to measure the vertical"
                   if accel_cal is None else "neither about the vertical nor with an axis in "
                   "the accelerometer's frame")  # fmt: skip
            notes.append(f"{name}: known angle but {why}: left out")
            continue
        n, sigma, how, guess = found
        assumed |= guess
        keep.append(seg)
        t.append(tt)
        z.append(session.gyro[sl])
        a.append(acc)
        ang.append(np.radians(seg.angle_deg))
        axis.append(n)
        ax_sigma.append(max(sigma, 1e-6))
        labelled.append(how.startswith("labelled"))
        notes.append(f"{name}: {seg.angle_deg:g} deg, axis {how}")
    known = gyro_known.KnownTurns(
        t, z, np.array(ang), np.array(axis).reshape(-1, 3), np.array(ax_sigma),
        np.full(len(t), np.radians(cfg.gyro.known.angle_std_deg)),
        None if accel_cal is None else a, np.array(labelled, bool),
    )  # fmt: skip
    return known, keep, notes, assumed


def in_accel_frame(known: gyro_known.KnownTurns, phi: np.ndarray | None):
    """``known`` with the frame's part of its labelled axes: seen from the frame the
    accelerometer estimates, a labelled axis is off by that frame's turn ``phi`` (3, m: along
    each square-root direction of the accelerometer calibration's covariance,
    :func:`~imucal_cli.calibrate.gyro.full.accel_directions_and_frame`), so the rates, which
    are reported in that frame, are held to the labels only as well as it is known. Without
    ``phi`` or a labelled axis, ``known`` as it is."""
    if phi is None or known.labelled is None or not known.labelled.any():
        return known
    frame = np.cross(phi.T[None], known.axis[:, None, :]).transpose(0, 2, 1)  # phi_j x n_k
    return replace(known, frame=frame * known.labelled[:, None, None])


def _g_choice(cfg, fit):
    """The fit with or without g-sensitivity per ``[gyro.full] g_sensitivity``. ``fit(with_g,
    tau)``: the F-test weighs the turns measured by gravity with the excess ``tau`` estimated
    without g-sensitivity in both fits, so that their chi^2 compare; the model kept has its
    own excess (a g-sensitivity left out shows as excess)."""
    mode = cfg.gyro.full.g_sensitivity
    base = fit(False, None)
    if mode == "off":
        return base, None
    try:
        with_g = fit(True, base.tau)
    except DesignError:
        if mode == "on":
            raise
        return base, {"included": False, "observable": False}
    dof = with_g.dof
    drop = max(base.chi2 - with_g.chi2, 0.0)
    F = float(drop / 9 / (with_g.chi2 / dof))
    p = float(fdtrc(9, dof, F))
    test = {"included": mode == "on" or p < gyro_full.G_SELECT_P, "observable": True, "F": F,
            "dof": [9, dof], "p_value": p}  # fmt: skip
    if not test["included"]:
        return base, test
    if base.tau > 0:  # the excess of the model with g-sensitivity: what it leaves unexplained
        with_g = fit(True, None)
    return with_g, test


def _g_choice_without_accel(cfg, fit, data):
    """No accelerometer calibration: the g-sensitivity cannot be measured (refused when
    ``[gyro.full] g_sensitivity = "on"``)."""
    if cfg.gyro.full.g_sensitivity == "on":
        raise DesignError(f"{data.where}: [gyro.full] g_sensitivity = \"on\" needs the "
                          "accelerometer calibrated (an [accel] solver, or --accel CAL.json)")
    data.notes.append("g-sensitivity: not estimated (no accelerometer calibration)")
    return fit(False, None), None


def _known_data(session, cfg, accel_cal, where):
    """The known-angle turns, the still periods and the other turns between still periods
    (measured by gravity; only with an accelerometer calibration)."""
    if session.gyro is None or (accel_cal is not None and session.accel is None):
        raise DesignError(f"{where}: turns of known angle need /raw/gyro"
                          + ("" if accel_cal is None else " and /raw/accel"))  # fmt: skip

    session, settled = settle_turns(session)  # each turn integrated from rest to rest
    segs = [s for s in session.rotation_segments() if s.angle_deg is not None]
    if not segs:
        raise DesignError(f"{where}: no rotation segment states its angle (angle_deg)")
    statics = session.static_segments()
    if not statics:
        raise DesignError(f"{where}: the gyro's bias needs still periods (none in this session)")
    stills, noise = still_periods(session, accel_cal, cfg, statics)
    n = sum(s.segment.stop - s.segment.start for s in stills)
    b0 = np.sum([s.z_mean * (s.segment.stop - s.segment.start) for s in stills], axis=0) / n
    known, used, notes, assumed = known_turns(session, cfg, accel_cal, segs, b0)
    if accel_cal is None and len(used) < 3:
        raise DesignError(
            f"{where}: {len(used)} of {len(segs)} turns of known angle have a labelled axis; "
            "without an accelerometer calibration a turn's axis is its label: label them "
            "(imucal label SESSION --segment NAME --axis X,Y,Z, three different axes), or "
            "pass an earlier accelerometer calibration: --accel CAL.json"
        )
    others = [s for s in session.rotation_segments() if s not in used]
    if accel_cal is None:
        turns = []
        if others:
            notes.append(f"{len(others)} other turn(s) left out: measuring a turn of unknown "
                         "angle needs the accelerometer calibrated (--accel CAL.json)")
        notes.insert(0, "no accelerometer calibration: the turns' axes are their labels (the "
                        "gyro is calibrated in the labels' frame), the bias from the still "
                        "periods")  # fmt: skip
    else:
        turns, _ = turns_between(session, stills, others, cfg.gyro.rotations.max_gap_s)
    data = GyroData(session, cfg, where, accel_cal, stills, turns, max(noise, 1e-12), b0,
                    noise / np.sqrt(n), session.gyro_units or "unknown",
                    notes=[f"{len(known.t)} turn(s) of known angle, {len(turns)} between still "
                           "periods measured by gravity"] + ([settled] if settled else [])
                    + notes)  # fmt: skip
    data.noise, data.round_cov = rounding(session, stills, data.noise)
    counts = np.array([s.segment.stop - s.segment.start for s in stills], float)
    data.b_still_std = float(np.sqrt(data.noise**2 / n + rounding_of_mean(data.round_cov, counts)))
    clipped_known(session, data, known.z)  # the turns between still periods too
    return data, known, used, segs, statics, assumed


def calibrate_gyro_known(
    session: Session, cfg: Config, accel_cal: SensorCalibration | None
) -> SensorCalibration:  # fmt: skip
    """Gyro calibration from turns of known angle, with the session's other turns between
    still periods in the same fit. Without an accelerometer calibration (``accel_cal``
    None) the turns' labelled axes give the frame and the still periods the bias.

    The turns between still periods are weighed with the excess scatter they show
    (:mod:`imucal_cli.estimators.gyro.known`), and left out where they miss the model by more than
    ``[gyro] max_residual_ratio`` times their noise and the known turns determine the gyro
    alone (the full model refuses such turns); the known turns are then checked against what
    remains (:mod:`.gyro_known_checks`).

    Raises
    ------
    DesignError
        No turn of known angle, or the turns do not determine the model.
    """
    where = session_name(session)
    session, _ = with_segments(session)
    data, known, used, segs, statics, assumed = _known_data(session, cfg, accel_cal, where)
    if not used:
        return _without_known_turns(session, cfg, accel_cal, data, segs)
    turns, b0 = data.turns, data.bias_still
    rot, st = (rotations_and_stills(data) if turns
               else (None, solver_stills(data.stills, data.round_cov)))  # fmt: skip
    x0 = None
    if len(known.t) < 3 and rot is not None and 2 * len(turns) >= 9:
        full = gyro_full.fit_full(rot, st, data.noise, b0)
        x0 = np.r_[full.b, full.M.ravel()]

    # the turns gravity measures in the accelerometer's frame, labelled axes off it by its turn
    accel_dirs, phi = accel_directions_and_frame(data) or (None, None)
    known = in_accel_frame(known, phi)

    def fitter(rot_, tau_fixed=None):
        def fit(with_g, tau=None, known_=known):
            return gyro_known.fit_known(known_, st, data.noise, b0, rot=rot_, x0=x0,
                                        g_sensitivity=with_g,
                                        tau=tau_fixed if tau is None else tau,
                                        accel_dirs=accel_dirs)  # fmt: skip
        return fit

    def vertical_known():  # the axis a check tries: the measured vertical of each such turn
        if accel_cal is None:
            return None
        alt, alt_used, _, _ = known_turns(session, cfg, accel_cal, segs, b0, vertical_first=True)
        alt = in_accel_frame(alt, phi)
        if [s.name for s in alt_used] != [s.name for s in used] or np.allclose(alt.axis,
                                                                              known.axis):
            return None
        return alt

    verdict, rot = _choose(cfg, data, known, used, st, rot, b0, fitter, vertical_known,
                           accel_dirs)  # fmt: skip
    res, g_test = verdict.result, verdict.g_test
    if accel_cal is None:
        cov_a = np.zeros_like(res.cov)
    else:
        cov_a = _accel_part(session, cfg, accel_cal, segs, statics, res, data, rot,
                            verdict.known, in_weights=accel_dirs is not None and rot is not None)
    noise_total = rate_std(res.M, res.cov[3:12, 3:12])
    res.cov = res.cov + cov_a
    uncertainty = RateStd(total=rate_std(res.M, res.cov[3:12, 3:12]), noise=noise_total,
                          accel_calibration=None if accel_cal is None
                          else rate_std(res.M, cov_a[3:12, 3:12]),
                          meaning="relative std of a calibrated rate in its worst direction")
    return _section(data, res, verdict.known, used, g_test, uncertainty, assumed, verdict)


def _choose(cfg, data, known, used, st, rot, b0, fitter, vertical_known, accel_dirs):
    """The fit kept and its checks (:mod:`.gyro_known_checks`): the turns between still
    periods weighed with their own excess, or left out; returns the verdict and the turns
    between still periods in the fit kept (None: none)."""
    joint, rot_used, why_out, rot_fit = None, rot, None, None
    if data.accel_cal is None:
        res, g_test = _g_choice_without_accel(cfg, fitter(None), data)
    else:
        res, g_test = _g_choice(cfg, fitter(rot))
        own = None if rot is None else checks.own_excess(st, data.noise, rot, res, accel_dirs)
        if own is not None:  # their excess from themselves: a wrong known turn cannot raise it
            tau = checks.significant_excess(own)
            res, g_test = _g_choice(cfg, fitter(rot, tau))
            rot_fit = fitter(rot, tau)
        else:
            rot_fit = fitter(rot)
        level = res.gravity_level if own is None else own.gravity_level
        if rot is not None and (res.tau > 0 or checks.known_disagree(res)) and \
                checks.known_alone(known, b0):
            alone, g_alone = _g_choice(cfg, fitter(None))
            why_out = checks.leave_out(cfg, known, st, data.noise, rot, res, alone, accel_dirs,
                                       level)  # fmt: skip
            if why_out:
                joint, rot_used = res, None  # the turns between still periods: left out
                res, g_test = alone, g_alone
    verdict = checks.judge(data, res, known, used, joint, rot, rot_used,
                           fitter(None) if rot_used is None else rot_fit, g_test,
                           vertical_known, accel_dirs, why_out)  # fmt: skip
    return verdict, rot_used


def _without_known_turns(session, cfg, accel_cal, data, segs) -> SensorCalibration:
    """No turn of known angle can be used (each one's reason is in the notes): the turns
    between still periods alone (the full model) when there are enough of them, else a
    one-line refusal naming why."""
    reasons = [n for n in data.notes if "known angle but" in n]
    why = "; ".join(reasons[:3]) + (f" (and {len(reasons) - 3} more)" if len(reasons) > 3
                                    else "")  # fmt: skip
    if accel_cal is not None and 2 * len(data.turns) >= 9:
        sec = calibrate_gyro_rotations(session, replace(cfg, gyro=replace(cfg.gyro,
                                                                          solver="full")),
                                       accel_cal)  # fmt: skip
        sec.notes = sec.notes or []
        sec.notes.insert(
            0, f"none of the {len(segs)} turns of known angle could be used ({why}): the gyro "
               f"is calibrated by the full model from the {len(data.turns)} turns between still "
               "periods")  # fmt: skip
        return sec
    raise DesignError(
        f"{data.where}: none of the {len(segs)} turns of known angle can be used ({why}), and "
        f"{len(data.turns)} turns between still periods cannot determine the gyro alone: label "
        "each turn's axis in the accelerometer's frame (imucal label SESSION --segment NAME "
        "--axis X,Y,Z, with an accelerometer solved from labelled poses), or turn about the "
        "vertical, flat on a table"
    )


def _accel_part(session, cfg, accel_cal, segs, statics, res, data, rot, known,
                in_weights: bool = False) -> np.ndarray:  # fmt: skip
    """Covariance from the accelerometer calibration (it measures the axes and the still
    directions): refits with its parameters moved by one std along each eigenvector.

    ``in_weights``: the fit already weighed the turns between still periods with the
    accelerometer calibration's part of their noise (its covariance then holds that part);
    only the axes the accelerometer measures (turns about the vertical) are moved, the still
    periods' gravity held (nothing at all when every axis is a label)."""
    cov = None if accel_cal.covariance is None else accel_cal.covariance.values
    n = len(res.cov)
    if cov is None or np.shape(accel_cal.matrix) != (3, 3):
        data.notes.append("the accelerometer calibration states no covariance: the gyro's std "
                          "leave out its uncertainty")  # fmt: skip
        return np.zeros((n, n))
    if in_weights and not any("measured vertical" in note for note in data.notes):
        return np.zeros((n, n))
    # without its frame: the rates are reported in it (the labelled axes' part, off it by its
    # turn, is in the fit's weights: in_accel_frame)
    C = frame_free(np.asarray(cov, float), accel_cal.matrix)
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
            moved = AccelCalibration(solver=accel_cal.solver, units=accel_cal.units,
                                     bias=th[:3], matrix=th[3:].reshape(3, 3),
                                     gauge=accel_cal.gauge)  # fmt: skip
            d.append(_refit(session, cfg, moved, segs, statics, res, data, rot, x, known,
                            in_weights))  # fmt: skip
        dx = (d[0] - d[1]) / 2
        out += np.outer(dx, dx)
    return out


def _refit(session, cfg, accel_cal, segs, statics, res, data, rot, x, known0,
           axes_only: bool = False) -> np.ndarray:  # fmt: skip
    """The fit again with another accelerometer calibration: the same turns, axes' sources
    and excess ``tau`` (the stills' gravity, unless ``axes_only``, and the measured axes move
    with it)."""
    stills, _ = still_periods(session, data.accel_cal if axes_only else accel_cal, cfg, statics)
    known, _, _, _ = known_turns(session, cfg, accel_cal, segs, data.bias_still)
    if len(known.t) != len(known0.t):  # a turn's axis source changed: keep the first one's
        known = known0
    else:
        known = replace(known, angle_sigma=known0.angle_sigma)
    st = solver_stills(stills)
    fit = gyro_known.fit_known(known, st, data.noise, data.bias_still, rot=rot, x0=x[:12],
                               g_sensitivity=res.G is not None, tau=res.tau)  # fmt: skip
    return np.r_[fit.b, fit.M.ravel(), [] if fit.G is None else fit.G.ravel()]
