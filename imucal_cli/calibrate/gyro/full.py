"""The full gyro model in the calibrate step: 12 parameters (bias, scale and misalignment in
the accelerometer's frame), or 21 with the g-sensitivity when the data call for it
(:mod:`imucal_cli.estimators.gyro.full`).

A fit is checked against the noise (issue 10.2): when the turns' gravity residuals are far
above what the noise predicts, all of them (the model does not match the sensor) or some of
them (those turns disagree with the rest), the section gets a warning naming the segments, so
that ``calibrate`` refuses to save it without ``--force``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from imucal_cli.calibrate.common import num
from imucal_cli.calibrate.gyro.turns import AXES, GyroData, GyroFit, Still
from imucal_cli.calibrate.thermal import sample_temperature
from imucal_cli.errors import ImucalError
from imucal_cli.estimators.accel.frame import frame_free, frame_split
from imucal_cli.estimators.gyro import full as gyro_full
from imucal_cli.estimators.gyro import sigma as gyro_sigma
from imucal_cli.estimators.gyro.known_turns import accel_factor
from imucal_cli.model.codec import build
from imucal_cli.model.gyro import (
    AccelPropagation,
    GSensitivityTest,
    RateStd,
    RotationRow,
    StdRatio,
)
from imucal_cli.model.parts import Parameter
from imucal_cli.numerics.segmented import stacked_rows
from imucal_cli.planning.information import axes_std

#: Medians of the chi-square distribution with 2 (a turn's two residuals) and 3 (a still
#: period's gyro mean) degrees of freedom.
CHI2_2_MEDIAN, CHI2_3_MEDIAN = 2 * np.log(2), 2.365974


def turn_windows(data: GyroData) -> list[slice]:
    """The samples each turn is integrated over: its segment, and the still periods' edge
    samples it touches (the last still sample before it, the first after). The attitude is
    the still period's up to its last sample, so the interval from there to the turn's first
    sample, where the unit already moves, belongs to the turn: integrated from its own first
    sample, the turn lost half an interval's rotation at each end (at 50 Hz, turns of 0.5 s
    came out 0.1 % short, the gyro's gains 4 std off)."""
    stills, n = data.stills, len(data.session.time)
    out = []
    for t in data.turns:
        a, b = t.segment.start, t.segment.stop
        if a > 0 and stills[t.before].segment.stop == a:
            a -= 1
        if b < n and stills[t.after].segment.start == b:
            b += 1
        out.append(slice(a, b))
    return out


def rotations_and_stills(data: GyroData) -> tuple[gyro_full.Rotations, gyro_full.Stills]:
    """The solver's view of the turns (over :func:`turn_windows`) and still periods
    (calibrated accel in each turn: the calibration applied once to all turns' samples)."""
    session = data.session
    windows = turn_windows(data)
    rows, counts = stacked_rows([w.start for w in windows], [w.stop for w in windows])
    a = data.accel_cal.apply(session.accel.take(rows, axis=0))
    rot = gyro_full.Rotations(
        t=[session.time[w] for w in windows],
        z=[session.gyro[w] for w in windows],
        before=np.array([t.before for t in data.turns]),
        after=np.array([t.after for t in data.turns]),
        a=np.split(a, np.cumsum(counts)[:-1]),
    )
    return rot, solver_stills(data.stills, data.round_cov)


def solver_stills(stills: list[Still], round_cov: np.ndarray | None = None) -> gyro_full.Stills:
    """The solver's view of the still periods: calibrated gravity and its direction noise,
    the raw gyro mean and its noise (floored at 1e-12: a quantised gyro can read constant),
    and the covariance of the means' rounding errors (``round_cov``, (3, P, P) raw units^2)."""
    return gyro_full.Stills(
        g=np.array([s.g for s in stills]),
        g_sigma=np.array([s.g_sigma for s in stills]),
        z_mean=np.array([s.z_mean for s in stills]),
        z_sigma=np.array([max(s.z_sigma, 1e-12) for s in stills]),
        z_round=round_cov,
    )


