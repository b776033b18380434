"""The accelerometer of a design that cannot fix the whole model (issue 27.3): a vehicle's or
robot's log (a few still periods tilted about one axis), poses on one or two faces.  The
gravity-magnitude equations are fitted with a prior on every parameter
(:mod:`imucal_cli.estimators.accel.partial`): what the poses determine is measured, the rest
held at the prior (nominal values, or an earlier calibration given with ``--prior``) with the
prior's std, and the section says which are which (``"partial"``, each parameter's
``status``) and which poses would determine the rest.

The nominal prior (docs/solvers.md, "Partial designs"): gains the nominal sensitivity +- 3 %,
bias the nominal offset +- 60 mg, angles between the axes 90 deg +- 2 deg (1 std each): the
initial tolerances of consumer 6-axis parts' datasheets (sensitivity +-3 %, zero-g offset
+-50 to +-80 mg, cross-axis sensitivity +-2 %, about 1.1 deg), so that a part within its
datasheet lies within 1-2 std of it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.special import chdtrc

from imucal_cli.calibrate.accel.checks import MISFIT_FLOOR_MG, MISFIT_SIGMAS
from imucal_cli.calibrate.accel.gravity import GAUGE_9
from imucal_cli.calibrate.accel.section import (
    COVARIANCE_OF,
    PoseFit,
    common_members,
    parameter_rows,
)
from imucal_cli.calibrate.common import Nominal, StaticPoses, accel_units, rms
from imucal_cli.errors import DesignError
from imucal_cli.estimators.accel import partial as map_fit
from imucal_cli.formats.config import Config
from imucal_cli.model.accel import AccelCalibration
from imucal_cli.model.codec import build
from imucal_cli.model.parts import Combination, Covariance, Partial
from imucal_cli.model.section import SensorCalibration

#: The nominal prior's std: relative gain, bias in g, angles between the axes in degrees.
GAIN_STD = 0.03
BIAS_STD_G = 0.06
ANGLE_STD_DEG = 2.0

RULE = (f"measured: posterior std below {map_fit.MEASURED_RATIO:g} of the prior std (the "
        "data carry 3 times the prior's information or more); assumed: the prior's value, "
        "within its std")  # fmt: skip

#: A fit whose data misfit has this small a probability under the noise is refused a save.
MISFIT_P = 1e-3

#: Candidate poses for the suggestion: the faces and the 45-degree edges (calibrated frame).
_AXES = {"+X": (1, 0, 0), "-X": (-1, 0, 0), "+Y": (0, 1, 0), "-Y": (0, -1, 0),
         "+Z": (0, 0, 1), "-Z": (0, 0, -1)}  # fmt: skip


def _candidates() -> dict[str, np.ndarray]:
    out = {f"{k} up": np.array(v, float) for k, v in _AXES.items()}
    names = list(_AXES)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            u = np.add(_AXES[a], _AXES[b])
            if np.linalg.norm(u) > 1.0:
                out[f"the {a}{b} edge up (45 deg between {a} and {b} up)"] = u / np.sqrt(2)
    return out


def nominal_gain(nominal: Nominal, a_mean: np.ndarray, g: float
                 ) -> tuple[float, np.ndarray, str] | None:  # fmt: skip
    """The nominal sensitivity (raw units per m/s^2), offset (raw) and their basis in words:
    the config's or the units' (``nominal.sensitivity``); for counts without one, the power of
    two counts per g nearest the poses' magnitude (the datasheet gains of consumer parts:
    16384, 8192, 4096, 2048 LSB/g of the MPU-6050, ICM-20948, BMI160 and LSM6 families at
    +-2..16 g, 256 of the ADXL345), when it is within 10 % of it, about the nominal offset or
    else zero (a signed ADC: the offset a range read from few poses guesses at mid-scale
    can be wrong); else None."""
    bias = np.asarray(nominal.bias, float)[:3]
    if nominal.sensitivity is not None:
        return float(nominal.sensitivity), bias, nominal.basis
    for offset in (bias, np.zeros(3)):
        seen = float(np.median(np.linalg.norm(a_mean - offset, axis=1))) if len(a_mean) else 0.0
        if not np.isfinite(seen) or seen <= 0:
            continue
        lsb = 2.0 ** round(np.log2(seen))  # counts per g
        if abs(lsb / seen - 1) <= 0.1:
            return lsb / g, offset, (
                f"{lsb:.0f} counts per g, the power of two nearest the poses' magnitude (a "
                f"consumer part's datasheet gain); offset {', '.join(f'{b:.6g}' for b in offset)}"
                " counts")  # fmt: skip
    return None


def nominal_prior(nominal: Nominal, a_mean: np.ndarray, g: float) -> map_fit.Prior:
    """The documented nominal prior (module notes); a :class:`DesignError` when no nominal
    sensitivity is known (nothing to hold the gains at)."""
    found = nominal_gain(nominal, a_mean, g)
    if found is None:
        raise DesignError("the nominal sensitivity is unknown (raw units and full scale not "
                          "stated), so the gains the poses do not determine have no value to "
                          "be held at: set [accel] nominal_sensitivity, or pass an earlier "
                          "calibration (--prior CAL.json)")  # fmt: skip
    s, offset, basis = found
    mean = np.r_[offset, [s] * 3, [0.0] * 3]
    std = np.r_[[BIAS_STD_G * g * s] * 3, [GAIN_STD * s] * 3, [ANGLE_STD_DEG] * 3]
    return map_fit.Prior(mean, std, f"nominal ({basis}): gains +-{GAIN_STD:.0%}, bias "
                         f"+-{BIAS_STD_G * 1000:.0f} mg, angles between the axes 90 +-"
                         f"{ANGLE_STD_DEG:g} deg (1 std, consumer datasheet tolerances)")


def calibration_prior(sec: SensorCalibration, path: str) -> map_fit.Prior:
    """The prior of an earlier accelerometer calibration of the unit: its bias,
    sensitivities and angles between the axes, with their std (its ``parameters``' ``b_*``
    std, ``sensitivity_std``, ``misalignment_std_deg``)."""
    std_of = {p.name: p.std for p in sec.parameters or []}
    keys = ("xy", "xz", "yz")
    try:
        mean = np.r_[sec.bias[:3], sec.sensitivity[:3],
                     [sec.misalignment_deg[k] for k in keys]]  # fmt: skip
        std = np.r_[[std_of[f"b_{c}"] for c in "xyz"], sec.sensitivity_std[:3],
                    [sec.misalignment_std_deg[k] for k in keys]]  # fmt: skip
    except (KeyError, TypeError, IndexError):
        raise DesignError(f"{path}: its accelerometer section does not state the bias, "
                          "sensitivities and angles between the axes with their std, which a "
                          "prior needs") from None  # fmt: skip
    mean, std = np.asarray(mean, float), np.asarray(std, float)
    if not (np.isfinite(mean).all() and np.isfinite(std).all() and (std > 0).all()):
        raise DesignError(f"{path}: its accelerometer std are not all positive and finite")
    return map_fit.Prior(mean, std, f"an earlier calibration, {path} (its values and std)")


def partial_section(poses: StaticPoses, session, cfg: Config, g: float, nominal: Nominal,
                    prior: map_fit.Prior) -> AccelCalibration:  # fmt: skip
    """The accel section of the fit with ``prior`` (module notes)."""
    res, first, scale = _fit(poses, g, prior, cfg.accel.gravity.max_iterations)
    units_in, units_note = accel_units(session, g)
    h = (poses.a_mean - res.bias) @ res.matrix.T
    summary = (res.params[3:], res.std[3:])
    members = common_members(units_in=units_in, g=g, summary=summary, poses=poses,
                             fit=PoseFit(res.residuals, h / np.linalg.norm(h, axis=1,
                                                                           keepdims=True)),
                             nominal=nominal,
                             min_separation_deg=cfg.accel.min_separation_deg)  # fmt: skip
    members["rms_loo"] = None
    warnings, blocking = _misfit(first, scale, rms(res.residuals), g)
    res, conflict = _prior_conflict(res, len(poses.a_mean))
    warnings += conflict
    units = [units_in] * 3 + [f"{units_in} per m/s^2"] * 3 + ["deg"] * 3
    rows = parameter_rows(list(map_fit.NAMES), res.params, res.std, units)
    for row, m, s0 in zip(rows, res.measured, prior.std, strict=True):
        row.status = "measured" if m else "assumed"
        row.prior_std = float(s0)
    part = _partial(res, g)
    dof = _dof(res, len(poses.a_mean))
    expected = float(np.sqrt(np.mean(res.sigmas**2) / scale * max(dof, 0.0) / len(res.sigmas)))
    notes = [_summary(part.measured, part.assumed, prior.source, part.capture),
             *(members.pop("notes", None) or [])]  # fmt: skip
    return build(
        AccelCalibration, solver="partial", units="m/s^2", bias=res.bias, matrix=res.matrix,
        residual_rms=rms(res.residuals), **members,
        variant="9-parameter with a prior (maximum a posteriori)", gauge=GAUGE_9,
        parameters=rows, covariance=_model_covariance(res),
        init="prior mean", weighting="noise", iterations=res.iterations,
        function_evaluations=res.nfev, converged=res.converged, message=res.message,
        chi2=first[0], dof=int(round(first[1])), noise_scale=scale, notes=notes,
        warnings=warnings + ([units_note] if units_note else []), blocking=blocking,
        rms_expected=expected,
        rms_after_below_noise=bool(dof < 0.5 or rms(res.residuals) < 0.5 * expected),
        partial=part,
    )  # fmt: skip


def _fit(poses: StaticPoses, g: float, prior: map_fit.Prior, max_iterations: int
         ) -> tuple[map_fit.PartialResult, tuple[float, float], float]:  # fmt: skip
    """The fit, and again with the noise scaled when the magnitudes scatter beyond the still
    holds' own noise (vibration, a slow tilt: the data weighed by the scatter they show
    against the prior, the gravity fit's ``noise_scale``, so that an overconfident noise does
    not overrule the prior). Returns it, the first fit's ``(chi2, dof)`` and the scale."""
    res = map_fit.fit_partial(poses.a_mean, poses.cov_mean, g, prior, max_iterations)
    scale = 1.0
    first = (res.chi2, _dof(res, len(poses.a_mean)))
    if first[1] >= 1.0 and first[0] > first[1]:
        scale = first[0] / first[1]
        res = map_fit.fit_partial(poses.a_mean, poses.cov_mean * scale, g, prior,
                                  max_iterations)  # fmt: skip
    if not res.converged:
        raise DesignError(f"the fit with a prior did not converge ({res.message})")
    return res, first, scale


