"""The gyroscope of a log whose turns cannot determine its model (issue 27.3): a vehicle's or
robot's log (a few still periods, free turns, no labels, no calibrated accelerometer), or
still periods only.  Every still period measures the gyro's bias (the mean raw rate while
still: the model ``omega = M (raw - b)`` at rest); the matrix ``M`` (gains, misalignment) is
held at the prior (nominal values, or an earlier calibration's gyro with ``--prior``) with the
prior's std, and the section says which are which (``"partial"``, each parameter's
``status``, as the accelerometer's partial fit does: :mod:`..accel.partial`) and which capture
would determine the rest.  Where the turns would determine part of the matrix, it is still
held at the prior (kept simple, docs/solvers.md "Partial designs").

The nominal prior (docs/solvers.md): ``M = I / s`` with ``s`` the nominal sensitivity (raw
units per rad/s: ``[gyro] nominal_sensitivity``, or 1 for rad/s, 180/pi for deg/s), each gain
+- 3 % and each off-diagonal term +- 2 deg of ``1 / s`` (1 std), as the accelerometer's
nominal prior; the bias 0 +- 20 deg/s (the widest consumer zero-rate offset, MPU-6050's
+-20 deg/s), which the still periods overrule by orders of magnitude.  Raw counts without a
nominal sensitivity have no value to hold the matrix at (the range, 131 .. 16.4 LSB per
deg/s, cannot be read from still data): the gyro is then left out, its note giving the bias
measured and what would save it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import chdtrc

from imucal_cli.calibrate.common import session_name
from imucal_cli.calibrate.gyro.full import gain_std
from imucal_cli.calibrate.gyro.turns import AXES
from imucal_cli.design import holds
from imucal_cli.errors import DesignError
from imucal_cli.estimators.accel.partial import MEASURED_RATIO
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.model.calibration import MODEL_EQUATION, SensorCalibration
from imucal_cli.model.codec import build
from imucal_cli.model.gyro import GyroCalibration
from imucal_cli.model.parts import Parameter, Partial
from imucal_cli.numerics.quantisation import hold_rounding, rounding_covariance
from imucal_cli.numerics.segmented import moments_in_chunks
from imucal_cli.planning.information import axes_std

#: The nominal prior's std: relative gain, off-diagonal terms (deg), bias (deg/s).
GAIN_STD = 0.03
ANGLE_STD_DEG = 2.0
BIAS_STD_DPS = 20.0

#: The still data's batch means scattering beyond their noise with this small a probability:
#: the bias drifted (temperature, bias instability) or the noise is correlated; its std is
#: scaled by it.
SCATTER_P = 1e-3

#: Batches of a still period (at most, each at least ``BATCH_MIN`` samples) whose means
#: test the scatter.
BATCHES = 8
BATCH_MIN = 50

NAMES = tuple([f"b_{a}" for a in AXES] + [f"m_{r}{c}" for r in AXES for c in AXES])

RULE = (f"measured: posterior std below {MEASURED_RATIO:g} of the prior std (the data carry "
        "3 times the prior's information or more); assumed: the prior's value, within its "
        "std")  # fmt: skip

CAPTURE = ("turns about each axis: 3 or more turns of a known angle about each of x, y and z "
           "(a full turn flat on a table on three faces: plan gyro-axes or ferraris), or 10 or "
           "more turns between still periods with the accelerometer calibrated (plan free:12 "
           "or qureshi18, or these turns with --accel CAL.json); or hold the matrix at an "
           "earlier calibration of this unit instead of nominal values: "
           "--prior CAL.json")  # fmt: skip

_UNITS = {"rad/s": 1.0, "deg/s": 180.0 / np.pi}


@dataclass(frozen=True)
class GyroPrior:
    """The prior of the gyro's matrix.

    Attributes
    ----------
    matrix : ndarray, shape (3, 3)
        Its mean, rad/s per raw unit.
    std : ndarray, shape (3, 3)
        Each term's std, rad/s per raw unit.
    source : str
        Where it comes from, in words.
    frame : str
        The frame its matrix calibrates into.
    """

    matrix: np.ndarray
    std: np.ndarray
    source: str
    frame: str = "the gyro's own axes (nominal: the chip's; its angles to them assumed)"


def nominal_sensitivity(session: Session, cfg: Config) -> float | None:
    """Raw units per rad/s: the config's, else the units' (rad/s, deg/s), else None."""
    return cfg.gyro.nominal_sensitivity or _UNITS.get(session.gyro_units or "")


def nominal_prior(s: float) -> GyroPrior:
    """The documented nominal prior (module notes) at sensitivity ``s`` (raw per rad/s)."""
    std = np.full((3, 3), np.radians(ANGLE_STD_DEG) / s)
    np.fill_diagonal(std, GAIN_STD / s)
    return GyroPrior(np.eye(3) / s, std, f"nominal ({s:.6g} raw units per rad/s): gains +-"
                     f"{GAIN_STD:.0%}, each axis within {ANGLE_STD_DEG:g} deg of its own "
                     "(1 std, consumer datasheet tolerances)")  # fmt: skip


def calibration_prior(sec: SensorCalibration, path: str) -> GyroPrior:
    """The matrix of an earlier gyro calibration of the unit, with its std (its parameter
    rows ``m_xx`` .. ``m_zz``)."""
    std_of = {p.name: p.std for p in sec.parameters or []}
    try:
        std = np.array([std_of[n] for n in NAMES[3:]], float).reshape(3, 3)
        matrix = np.asarray(sec.matrix, float).reshape(3, 3)
    except (KeyError, TypeError, ValueError):
        raise DesignError(f"{path}: its gyro section does not state the matrix terms m_xx .. "
                          "m_zz with their std, which a prior needs") from None  # fmt: skip
    if not (np.isfinite(matrix).all() and np.isfinite(std).all() and (std > 0).all()):
        raise DesignError(f"{path}: its gyro matrix std are not all positive and finite")
    return GyroPrior(matrix, std, f"an earlier calibration, {path} (its gyro matrix and std)",
                     sec.frame or GyroPrior.frame)  # fmt: skip


def _batches(statics) -> tuple[np.ndarray, np.ndarray]:
    """Each still period cut into up to :data:`BATCHES` batches of at least
    :data:`BATCH_MIN` samples (a shorter period: one): their starts and stops."""
    start, stop = [], []
    for seg in statics:
        n = seg.stop - seg.start
        edges = np.linspace(seg.start, seg.stop, min(max(n // BATCH_MIN, 1), BATCHES) + 1)
        edges = edges.round().astype(np.int64)
        start.extend(edges[:-1])
        stop.extend(edges[1:])
    return np.array(start, np.int64), np.array(stop, np.int64)


def stills_bias(session: Session, cfg: Config) -> tuple[np.ndarray, np.ndarray, float, str | None]:
    """The bias (raw units, 3) from every still period: the mean of their samples, std the
    per-sample noise (per channel, pooled within batches of the periods) over the root of
    their number; per channel scaled by the scatter of the batches' means when it exceeds
    their noise (:data:`SCATTER_P`; the batch-means estimate of a mean's variance: a bias that
    drifts within or between the periods, correlated noise); with the variance of the rounding
    every period shares where a quantised gyro's noise does not dither it
    (:func:`imucal_cli.numerics.quantisation.rounding_variance`). Returns it, its std, the
    per-sample noise (RMS over the channels) and the warning of a scaled std (or None)."""
    statics = session.static_segments()
    if not statics:
        raise DesignError(f"{session_name(session)}: no still period to measure the gyro's bias")
    start, stop = _batches(statics)
    means, ss = moments_in_chunks(session.gyro, start, stop)
    n = (stop - start).astype(float)
    noise = np.sqrt(ss.sum(axis=0) / max(float(np.sum(n - 1)), 1.0))
    noise = np.maximum(noise, 1e-12)
    bias = n @ means / n.sum()
    std = noise / np.sqrt(n.sum())
    chi2 = np.sum((means - bias) ** 2 * n[:, None], axis=0) / noise**2  # per channel
    dof = len(n) - 1
    warning = None
    if dof > 0:
        scatter = chdtrc(dof, chi2) < SCATTER_P
        if scatter.any():
            scale = np.where(scatter, np.sqrt(chi2 / dof), 1.0)
            std = std * scale
            warning = (f"the still data's means over {len(n)} stretches scatter "
                       f"{', '.join(f'{x:.1f}' for x in scale)} times (x, y, z) more than "
                       f"their noise (chi^2 on {dof} degrees of freedom each, p below "
                       f"{SCATTER_P:g}): the bias drifted (warm-up, bias instability) or the "
                       "noise is correlated; the bias std is scaled by it")  # fmt: skip
    # a quantised gyro too quiet to dither its rounding: every period errs alike
    q = holds.record_quantum(session.gyro)
    blocks = [session.gyro[s.start : s.stop] for s in statics]
    w = n / n.sum()
    sigma, v = hold_rounding(blocks, q, float(np.sqrt(np.mean(noise**2))))  # one for the 3
    if v > 0:  # the batches' means' rounding, alike where they sit alike in a count
        for c in range(len(std)):
            std[c] = np.sqrt(std[c] ** 2 + w @ rounding_covariance(means[:, c], sigma, q) @ w)
    return bias, std, float(np.sqrt(np.mean(noise**2))), warning


def partial_gyro_section(session: Session, cfg: Config, prior: GyroPrior, why: str,
                         extra: str | None = None) -> GyroCalibration:  # fmt: skip
    """The gyro section: the bias measured by the still periods (MAP with the nominal bias
    prior), the matrix held at ``prior`` (module notes). ``why``: why the turns do not
    determine the model; ``extra``: what the turns are for, added to the capture words."""
    units = session.gyro_units or "unknown"
    s_nom = 1.0 / float(np.mean(np.abs(np.diag(prior.matrix))))
    b_data, b_std, noise, warning = stills_bias(session, cfg)
    b0_std = np.radians(BIAS_STD_DPS) * s_nom
    w_data, w_prior = b_std**-2, b0_std**-2
    bias = (b_data * w_data) / (w_data + w_prior)  # the prior's mean is 0
    bias_std = (w_data + w_prior) ** -0.5
    M = prior.matrix
    values = np.r_[bias, M.ravel()]
    post_std = np.r_[bias_std, prior.std.ravel()]
    prior_std = np.r_[[b0_std] * 3, prior.std.ravel()]
    measured = post_std < MEASURED_RATIO * prior_std
    unit = [units] * 3 + [f"rad/s per {units}"] * 9
    rows = [Parameter(n, float(v), float(sd), u, status="measured" if m else "assumed",
                      prior_std=float(p0))
            for n, v, sd, u, m, p0 in zip(NAMES, values, post_std, unit, measured, prior_std,
                                          strict=True)]  # fmt: skip
    cov_M = np.diag(prior.std.ravel() ** 2)
    gains, g_std, a_std = axes_std(M, cov_M)
    S = np.linalg.inv(M)
    s_axes = S / np.linalg.norm(S, axis=1, keepdims=True)
    pairs = ((0, 1), (0, 2), (1, 2))
    part = Partial(rule=RULE, prior=prior.source,
                   measured=[n for n, m in zip(NAMES, measured, strict=True) if m],
                   assumed=[n for n, m in zip(NAMES, measured, strict=True) if not m],
                   combinations=[],
                   capture=CAPTURE + (f". {extra}" if extra else ""))  # fmt: skip
    notes = [summary(part.measured, part.assumed, prior.source, part.capture),
             f"why not the whole model: {why}"]  # fmt: skip
    return build(
        GyroCalibration, solver="gyro-partial", units="rad/s", bias=bias, matrix=M,
        residual_rms=0.0, model=MODEL_EQUATION, units_in=units,
        variant="bias from the still periods, matrix held at the prior",
        frame=prior.frame,
        approach="partial", parameters=rows,
        sensitivity=[float(x) for x in gains], sensitivity_unit=f"{units} per rad/s",
        sensitivity_std=[float(x) for x in gain_std(M, cov_M)],
        misalignment_deg={f"{AXES[i]}{AXES[j]}": float(
            np.degrees(np.arccos(np.clip(s_axes[i] @ s_axes[j], -1, 1))) - 90)
            for i, j in pairs},
        misalignment_std_deg=dict(zip(("xy", "xz", "yz"), map(float, a_std), strict=True)),
        gyro_noise_raw=float(noise), noise_basis="pooled over the still periods",
        notes=notes, warnings=[warning] if warning else [], blocking=[], partial=part,
    )  # fmt: skip


def summary(measured: list[str], assumed: list[str], source: str, capture: str) -> str:
    """The section's first note, in the accelerometer's partial words."""
    text = (f"these still periods determine only part of the model: measured "
            f"{', '.join(measured) or 'none'}; assumed (held at the prior, with its std) "
            f"{', '.join(assumed) or 'none'}; prior: {source}")  # fmt: skip
    return f"{text}; to measure the rest: {capture}" if capture else text


def bias_words(session: Session, cfg: Config) -> str:
    """The bias the still periods measure, in words (for the note of a gyro left out for
    want of a nominal sensitivity); empty when there is none."""
    try:
        b, sd, _, _ = stills_bias(session, cfg)
    except DesignError:
        return ""
    units = session.gyro_units or "raw units"
    return (f"its still periods measure the bias ({', '.join(f'{x:.4g}' for x in b)} +- "
            f"{sd[0]:.2g} {units}), but the matrix has no nominal value to be held at (the "
            "range of raw counts cannot be read from still data): set [gyro] "
            "nominal_sensitivity (raw units per rad/s: the datasheet's LSB per deg/s times "
            "57.3) or pass an earlier calibration with a gyro, --prior CAL.json, and the gyro "
            "is saved with its bias measured and its matrix assumed")  # fmt: skip