def fit_full_model(data: GyroData, g_sensitivity: str | None = None) -> GyroFit:
    """Fit the full model (g-sensitivity per ``[gyro.full] g_sensitivity`` unless given)."""
    cfg = data.cfg
    rot, st = rotations_and_stills(data)
    res = gyro_full.fit_full(
        rot, st, data.noise, data.bias_still,
        max_iterations=cfg.gyro.full.max_iterations,
        g_sensitivity=g_sensitivity or cfg.gyro.full.g_sensitivity,
    )  # fmt: skip
    data.notes.extend(res.notes)
    uncertainty = add_accel_uncertainty(data, rot, st, res)
    units = data.units_in
    parameters = parameter_rows(res, units)
    rotations = [
        RotationRow(segment=t.segment.name, label=t.segment.label, known_angle_deg=None,
                    measured_angle_deg=float(a), angle_error_deg=float(r),
                    noise_deg=float(s))
        for t, r, a, s in zip(data.turns, res.angle_residual_deg, res.rotation_angle_deg,
                              res.turn_sigma_deg, strict=True)
    ]  # fmt: skip
    data.warnings.extend(residual_warnings(data, res, rot, st))
    S = np.linalg.inv(res.M)
    s_axes = S / np.linalg.norm(S, axis=1, keepdims=True)
    members = {
        "approach": "full",
        # Angles between the gyro's sensitivity axes, minus 90 (as for the accelerometer)...
        "misalignment_deg": {
            f"{AXES[i]}{AXES[j]}": float(np.degrees(np.arccos(s_axes[i] @ s_axes[j])) - 90)
            for i, j in ((0, 1), (0, 2), (1, 2))
        },
        # ...and of each sensitivity axis from the accelerometer's axis of the same name.
        "axis_to_accel_frame_deg": {
            a: float(np.degrees(np.arccos(np.clip(s_axes[i, i], -1, 1))))
            for i, a in enumerate(AXES)
        },
        "iterations": res.iterations, "chi2": res.chi2, "dof": res.dof,
        "noise_scale": res.noise_scale,
        "rate_std": uncertainty,
        "sensitivity_std": gain_std(res.M, res.cov[3:12, 3:12]).tolist(),
        # std of misalignment_deg (delta method), for targets (capture --until)
        "misalignment_std_deg": dict(zip(("xy", "xz", "yz"), map(float, axes_std(
            res.M, res.cov[3:12, 3:12])[2]), strict=True)),
    }  # fmt: skip
    undetermined = design_warning(data, uncertainty)
    nonlinear = None if uncertainty.accel_propagation is None else (
        uncertainty.accel_propagation.warning)  # fmt: skip
    data.warnings.extend(w for w in (undetermined, nonlinear) if w)
    # Std that sigma points can state only roughly: left out by auto like an undetermined gyro.
    if undetermined or nonlinear:
        members["undetermined"] = undetermined or nonlinear
    if res.G is not None:
        members["g_sensitivity"] = res.G
        members["g_sensitivity_unit"] = f"{units} per m/s^2 (raw - bias - g_sensitivity @ a)"
    if res.g_test is not None:
        members["g_sensitivity_test"] = build(GSensitivityTest, **res.g_test)
        data.notes.append(_g_note(res.g_test))
    return GyroFit(res.b, res.M, parameters, rotations, np.radians(res.angle_residual_deg),
                   np.linalg.norm(S, axis=1), members)  # fmt: skip


def parameter_rows(res, units: str) -> list[Parameter]:
    """The section's parameter rows of a full-model result ``res`` (``b``, ``M``, optional
    ``G``, ``std``): bias in raw ``units``, matrix in rad/s per raw unit, g-sensitivity."""
    n = len(res.std)
    unit = [units] * 3 + [f"rad/s per {units}"] * 9 + [f"{units} per m/s^2"] * 9
    values = np.r_[res.b, res.M.ravel(), [] if res.G is None else res.G.ravel()]
    return [
        Parameter(name, float(v), num(s), u)
        for name, v, s, u in zip(gyro_full.parameter_names(n), values, res.std, unit[:n],
                                 strict=True)  # fmt: skip
    ]


