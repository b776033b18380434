"""Checks of a known-angle gyro fit against its noise (issue 24.5): the turns between still
periods against their own noise, and the turns of known angle against the rest of the fit.

* **Turns between still periods.** Their scatter beyond the stated noise is estimated and
  weighed (:mod:`imucal_cli.estimators.gyro.known`); where it exceeds ``[gyro]
  max_residual_ratio`` they do not match the model (the full model refuses them) and, when the
  known turns determine the gyro alone, they are left out, which the section says with how far
  they miss under the known turns.
* **Turns of known angle.** With spare equations (turns between still periods, or more known
  turns than the 9 terms of the matrix need) each known turn's residual is judged against its
  noise: the stated angle error and the integrated gyro noise along its axis, the axis' std
  across it. A disagreement (chi^2 of the known turns against their redundancy, p below
  :data:`P_DISAGREE`) is explained by the model where one of its terms removes it (a turn's
  reading clipped at the gyro's range; g-sensitivity; the turn's axis: the measured vertical
  instead of the label), else stated; it stops a save (a blocking warning) where a turn misses
  its angle by more than ``max_residual_ratio`` times its noise.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtrc, chdtri

from imucal_cli.calibrate.gyro.full import solver_stills
from imucal_cli.errors import DesignError, SolverError
from imucal_cli.estimators.gyro import known as gyro_known
from imucal_cli.estimators.gyro import known_predict
from imucal_cli.model.codec import nulls
from imucal_cli.model.gyro import KnownTurnCheck, RotationRow

#: The known turns disagree with the rest of the fit below this p-value of their chi^2.
P_DISAGREE = 1e-3


@dataclass
class Verdict:
    """What the checks decided: the result kept (an explanation may refit it), the known
    turns it used, warnings that stop a save (``blocking``) and those that are said
    (``said``), notes, the section's rows of the turns between still periods, and the
    comparison's figures."""

    result: gyro_known.KnownResult
    g_test: dict | None
    known: gyro_known.KnownTurns
    blocking: list[str] = field(default_factory=list)
    said: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    gravity_rows: list[RotationRow] = field(default_factory=list)
    comparison: KnownTurnCheck = field(default_factory=KnownTurnCheck)


def known_alone(known: gyro_known.KnownTurns, b0: np.ndarray) -> bool:
    """Do the known turns determine the matrix on their own (three independent axes)?"""
    try:
        gyro_known.closed_form(known, b0)
    except DesignError:
        return False
    return True


#: Cross-validate the turns between still periods only up to this many (each is one refit).
MAX_HELD_OUT = 40


def own_excess(still, noise, rot, res, accel_dirs):
    """The turns between still periods fitted on their own (from ``res``'s solution, its
    model): their excess ``tau`` and level as they scatter about a model of their own, so
    that a wrong known turn, which pulls the joint fit away from them, is not taken for their
    scatter. None where they cannot determine the model alone (fewer than 5, or a design
    they leave undetermined)."""
    if 2 * len(rot.t) < 9:
        return None
    empty = gyro_known.KnownTurns([], [], np.zeros(0), np.zeros((0, 3)), np.zeros(0),
                                  np.zeros(0))  # fmt: skip
    x0 = np.r_[res.b, res.M.ravel()]
    try:
        return gyro_known.fit_known(empty, still, noise, res.b, rot=rot, x0=x0,
                                    g_sensitivity=res.G is not None, accel_dirs=accel_dirs)
    except (DesignError, SolverError, np.linalg.LinAlgError):
        return None


#: The turns between still periods get an excess only when their chi^2 in the stated noise
#: is above its upper quantile of this probability (as a group's noise scale in
#: :func:`imucal_cli.estimators.gyro.known._covariance`).
EXCESS_P = 0.01


def significant_excess(own) -> float:
    """``own.tau`` (:func:`own_excess`) where the turns between still periods scatter beyond
    their stated noise (chi^2 above its upper :data:`EXCESS_P` quantile), else 0: the positive
    part of an estimate from a few turns is above zero half the time when there is no excess,
    and would widen every std (the Ferraris protocol's simulated sessions: 97.5 % of the 95 %
    intervals held the truth)."""
    r = own.gravity_redundancy
    chi2 = float(np.sum(own.gravity_chi2_stated))
    return own.tau if r > 0.5 and chi2 > chdtri(r, EXCESS_P) else 0.0


def known_disagree(res) -> bool:
    """Do the known turns disagree with the rest of the fit (p below :data:`P_DISAGREE`)?"""
    return _known_p(res)[2] < P_DISAGREE