def _partial(res: map_fit.PartialResult, g: float) -> Partial:
    """The section's ``partial`` member: the rule, the prior, which are measured and which
    assumed, the determined combinations and the poses that would measure the rest."""
    measured = [n for n, m in zip(map_fit.NAMES, res.measured, strict=True) if m]
    assumed = [n for n, m in zip(map_fit.NAMES, res.measured, strict=True) if not m]
    sigma = float(np.median(res.sigmas))
    picks = map_fit.suggest(res, g, _candidates(), sigma) if assumed else []
    combos = [_combination(c, value, cstd, res.prior.std)
              for c, value, cstd in res.combinations]  # fmt: skip
    return Partial(rule=RULE, prior=res.prior.source, measured=measured, assumed=assumed,
                   combinations=combos, capture=_capture_words(picks, assumed))


def _model_covariance(res: map_fit.PartialResult) -> Covariance:
    """The posterior covariance of ``(bias, matrix row-major)`` (the ``covariance`` member
    every accel section has, :data:`.section.COVARIANCE_OF`): ``J C J^T``, ``J`` the
    Jacobian of ``(bias, matrix_of(p))`` by the parameters (central differences)."""
    p = res.params

    def f(x):
        return np.r_[x[:3], map_fit.matrix_of(x).ravel()]

    step = 1e-6 * np.maximum(np.abs(p), 1.0)
    J = np.empty((12, 9))
    for i in range(9):
        e = np.zeros(9)
        e[i] = step[i]
        J[:, i] = (f(p + e) - f(p - e)) / (2 * step[i])
    C = J @ res.cov @ J.T
    return Covariance(COVARIANCE_OF, (C + C.T) / 2)