def accel_derivative(stills, accel_cal) -> np.ndarray | None:
    """(P, 3, 12): how each still period's calibrated accel mean ``A (raw - B)`` moves with
    the accelerometer's ``(B, A row-major)``; None when the accelerometer is not a triad."""
    A, B = np.asarray(accel_cal.matrix, float), np.asarray(accel_cal.bias, float)
    if A.shape != (3, 3):
        return None
    d = np.array([s.a_raw for s in stills]) - B  # (P, 3)
    out = np.zeros((len(stills), 3, 12))
    out[:, :, :3] = -A
    for i in range(3):
        out[:, i, 3 + 3 * i : 6 + 3 * i] = d
    return out


def accel_uncertainty(data: GyroData, with_frame: bool = False):
    """``(dg, C, shift)``: :func:`accel_derivative` and the accelerometer calibration's
    covariance, with the columns of its temperature terms where its poses were compensated
    (the section's ``compensation``): a term's error ``dc`` moves still period k's raw mean by
    ``-(T_k - T_ref)^j dc`` in its channel, jointly with the calibration's own error (one fit
    gave both; docs/temperature.md). ``shift(d, T)`` is that move, (N, 3), at temperatures
    ``T``, or None without terms; None without a covariance or a triad. ``C`` is without the
    rotation of the accelerometer's frame (:func:`~imucal_cli.estimators.accel.frame.
    frame_free`) unless ``with_frame``: a gyro the turns between still periods determine
    reports in that frame and turns with it wholly; turns about labelled axes hold it to the
    labels' frame instead (the known-angle solver keeps the frame's part)."""
    cal = data.accel_cal
    cov = None if cal is None or cal.covariance is None else cal.covariance.values
    dg = None if cov is None else accel_derivative(data.stills, cal)
    if dg is None:
        return None
    comp = getattr(cal, "compensation", None)
    temp = sample_temperature(data.session)
    Am = np.asarray(cal.matrix, float)

    def frame(C):  # the frame's turn moves the gyro with it: not its error
        return np.asarray(C, float) if with_frame else frame_free(C, Am)

    if comp is None or temp is None:
        return dg, frame(cov), None

    def shift(d: np.ndarray, T: np.ndarray) -> np.ndarray:
        out = np.zeros((len(T), 3))
        for v, (j, c) in zip(d, comp.columns, strict=True):
            out[:, c] -= v * (T - comp.temperature_ref) ** j
        return out

    T = np.array([temp[s.segment.start : s.segment.stop].mean() for s in data.stills])
    eye = np.eye(len(comp.columns))
    extra = np.stack([shift(e, T) @ Am.T for e in eye], axis=2)  # (P, 3, terms)
    return np.concatenate([dg, extra], axis=2), frame(comp.covariance), shift


def gain_std(M: np.ndarray, cov_M: np.ndarray) -> np.ndarray:
    """Std of the gains (row norms of ``M^-1``, raw units per rad/s): delta method."""
    S = np.linalg.inv(M)
    gains = np.linalg.norm(S, axis=1)
    # d(M^-1) = -S dM S, so d g_i = u_i . d s_i = -sum_kl S_ik dM_kl (S_l . u_i)
    J = np.array([-np.outer(S[i], S @ (S[i] / gains[i])).ravel() for i in range(3)])
    return np.sqrt(np.clip(np.diag(J @ cov_M @ J.T), 0, None))


def rate_std(M: np.ndarray, cov_M: np.ndarray) -> float:
    """Relative std of a calibrated rate in its worst direction: ``omega`` is off by
    ``dM M^-1 omega``; the largest eigenvalue of ``E[(dM M^-1)^T (dM M^-1)]``."""
    K = np.kron(np.eye(3), np.linalg.inv(M).T)  # vec(dM M^-1) = K vec(dM), row-major
    C = K @ cov_M @ K.T
    Q = sum(C[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] for i in range(3))
    return float(np.sqrt(max(np.linalg.eigvalsh(Q)[-1], 0.0)))