def leave_out(cfg, known, still, noise, rot, joint, alone, accel_dirs, level=None
              ) -> str | None:  # fmt: skip
    """Why the turns between still periods, which scatter beyond their noise (``joint.tau``
    > 0), are left out of a fit the known turns determine alone, or None to keep them. Out
    when they miss the model by more than ``[gyro] max_residual_ratio`` times their noise
    (``level``: fitted on their own where they can be, :func:`own_excess`; the full model
    refuses such turns), or when they do not predict one another better than the
    known turns alone predict them (each turn held out of the joint fit in turn: mean squared
    gravity residual): their scatter is then not noise the fit averages but something the
    model lacks, and weighing them in moves the gains away from the known angles for
    nothing."""
    limit = cfg.gyro.max_residual_ratio
    if (joint.gravity_level if level is None else level) > limit:
        return f"more than [gyro] max_residual_ratio = {limit:g}"
    if len(rot.t) > MAX_HELD_OUT:
        return None
    try:
        held = known_predict.held_out_turns(known, still, noise, rot, joint, accel_dirs=accel_dirs)
    except (DesignError, SolverError):
        return None
    by_known = known_predict.predict_gravity(rot, still, noise, alone, accel_dirs)
    rms_held = float(np.sqrt(np.mean(held**2)))
    rms_known = float(np.sqrt(np.mean(by_known["gravity_residual_deg"] ** 2)))
    if rms_held < rms_known:
        return None
    return (f"and each held out of the fit with the others is predicted to {rms_held:.2g} deg "
            f"RMS, no better than by the known turns alone ({rms_known:.2g} deg)")


def _names(items) -> list[str]:
    return [s.label or s.name for s in items]


def judge(data, res, known, used, joint, rot, rot_used, fit, g_test, vertical_known,
          accel_dirs=None, why_out: str | None = None) -> Verdict:  # fmt: skip
    """Check a known-angle fit (module notes).

    Parameters
    ----------
    data : GyroData
    res : KnownResult
        The fit kept so far (without the turns between still periods when ``joint`` is set).
    known, used : KnownTurns, list of Segment
    joint : KnownResult or None
        The fit with the turns between still periods, when they were left out after it.
    rot, rot_used : Rotations or None
        All turns between still periods, and those in ``res`` (None: none).
    fit : callable
        ``fit(with_g, tau, known)`` refits with ``rot_used``.
    g_test : dict or None
    vertical_known : callable
        The known turns with the measured vertical as the axis of every turn about it.
    accel_dirs : ndarray, optional
        The accelerometer calibration's error as it moves the still periods' gravity
        (:func:`imucal_cli.estimators.gyro.known.accel_blocks`).
    why_out : str, optional
        Why the turns between still periods were left out (:func:`leave_out`).
    """
    v = Verdict(res, g_test, known)
    limit = data.cfg.gyro.max_residual_ratio
    gravity_names = _names([t.segment for t in data.turns])
    if joint is not None:
        _left_out(v, data, joint, rot, gravity_names, why_out, len(used), accel_dirs)
    elif rot_used is not None:
        _weighed(v, data, res, gravity_names, limit)
    _known_check(v, data, used, fit, vertical_known, limit)
    return v


def _gravity_rows(names, segments, stats, used: bool) -> list[RotationRow]:
    return [RotationRow(segment=s.name, label=s.label, known_angle_deg=None,
                        measured_angle_deg=float(a), angle_error_deg=float(r),
                        noise_deg=float(sg), measured_by="gravity", used=used)
            for s, a, r, sg in zip(segments, stats["gravity_angle_deg"],
                                   stats["gravity_residual_deg"], stats["gravity_sigma_deg"],
                                   strict=True)]  # fmt: skip


def _worst(names, values, unit="deg", n=3) -> str:
    order = np.argsort(-np.asarray(values))[:n]
    return ", ".join(f"{names[k]} {values[k]:.2f} {unit}" for k in order)


def _left_out(v: Verdict, data, joint, rot, names, why, n_known, accel_dirs) -> None:
    """The turns between still periods were left out (:func:`leave_out`): said, with how the
    known turns alone predict them."""

    st = solver_stills(data.stills, data.round_cov)
    pred = known_predict.predict_gravity(rot, st, data.noise, v.result, accel_dirs)
    v.gravity_rows = _gravity_rows(names, [t.segment for t in data.turns], pred, used=False)
    miss = pred["gravity_residual_deg"]
    tau = float(np.degrees(joint.tau))
    c = v.comparison
    c.turns_between_still_periods, c.their_level, c.their_excess_deg = (
        "left out", joint.gravity_level, tau)  # fmt: skip
    c.their_rms_under_known_deg, c.why_left_out = float(np.sqrt(np.mean(miss**2))), why
    v.said.append(
        f"the {len(names)} turns between still periods miss the gravity direction by "
        f"{joint.gravity_level:.1f} times their noise (the still periods', the gyro's and the "
        f"accelerometer calibration's; {tau:.2g} deg per turn beyond it), {why}: they do not "
        "match the gyro model to their noise (a hand flip moves the unit in ways a rate "
        "integral between still periods does not hold, or the unit moved while still), so "
        f"they are left out and the gyro rests on the {n_known} turns of known angle; under "
        f"those they miss by {np.sqrt(np.mean(miss**2)):.2g} deg RMS (worst: "
        f"{_worst(names, miss)})"
    )