def _combination(c: np.ndarray, value: float, std: float, prior_std: np.ndarray
                 ) -> Combination:  # fmt: skip
    """A determined combination, its negligible terms (under 2 % of the leading one, in
    prior units) left out of the words, not of the value."""
    weight = np.abs(c * prior_std)
    keep = weight > 0.02 * weight.max()
    return Combination({n: float(f"{v:.6g}") for n, v, k in zip(map_fit.NAMES, c, keep,
                                                                 strict=True) if k},
                       float(value), float(std))  # fmt: skip


def _capture_words(picks: list[str], assumed: list[str]) -> str:
    """What capture would measure the assumed parameters (the greedy picks), in words."""
    if not assumed:
        return ""
    if not picks:
        return "no single pose adds enough: capture the six faces (plan six)"
    return (f"hold the unit still with {', then '.join(picks)} (the poses that measure "
            f"{', '.join(assumed)} most, one after the other), or capture the six faces and "
            "12 edges (plan qureshi18); or hold them at an earlier calibration of this unit "
            "instead of nominal values: --prior CAL.json")  # fmt: skip


def _summary(measured: list[str], assumed: list[str], source: str, capture: str) -> str:
    if not assumed:  # each parameter narrowed, yet some combinations rest on the prior
        return (f"these poses determine only part of the model: every parameter is measured "
                f"(its std under {map_fit.MEASURED_RATIO:g} of the prior's), but too few "
                f"directions fix every combination of them: the rest lean on the prior "
                f"({source}), within its std, which theirs include")  # fmt: skip
    text = (f"these poses determine only part of the model: measured "
            f"{', '.join(measured) or 'none'}"
            f"; assumed (held at the prior, with its std) {', '.join(assumed) or 'none'}; prior: "
            f"{source}")  # fmt: skip
    return f"{text}; to measure the rest: {capture}" if capture else text