def add_accel_uncertainty(data: GyroData, rot, st, res) -> RateStd:
    """Add the accelerometer calibration's uncertainty to the fit's covariance (issue 10.2).

    The turns are measured against gravity directions that the calibrated accelerometer
    gives: its error moves every direction together and does not average out over turns.
    Where the design leaves the gyro barely determined (the 5 moves between six faces), it
    dominates: ignoring it stated the gains 20 times too precise. Returns the rate std
    (relative, worst direction) in total, from the noise and from the accelerometer."""
    noise_only = rate_std(res.M, res.cov[3:12, 3:12])
    found = accel_uncertainty(data)
    out = RateStd(total=noise_only, noise=noise_only, accel_calibration=None,
                  meaning="relative std of a calibrated rate in its worst direction")
    if found is None:
        data.notes.append("the accelerometer calibration states no covariance: the gyro's std "
                          "leave out its uncertainty")  # fmt: skip
        return out
    dg, C, shift = found
    A = gyro_full.accel_sensitivity(rot, st, data.noise, res, dg)
    prop = accel_propagation(data, rot, st, res, C, A, shift)
    cov_a = prop.cov
    own = res.cov
    linear_total = rate_std(res.M, (own + prop.linear)[3:12, 3:12])
    res.cov = own + cov_a
    out.accel_calibration = rate_std(res.M, cov_a[3:12, 3:12])
    out.total = rate_std(res.M, res.cov[3:12, 3:12])
    out.accel_propagation = build(AccelPropagation, **prop.summary())
    how = ""
    if prop.method == "sigma points":
        first = own + prop.linear
        ratios = {
            "parameters": float(np.max(np.sqrt(np.diag(res.cov) / np.diag(first)))),
            "gains": float(np.max(gain_std(res.M, res.cov[3:12, 3:12])
                                  / gain_std(res.M, first[3:12, 3:12]))),
            "rate": out.total / linear_total,
        }  # fmt: skip
        out.accel_propagation.first_order_total = linear_total
        out.accel_propagation.std_ratio = StdRatio(**ratios)
        how = (f" (by refitting at {prop.refits} sigma points: the first order gave "
               f"{100 * linear_total:.2g} %)")
        warning = nonlinear_warning(ratios, prop)
        if warning:  # added to the section's warnings after the design's own
            out.accel_propagation.warning = warning
    data.notes.append("std include the accelerometer calibration's uncertainty (the turns are "
                      f"measured with it): rates to {100 * out.total:.2g} % (1 std), "
                      f"{100 * out.accel_calibration:.2g} % of it from the accelerometer"
                      f"{how}")
    return out


def accel_propagation(data: GyroData, rot, st, res, C: np.ndarray, A: np.ndarray,
                      shift=None):  # fmt: skip
    """The accelerometer calibration's part of the gyro covariance: first order, or by
    refitting the gyro at sigma points of the accelerometer's parameters (and of its
    temperature terms, ``shift``: :func:`accel_uncertainty`) where the first order is
    doubtful (:func:`imucal_cli.estimators.gyro.sigma.propagate`)."""
    acc = data.accel_cal
    a_raw = np.array([s.a_raw for s in data.stills])
    with_g = res.G is not None
    windows = turn_windows(data)
    turn_raw = [data.session.accel[w] for w in windows] if with_g else None
    x_hat = np.r_[res.b, res.M.ravel(), res.G.ravel() if with_g else []]
    theta_hat = np.r_[np.asarray(acc.bias, float), np.ravel(acc.matrix), np.zeros(len(C) - 12)]
    temp = None if shift is None else sample_temperature(data.session)
    t_still = None if temp is None else np.array(
        [temp[s.segment.start : s.segment.stop].mean() for s in data.stills])  # fmt: skip

    def moved(theta: np.ndarray):
        B, Am, d = theta[:3], theta[3:12].reshape(3, 3), theta[12:]
        a_st, turns = a_raw, turn_raw
        if temp is not None and d.any():
            a_st = a_raw + shift(d, t_still)
            turns = None if not with_g else [
                r + shift(d, temp[w]) for r, w in zip(turn_raw, windows, strict=True)]
        moved_st = replace(st, g=(a_st - B) @ Am.T)
        moved_rot = rot if not with_g else replace(rot, a=[(r - B) @ Am.T for r in turns])
        return moved_rot, moved_st

    def refit(theta: np.ndarray, x_start: np.ndarray) -> np.ndarray | None:
        return gyro_full.refit_moved(*moved(theta), data.noise, res, x_start,
                                     max_iterations=data.cfg.gyro.full.max_iterations)

    def step(theta: np.ndarray, x_start: np.ndarray) -> np.ndarray | None:
        return gyro_full.step_moved(*moved(theta), data.noise, res, x_start)

    return gyro_sigma.propagate(x_hat, theta_hat, C, A, res.cov, refit, step)