def _weighed(v: Verdict, data, res, names, limit) -> None:
    """The turns between still periods are in the fit: their excess, said or refused."""
    v.gravity_rows = _gravity_rows(names, [t.segment for t in data.turns],
                                   {k: getattr(res, k) for k in (
                                       "gravity_angle_deg", "gravity_residual_deg",
                                       "gravity_sigma_deg")}, used=True)  # fmt: skip
    level, tau = res.gravity_level, float(np.degrees(res.tau))
    c = v.comparison
    c.turns_between_still_periods, c.their_level, c.their_excess_deg = "used", level, tau
    if level > limit:  # the known turns cannot do without them: as the full model, refused
        v.blocking.append(
            f"the turns' gravity residuals are {level:.0f} times what the noise predicts "
            f"(worst: {_worst(names, res.gravity_residual_deg)}): the model does not match "
            "this sensor or these turns (a wrong time base, motion during the still periods), "
            "and the turns of known angle cannot determine the gyro without them"
        )
    elif tau > 0:
        v.notes.append(
            f"the {len(names)} turns between still periods scatter {level:.1f} times their "
            f"stated noise: each is weighed with {tau:.2g} deg more (per direction, estimated "
            "from their scatter)"
        )


def _known_p(res) -> tuple[float, float, float]:
    chi2 = float(np.sum(res.known_chi2))
    r = res.known_redundancy
    return chi2, r, float(chdtrc(r, chi2)) if r > 0.5 else 1.0


def _known_check(v: Verdict, data, used, fit: Callable, vertical_known: Callable, limit) -> None:
    """The known turns against their noise and the rest of the fit (module notes)."""
    res = v.result
    names = _names(used)
    ratio = np.abs(res.angle_error_deg) / np.maximum(res.angle_sigma_deg, 1e-12)
    chi2, r, p = _known_p(res)
    v.comparison.known_chi2, v.comparison.known_redundancy, v.comparison.known_p_value = (
        chi2, r, p)  # fmt: skip
    if r <= 0.5:
        return  # nothing checks them (said by the spare-equation note)
    if p >= P_DISAGREE and ratio.max() <= limit:
        return
    how = _explain(v, data, used, fit, vertical_known)
    if how is not None:
        v.said.append(
            f"the turns of known angle disagreed with the rest of the fit ({_angles(res, names)}; "
            f"chi^2 {chi2:.3g} for {r:.2g} spare equations, p = {p:.2g}): {how}"
        )
        return
    text = (f"the turns of known angle disagree with the rest of the fit ({_angles(res, names)}; "
            f"chi^2 {chi2:.3g} for {r:.2g} spare equations, p = {p:.2g}), which the model does "
            "not explain (the turn's axis, a clipped reading, g-sensitivity): check each turn's "
            "angle and sign (angle_deg), that it ended against the same stop it started from, "
            "and that the unit was still before and after")  # fmt: skip
    nulls(v.comparison, "explained_by")  # checked, nothing explains it
    (v.blocking if ratio.max() > limit else v.said).append(text)


def _angles(res, names) -> str:
    return ", ".join(
        f"{n} {m:+.1f} deg for {m - e:+.0f} (noise {s:.2g})"
        for n, m, e, s in zip(names, res.measured_angle_deg, res.angle_error_deg,
                              res.angle_sigma_deg, strict=True)
    )  # fmt: skip


def _explain(v: Verdict, data, used, fit, vertical_known) -> str | None:
    """A term of the model that removes the disagreement: the refit is kept. None when none
    does."""
    clipped = [w for w in data.warnings if "reaches the end of the gyro's range" in w]
    if clipped:
        v.comparison.explained_by = "clipped"
        return ("a turn of known angle reached the end of the gyro's range (its integral is "
                "short): turn more slowly")  # fmt: skip
    res = v.result
    tries = []
    mode = data.cfg.gyro.full.g_sensitivity
    if res.G is None and mode != "off" and v.known.a is not None:  # needs the accelerometer
        tries.append(("g-sensitivity", lambda: fit(True, res.tau, v.known), None))
    alt = vertical_known()
    if alt is not None:
        tries.append(("the turn's axis", lambda: fit(res.G is not None, res.tau, alt), alt))
    for name, refit, known in tries:
        try:
            new = refit()
        except DesignError:
            continue
        if _known_p(new)[2] >= P_DISAGREE:
            v.result = new
            v.comparison.explained_by = name
            if known is not None:
                v.known = known
            if name == "g-sensitivity":
                v.g_test = {**(v.g_test or {}), "included": True, "observable": True,
                            "reason": "it removes the known turns' disagreement"}  # fmt: skip
                return "explained by the gyro's g-sensitivity, now in the model"
            return ("explained by the turns' axes: each turn about the vertical is taken about "
                    "the vertical the accelerometer measured, not its label (the unit did not "
                    "sit square on its face, or the table is not level)")
    return None