def _dof(res: map_fit.PartialResult, n: int) -> float:
    """The magnitudes' degrees of freedom the prior leaves: ``n`` minus the parameters the
    data determine (the trace of the data's share of the posterior, ``sum lambda / (1 +
    lambda)``)."""
    s0 = res.prior.std
    return float(n - np.trace(np.eye(9) - res.cov / np.outer(s0, s0)))


def _misfit(first: tuple[float, float], scale: float, rms_after: float, g: float
            ) -> tuple[list[str], list[str]]:  # fmt: skip
    """The data's misfit against the still holds' noise (``first``: chi-square and the
    degrees of freedom the prior leaves, before any ``scale``): said when improbable (p below
    :data:`MISFIT_P`; the std are then scaled by it), and blocking a save as the other accel
    fits do, beyond :data:`.checks.MISFIT_SIGMAS` times the noise and
    :data:`.checks.MISFIT_FLOOR_MG`."""
    chi2, dof = first
    if dof < 0.5:
        return [], []
    p = float(chdtrc(dof, chi2))  # chi-square survival function
    if p >= MISFIT_P:
        return [], []
    excess = float(np.sqrt(chi2 / dof))
    text = (f"the poses' magnitudes scatter {excess:.1f} times more than the still holds' noise "
            f"(chi^2 {chi2:.3g} on {dof:.1f} degrees of freedom, p = {p:.2g}): vibration or a "
            f"slow tilt in a hold, or the prior is far from this part; the std are scaled by "
            f"it (noise_scale {scale:.3g})")  # fmt: skip
    block = excess > MISFIT_SIGMAS and 1000 * rms_after / g > MISFIT_FLOOR_MG
    return [text], [text] if block else []


def _prior_conflict(res: map_fit.PartialResult, n: int
                    ) -> tuple[map_fit.PartialResult, list[str]]:  # fmt: skip
    """The poses against the prior: the whole weighted sum of squares at the solution (the
    magnitudes' part, already on the noise scale ``_fit`` chose, and the prior's, ``sum ((p -
    p0) / sigma0)^2``) is chi-square on ``n`` degrees of freedom (``n`` magnitudes and 9
    prior rows for 9 parameters) when the part lies within its prior. A design that cannot
    fix the model fits its magnitudes whatever the prior, so a part outside it (a bias of
    several prior std) shows only in the prior's part: the parameters moved far from it,
    the assumed ones with the rest. Improbable (p below :data:`MISFIT_P`): said, and every
    std scaled by ``sqrt(chi^2 / n)`` (the data's and the prior's weights alike, which
    leaves the estimate as it is). Returns the result (scaled or not) and the warnings."""
    z = (res.params - res.prior.mean) / res.prior.std
    total = res.chi2 + float(z @ z)
    p = float(chdtrc(n, total)) if n > 0 else 1.0
    if p >= MISFIT_P:
        return res, []
    k = total / n
    far = np.argsort(-np.abs(z))[:3]
    moved = ", ".join(f"{map_fit.NAMES[i]} {z[i]:+.1f}" for i in far)
    text = (f"the poses and the prior disagree: the fit sits {moved} prior std from it "
            f"(chi^2 {total:.3g} on {n} degrees of freedom with the prior, p = {p:.2g}): this "
            "part lies outside the prior, so the assumed parameters are not the prior's "
            f"values; the std are scaled by sqrt({k:.3g}); capture the poses "
            "that measure them, or give an earlier calibration of this unit (--prior "
            "CAL.json)")  # fmt: skip
    combos = [(c, value, std * np.sqrt(k)) for c, value, std in res.combinations]
    return replace(res, cov=res.cov * k, combinations=combos), [text]