#: The sigma-point std of a parameter, a gain or the rate this many times the first order's
#: (or less than its inverse), or a sigma-point refit that fails: the std rest on a strongly
#: nonlinear dependence and are too approximate to save unasked.
NONLINEAR_RATIO = 1.5


def nonlinear_warning(ratios: dict, prop) -> str | None:
    """A warning when the gyro depends on the accelerometer calibration so nonlinearly that its
    std (by sigma points) are only a rough guide: far from the first order, or refits that
    fail (issue 10)."""
    what, worst = max(ratios.items(), key=lambda kv: max(kv[1], 1 / max(kv[1], 1e-300)))
    if max(worst, 1 / max(worst, 1e-300)) <= NONLINEAR_RATIO and not prop.failed:
        return None
    names = {"parameters": "a parameter's", "gains": "a gain's", "rate": "the rate's"}
    failed = (f"; {prop.failed} of {prop.refits} refits did not converge" if prop.failed
              else "")  # fmt: skip
    return (f"the gyro depends nonlinearly on the accelerometer calibration that measures its "
            f"turns: refitted at sigma points of the accelerometer's uncertainty, "
            f"{names[what]} std is {worst:.2g} times the first-order one{failed}; the std "
            "stated are the sigma points' and only approximate; calibrate the accelerometer "
            "better (--accel CAL.json from a session with more poses) or turn the unit 10 or "
            "more times about different axes (plan free:N)")


def design_warning(data: GyroData, uncertainty: RateStd, n_turns: int | None = None,
                   why: str | None = None) -> str | None:
    """A warning when the turns do not determine the gyro to ``[gyro] max_rate_std``, naming
    the cause and what would work (``why``: the caller's, where it knows better than the
    number of turns, e.g. turns of known angle whose labelled axes limit it)."""
    limit = data.cfg.gyro.max_rate_std
    total, acc = uncertainty.total, uncertainty.accel_calibration or 0.0
    if total <= limit:
        return None
    K = len(data.turns) if n_turns is None else n_turns
    head = (f"{K} turns determine the gyro's rates only to {100 * total:.2g} % (1 std, worst "
            f"direction; more than [gyro] max_rate_std = {limit:g})")  # fmt: skip
    if acc > uncertainty.noise:
        ang = data.accel_cal.misalignment_std_deg or {}
        worst = max(ang.values(), default=None)
        axes = "" if worst is None else f", its axes' angles known to {worst:.2g} deg"
        return (f"{head}: mostly from the accelerometer calibration that measures each turn "
                f"({100 * acc:.2g} %{axes}); use a better one: --accel CAL.json from a "
                "session with more poses (plan qureshi18 or random:N), or turn the unit 10 or "
                "more times about different axes (plan free:N)")  # fmt: skip
    more = "".join(f"; {w}" for w in data.left_out)
    if why is not None:
        return f"{head}: {why}{more}"
    return (f"{head}: too few or too small turns for the 12 parameters; turn the unit 10 or "
            f"more times, about different axes, still before and after each (plan free:N){more}")


def _g_note(test: dict) -> str:
    if not test.get("observable"):
        return ("g-sensitivity: not determined by these still periods and turns (hold the unit "
                "still with opposite faces up to measure it): left out")  # fmt: skip
    verdict = "included" if test["included"] else "not significant: left out"
    return (f"g-sensitivity: {verdict} (F = {test['F']:.3g} on {test['dof'][0]} and "
            f"{test['dof'][1]} dof, p = {test['p_value']:.2g})")  # fmt: skip


def accel_directions(data: GyroData, with_frame: bool = False) -> np.ndarray | None:
    """(P, 3, m): the still periods' calibrated gravity vectors moved along each square-root
    direction of the accelerometer calibration's covariance (None without one; its frame's
    turn as :func:`accel_uncertainty` says)."""
    found = accel_uncertainty(data, with_frame)
    if found is None:
        return None
    dg, C, _ = found
    return dg @ _root(C)


def accel_directions_and_frame(data: GyroData) -> tuple[np.ndarray, np.ndarray] | None:
    """``(dirs, phi)``: :func:`accel_directions` without the frame's turn (P, 3, m), and the
    turn of the frame along the same square-root directions of the accelerometer
    calibration's covariance (3, m), rad; None without a covariance. A gyro that turns about
    labelled axes is held partly to the labels' frame, and ``phi`` is how far the
    accelerometer's frame, which the rates are reported in, is from it
    (:attr:`imucal_cli.estimators.gyro.known.KnownTurns.frame`)."""
    found = accel_uncertainty(data, with_frame=True)
    if found is None:
        return None
    dg, C, _ = found
    root = _root(C)
    L, phi = frame_split(data.accel_cal.matrix, len(C))
    return dg @ (L @ root), phi @ root


def _root(C: np.ndarray) -> np.ndarray:
    """A square root ``R`` of a covariance, ``R R^T = C`` (eigenvectors times the roots of
    their eigenvalues, negative rounding clipped)."""
    lam, V = np.linalg.eigh((C + C.T) / 2)
    return V * np.sqrt(np.clip(lam, 0, None))


def turn_chi2(res, x=None, dirs=None, cov=None) -> np.ndarray:
    """Each turn's chi^2 (2 dof) at ``x`` (default ``res``'s solution) in the noise the model
    predicts for it: the still periods' and the gyro's (``res.turn_chi2``'s), the
    accelerometer calibration's part (``dirs``, :func:`accel_directions`: its error moves the
    gravity before and after every turn; issue 24.7c: a random:9 session's accelerometer,
    9 poses for its 9 parameters, put turns 2-17 times their stated noise off where the true
    accelerometer left them within it), and, for a turn the parameters ``x`` were fitted
    without, their uncertainty ``cov`` carried to its residual (a prediction, not a fit)."""
    gp = res.problem
    x = np.r_[res.b, res.M.ravel(), [] if res.G is None else res.G.ravel()] if x is None else x
    blocks = gyro_full._diagonal_blocks(gp.rotation_covariance(x), gp.K)
    if dirs is not None:
        F = accel_factor(gp, x, dirs)
        blocks = blocks + np.einsum("kam,kbm->kab", F, F)
    if cov is not None:
        _, J = gp.residuals_and_jacobian(x)
        Jk = J[: 2 * gp.K].reshape(gp.K, 2, -1)
        blocks = blocks + np.einsum("kai,ij,kbj->kab", Jk, cov, Jk)
    r = gp.raw_residuals(x)[: 2 * gp.K].reshape(gp.K, 2)
    return np.einsum("ki,ki->k", r, np.linalg.solve(blocks, r[:, :, None])[:, :, 0])


def residual_warnings(data: GyroData, res, rot, st) -> list[str]:
    """Turns whose gravity residual is far above what the noise predicts (issue 10.2).

    The level of the fit is the turns' robust RMS ratio to their predicted noise
    (``sqrt(median chi^2 / median of chi^2_2)``, :func:`turn_chi2`: with the accelerometer
    calibration's part); the fit is refused when that level exceeds ``[gyro]
    max_residual_ratio`` (the model does not match the sensor), or when turns exceed that
    ratio times the level of the others. A bad turn pulls the fit towards itself and raises
    the others' residuals, so the worst turns are also checked out of sample: refitted
    without them, do they still disagree by that much (their prediction's uncertainty
    included)?
    """
    limit = data.cfg.gyro.max_residual_ratio
    dirs = accel_directions(data)
    chi2 = res.turn_chi2 if dirs is None or res.problem is None else turn_chi2(res, dirs=dirs)
    level = _level(chi2)
    names = [t.segment.label or t.segment.name for t in data.turns]
    tested = res.G is not None or (res.g_test or {}).get("observable")
    if level > limit:
        g = "" if tested else 'g-sensitivity ([gyro.full] g_sensitivity = "on"), '
        worst = _describe(np.argsort(-chi2), names, res.angle_residual_deg, res)
        return [
            f"the turns' gravity residuals are {level:.0f} times what the noise predicts "
            f"(worst: {worst}): the model does not match this sensor or these turns ({g}a "
            "wrong time base, motion during the still periods)"
        ]
    outliers, resid = _outliers(data, res, rot, st, level, limit, chi2, dirs)
    if outliers:
        return [
            f"{len(outliers)} turn(s) disagree with the others: "
            f"{_describe(outliers, names, resid, res)}, more than {limit:g} times the others' "
            "level even when fitted without them: the unit moved during the still before or "
            "after, or the turn was clipped; re-capture or remove those segments"
        ]
    still_level = float(np.sqrt(np.median(res.still_chi2) / CHI2_3_MEDIAN))
    if still_level > limit:
        hint = ("the bias drifted between them" if tested else
                'the gyro is g-sensitive ([gyro.full] g_sensitivity = "on"), or the bias drifted')
        return [
            f"the gyro's still readings differ between the still periods by {still_level:.0f} "
            f"times their noise: {hint}"
        ]
    return []


#: Outlier candidates: turns beyond this share of the limit (times the level) are checked out of
#: sample; at most this many at once.
CANDIDATE_SHARE, MAX_CANDIDATES = 0.3, 3


def _level(chi2: np.ndarray) -> float:
    return float(np.sqrt(np.median(chi2) / CHI2_2_MEDIAN))


def _outliers(data, res, rot, st, level, limit, chi2_fit, dirs) -> tuple[list[int], np.ndarray]:
    """Turns that disagree with the rest out of sample (refit without them: each one's
    residual against its noise, the accelerometer calibration's part and the refit's
    uncertainty carried to it, :func:`turn_chi2`)."""
    ratio = np.sqrt(chi2_fit / 2)
    order = np.argsort(-ratio)
    candidates = [int(k) for k in order[:MAX_CANDIDATES]
                  if ratio[k] > CANDIDATE_SHARE * limit * max(level, 1.0)]  # fmt: skip
    if not candidates or len(data.turns) - len(candidates) < 5:
        return [], res.angle_residual_deg
    try:
        refit, chi2, resid = gyro_full.refit_without(
            rot, st, data.noise, res, candidates, max_iterations=data.cfg.gyro.full.max_iterations
        )
    except ImucalError:
        return [], res.angle_residual_deg
    if res.problem is not None:
        x = np.r_[refit.b, refit.M.ravel(), [] if refit.G is None else refit.G.ravel()]
        chi2 = turn_chi2(res, x, dirs)
        chi2[candidates] = turn_chi2(res, x, dirs, refit.cov)[candidates]
    others = _level(np.delete(chi2, candidates))
    out = [k for k in candidates if np.sqrt(chi2[k] / 2) > limit * max(others, 1.0)]
    return out, resid


def _describe(idx, names, resid, res, n=3) -> str:
    idx = list(idx)
    more = f" and {len(idx) - n} more" if len(idx) > n else ""
    return ", ".join(f"{names[i]} ({resid[i]:.2f} deg where the noise predicts "
                     f"{res.turn_sigma_deg[i]:.2f})" for i in idx[:n]) + more  # fmt: skip
