"""Grading a calibration against the simulated part's truth (``bench live``, issue 24.1).

Each fitted section is turned into the same four arrays, whatever its solver: the error of
every parameter against the truth (in the solver's own parameters and frame), the reported
std, the reported 95 % half-width (the section's ``ci95`` when it states one, else 1.96 std),
and the Cramér-Rao bound of the design the session actually holds (variance, per parameter),
or None where no bench computes one.  The bounds are those of the other benches:

- accelerometer, gravity magnitude (9 parameters, upper-triangular ``M``): :func:`gravity_crb`
  as in ``bench/gravity.py``;
- accelerometer, labelled poses (12): :func:`labelled_crb` as in ``bench/labelled.py``, the
  labels a prior of the simulated placement error;
- accelerometer, partial (9 with a prior: a design of too few directions, e.g. ``gyro-axes``):
  the report's parameters (bias, the sensitivity axes' lengths, their angles minus 90 deg)
  against the Bayesian bound ``(F + P^-1)^-1`` at the truth (:func:`_partial_bound`: the
  magnitudes' information and the section's own prior);
- gyro, full model from turns between still periods (12): :func:`full_bound` as in
  ``bench/gyro.py`` (the accelerometer calibration's covariance propagated through the turns);
- gyro, turns of known angle (12): the information of the solver's own stacked problem at
  the truth (:class:`imucal_cli.estimators.gyro.known._Stacked`, with the still periods and the
  turns gravity measures), as ``full_bound`` does for the full model; both with the
  accelerometer calibration the gyro solver used (:func:`gyro_accel`: none beside a partial
  one, the gyro then in the labels' frame);
- magnetometer (13, aligned): :func:`magnetometer_crb` as in ``bench/mag.py``.

A pose's true direction is what the truth makes of the pose's mean reading (``T (a - b)``,
normalised): a captured session's holds are not the simulator's segments, and the direction
found so is within the noise of the mean (1e-4 rad), which changes the bound by far less
than its own sampling error.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from types import SimpleNamespace

import numpy as np

from imucal_cli.calibrate.common import static_poses
from imucal_cli.calibrate.gyro import known as pk
from imucal_cli.calibrate.gyro.full import (
    accel_directions_and_frame,
    rotations_and_stills,
    solver_stills,
)
from imucal_cli.calibrate.gyro.rotations import full_bound, with_segments
from imucal_cli.calibrate.mag import mag_readings
from imucal_cli.calibrate.thermal import BLOCK_S, still_blocks
from imucal_cli.estimators.accel import partial as map_fit
from imucal_cli.estimators.accel.crb import gravity_crb, labelled_crb
from imucal_cli.estimators.accel.gravity import model_to_params
from imucal_cli.estimators.accel.labelled_model import jacobian, public_params
from imucal_cli.estimators.gyro.known import _Stacked
from imucal_cli.estimators.mag.crb import magnetometer_crb
from imucal_cli.estimators.thermal.temperature import polynomial_bound
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.model.calibration import Calibration, SensorCalibration

G0 = 9.80665


@dataclass
class Graded:
    """One calibrated section against the truth.

    Attributes
    ----------
    section : str
        ``"accel"``, ``"gyro"`` or ``"mag"``.
    solver : str
        The section's solver (and variant).
    names : list of str
        Parameter names, as the calibration JSON lists them.
    err : ndarray (p,)
        Estimate minus truth, the parameters' units.
    std : ndarray (p,)
        Reported standard deviation.
    half : ndarray (p,)
        Reported 95 % interval half-width.
    crb : ndarray (p,) or None
        Cramér-Rao bound (variance) at the session's design; None: no bound for this solver.
    note : str
        Why there is no bound, or how it was made.
    """

    section: str
    solver: str
    names: list[str]
    err: np.ndarray
    std: np.ndarray
    half: np.ndarray
    crb: np.ndarray | None
    note: str = ""

    @property
    def hits(self) -> np.ndarray:
        """Whether each reported 95 % interval holds the truth."""
        return np.abs(self.err) <= self.half

    @property
    def z2(self) -> np.ndarray | None:
        """``err^2 / crb`` per parameter (None without a bound)."""
        return None if self.crb is None else self.err**2 / self.crb


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _params(sec: SensorCalibration) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
    """Names, values, std and 95 % half-widths of a section's ``parameters``."""
    rows = sec.to_dict().get("parameters") or []
    names = [r["name"] for r in rows]
    value = np.array([float(r["value"]) for r in rows])
    std = np.array([float(r.get("std") or np.nan) for r in rows])
    half = np.array([float(r["ci95"]) if r.get("ci95") is not None else 1.96 * s
                     for r, s in zip(rows, std, strict=True)])  # fmt: skip
    return names, value, std, half


def _pose_design(session: Session, truth: Calibration):
    """The static poses the accelerometer solvers use (:func:`static_poses`), each pose's true
    up direction in the fixture frame, and the covariance of each pose's mean from the true
    noise (raw units^2)."""
    poses = static_poses(session)
    T, b = truth.accel.matrix, truth.accel.bias
    u = _unit((poses.a_mean - b) @ T.T)
    S = np.linalg.inv(T)
    sigma = float(truth.accel.to_dict()["noise"])
    quant = np.eye(3) / 12.0 if session.accel_units == "counts" else np.zeros((3, 3))
    cov = np.array([(sigma**2 * S @ S.T + quant) / n for n in poses.samples])
    return poses, u, cov


def _gauge(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Upper-triangular ``M`` (positive diagonal) and rotation ``Q`` with ``T = Q M``."""
    Q, R = np.linalg.qr(T)
    D = np.diag(np.sign(np.diag(R)))
    return D @ R, Q @ D


def partial_truth(T: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The partial fit's parameters (:data:`map_fit.NAMES`) of a part ``T``, ``b``: the bias,
    the lengths of the sensitivity axes (the rows of ``S = T^-1``) and the angles between them
    minus 90 deg (``G = S S^T``, ``G_ij = s_i s_j cos(90 deg + a_ij)``)."""
    S = np.linalg.inv(T)
    s = np.linalg.norm(S, axis=1)
    a = [np.degrees(np.arccos(S[i] @ S[j] / (s[i] * s[j]))) - 90.0 for i, j in map_fit.PAIRS]
    return np.r_[b, s, a]


def _partial_bound(p: np.ndarray, a_mean: np.ndarray, cov: np.ndarray, g: float,
                   prior_std: np.ndarray) -> np.ndarray:  # fmt: skip
    """The Bayesian Cramér-Rao bound (van Trees) of the partial fit at ``p``: the inverse of
    the magnitudes' Fisher information (``|h_k| - g`` over its noise, eq. 4, differentiated
    centrally) plus the prior's ``diag(prior_std^-2)``, (9, 9)."""
    sig = map_fit._sigmas(p, a_mean, cov)
    J = np.empty((len(a_mean), 9))
    for i in range(9):
        step = np.zeros(9)
        step[i] = 1e-6 * prior_std[i]
        J[:, i] = (map_fit._magnitudes(p + step, a_mean)
                   - map_fit._magnitudes(p - step, a_mean)) / (2 * step[i] * sig)  # fmt: skip
    return np.linalg.inv(J.T @ J + np.diag(prior_std**-2.0))


def grade_accel(session: Session, cal: Calibration, truth: Calibration) -> Graded:
    """The accelerometer section: gravity-magnitude (9), partial (9 with a prior) or
    labelled-pose (12) parameters."""
    sec = cal.accel
    names, value, std, half = _params(sec)
    poses, u, cov = _pose_design(session, truth)
    T, b = truth.accel.matrix, truth.accel.bias
    if tuple(names) == map_fit.NAMES:  # partial: the report's parameters, the section's prior
        x_true = partial_truth(T, b)
        rows = sec.to_dict()["parameters"]
        prior_std = np.array([float(r["prior_std"]) for r in rows])
        crb = np.diag(_partial_bound(x_true, poses.a_mean, cov, G0, prior_std))
        return Graded("accel", "partial, 9 with a prior", names, value - x_true, std, half, crb,
                      "Bayesian bound: the magnitudes' information and the section's "
                      "prior")  # fmt: skip
    if len(names) == 9:  # gravity magnitude: the solver's gauge, M upper triangular
        M, Q = _gauge(T)
        x_true = model_to_params(b, M)
        crb = np.diag(gravity_crb(M, b, u @ Q, G0, cov))
        solver = "gravity, 9"
    elif len(names) == 12 and names[-1] == "r_z":  # labelled poses
        x_true = public_params(b, np.linalg.inv(T))
        # the placement error of the labels; none stated (an exactly square iron): exact
        # labels, a tiny prior keeping the bound finite
        jitter = float(truth.accel.to_dict().get("jitter_deg") or 0.01)
        placement = np.where([up is not None for up in poses.up], jitter, np.inf)
        crb = np.diag(labelled_crb(T, b, u, G0, cov, placement))
        solver = "labelled, 12"
    else:
        raise ValueError(f"accel parameters {names} are not graded")
    return Graded("accel", solver, names, value - x_true, std, half, crb)


def gyro_accel(cal: Calibration) -> SensorCalibration | None:
    """The accelerometer calibration the gyro solver used: None beside a partial one (the
    pipeline calibrates that gyro as without an accelerometer, in the labels' frame:
    :func:`imucal_cli.calibrate.session._gyro_beside_partial`), so that its bound is that of
    the problem the solver solved, not one with turns gravity measures that it left out."""
    return None if cal.accel is None or cal.accel.partial is not None else cal.accel


def _truth_in_accel_frame(cal: Calibration, truth: Calibration) -> np.ndarray:
    """The rotation from the truth's (fixture) frame into the frame the calibrated
    accelerometer reports in (identity without an accelerometer: the labels' frame)."""
    if cal.accel is None or truth.accel is None:
        return np.eye(3)
    U, _, Vt = np.linalg.svd(cal.accel.matrix @ np.linalg.inv(truth.accel.matrix))
    return U @ Vt


def grade_gyro(session: Session, cal: Calibration, truth: Calibration) -> Graded:
    """The gyro section: ``(b, vec M)`` of the full or known-angle model against its bound;
    other gyro solvers are graded without a bound."""
    sec = cal.gyro
    names, value, std, half = _params(sec)
    # the frame the gyro was calibrated in: the accelerometer's it used (the labels' beside
    # a partial one, :func:`gyro_accel`)
    R = _truth_in_accel_frame(cal, truth) if gyro_accel(cal) is not None else np.eye(3)
    solver = str(sec.solver)
    if names[:3] == ["b_x", "b_y", "b_z"] and names[3:12] == [f"m_{a}{c}" for a in "xyz"
                                                              for c in "xyz"]:  # fmt: skip
        x_true = np.r_[truth.gyro.bias, (R @ truth.gyro.matrix).ravel()]
        n = len(names)
        if n > 12:  # g-sensitivity fitted: the truth has none
            x_true = np.r_[x_true, np.zeros(n - 12)]
        err = value - x_true
        crb, note = _gyro_bound(session, cal, solver, x_true, truth)
        return Graded("gyro", solver, names, err, std, half, crb, note)
    if names[:3] == ["b_x", "b_y", "b_z"] and names[3:6] == ["gain_x", "gain_y", "gain_z"]:
        # the factorization's gains are the rows' norms of S = M^-1 (raw units per rad/s)
        S_true = np.linalg.inv(truth.gyro.matrix)
        x_true = np.r_[truth.gyro.bias, np.linalg.norm(S_true, axis=1)]
        return Graded("gyro", solver, names[:6], value[:6] - x_true, std[:6], half[:6], None,
                      "no bench bounds the factorization gyro")  # fmt: skip
    raise ValueError(f"gyro parameters {names} are not graded")


def accel_at_bound(session: Session, cal: Calibration,
                   truth: Calibration) -> SensorCalibration | None:  # fmt: skip
    """The accelerometer calibration the gyro solver used (:func:`gyro_accel`), its covariance
    replaced by its bound where it is a labelled-pose one (:func:`labelled_crb` at the true
    placement, carried to ``(bias, matrix row-major)``): a gyro's bound is what the design
    allows, and the labelled fit's own covariance rests on a placement it estimates from a
    few degrees of freedom (ferraris seed 0: 0.77 deg from 6 against the 1.85 placed, its
    stated std 2.4 times too small, which a bound built on them would inherit)."""
    accel = gyro_accel(cal)
    if accel is None or accel.covariance is None or truth.accel is None:
        return accel
    names, *_ = _params(accel)
    if len(names) != 12 or names[-1] != "r_z":
        return accel
    poses, u, cov = _pose_design(session, truth)
    jitter = float(truth.accel.to_dict().get("jitter_deg") or 0.01)
    placement = np.where([up is not None for up in poses.up], jitter, np.inf)
    crb = labelled_crb(truth.accel.matrix, truth.accel.bias, u, G0, cov, placement)

    def public(v):  # (bias, matrix row-major) -> the labelled solver's parameters
        return public_params(v[:3], np.linalg.inv(v[3:].reshape(3, 3)))

    v0 = np.r_[np.asarray(accel.bias, float), np.ravel(accel.matrix)]
    P = jacobian(public, v0, floor=np.r_[np.ones(3), np.full(9, np.abs(v0[3:]).max())])
    P_inv = np.linalg.inv(P)
    values = P_inv @ crb @ P_inv.T
    return replace(accel, covariance=replace(accel.covariance, values=(values + values.T) / 2))


def _gyro_bound(session: Session, cal: Calibration, solver: str, x: np.ndarray,
                truth: Calibration):  # fmt: skip
    """The bound of the full or known-angle gyro model at ``x`` (variance per parameter), the
    accelerometer at its own bound (:func:`accel_at_bound`)."""
    cfg = Config()
    accel = accel_at_bound(session, cal, truth)
    try:
        if solver in ("known", "gyro-known"):
            return np.diag(_known_bound(session, cfg, accel, x)), "known-angle model"
        return np.diag(full_bound(session, cfg, accel, x)[1]), "full model"
    except Exception as exc:  # noqa: BLE001 - the row says why it has no bound
        return None, f"no bound: {type(exc).__name__}: {exc}"


def _known_bound(session: Session, cfg: Config, accel: SensorCalibration | None,
                 x: np.ndarray) -> np.ndarray:  # fmt: skip
    """The known-angle gyro fit's bound at ``x``: the inverse information of the solver's
    stacked whitened problem (known turns, still periods, turns gravity measures weighed with
    the accelerometer calibration's part, no excess scatter) at the truth, plus the
    accelerometer calibration's covariance carried through (the pipeline's own refits,
    :func:`imucal_cli.calibrate.gyro.known._accel_part`)."""
    session, _ = with_segments(session)
    data, known, used, segs, statics, _ = pk._known_data(session, cfg, accel, "bench")
    rot, st = rotations_and_stills(data) if data.turns else (None, solver_stills(data.stills))
    accel_dirs, phi = accel_directions_and_frame(data) or (None, None)  # as the solver
    known = pk.in_accel_frame(known, phi)
    with_g = len(x) > 12
    prob = _Stacked(known, st, data.noise, rot, with_g, accel_dirs=accel_dirs)
    prob.freeze(x)
    _, J = prob.f_and_J(x)
    crb = np.linalg.inv(J.T @ J)
    if accel is None:
        return crb
    at = SimpleNamespace(b=x[:3], M=x[3:12].reshape(3, 3), tau=0.0,
                         G=x[12:21].reshape(3, 3) if with_g else None, cov=crb)  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return crb + pk._accel_part(session, cfg, accel, segs, statics, at, data, rot, known,
                                    in_weights=accel_dirs is not None and rot is not None)


def grade_mag(session: Session, cal: Calibration, truth: Calibration) -> Graded:
    """The magnetometer section (aligned model: hard iron, ``W`` in the accelerometer's
    calibrated frame, the dip) against :func:`magnetometer_crb`, as ``bench/mag.py``."""
    sec = cal.mag
    names, value, std, half = _params(sec)
    R = _truth_in_accel_frame(cal, truth)
    W_true = R @ truth.mag.matrix
    field = float(truth.mag.to_dict().get("field_uT", sec.to_dict().get("field_uT") or 48.0))
    incl = float(truth.mag.to_dict().get("inclination_deg", 60.0))
    by_name = dict(zip(names, zip(value, std, half, strict=True), strict=True))
    wanted = [f"b_{a}" for a in "xyz"] + [f"w_{r}{c}" for r in "xyz" for c in "xyz"]
    if not all(n in by_name for n in wanted):
        raise ValueError(f"mag parameters {names} are not graded (not the aligned model)")
    est = np.array([by_name[n][0] for n in wanted])
    sd = np.array([by_name[n][1] for n in wanted])
    hw = np.array([by_name[n][2] for n in wanted])
    x_true = np.r_[truth.mag.bias, W_true.ravel()]
    readings = mag_readings(session, Config().mag, cal.accel, "bench")
    S = np.linalg.inv(truth.mag.matrix)
    noise = float(truth.mag.to_dict()["noise"])
    cov = noise**2 * S @ S.T + (np.eye(3) / 12.0 if session.mag_units == "counts" else 0.0)
    data = readings.data
    dirs = _unit((data.samples - truth.mag.bias) @ W_true.T)
    pose_dirs = _unit((data.pose_mean - truth.mag.bias) @ W_true.T)
    n = readings.pose_samples
    # each pose's up: what the truth makes of its mean accelerometer reading (accel frame)
    T, b = truth.accel.matrix, truth.accel.bias
    ups = []
    for seg in readings.segments:
        a = session.accel[seg.start : seg.stop].mean(axis=0)
        ups.append(R @ _unit(T @ (a - b)))
    ups = np.array(ups)
    sigma_a = float(truth.accel.to_dict()["noise"]) / G0
    up_cov = np.array([(np.eye(3) - np.outer(u, u)) * sigma_a**2 / k
                       for u, k in zip(ups, n, strict=True)])  # fmt: skip
    crb = np.diag(magnetometer_crb(W_true, field, dirs, cov, pose_up=ups, pose_dirs=pose_dirs,
                                   pose_cov=np.array([cov / k for k in n]), up_cov=up_cov))
    crb = crb[: len(wanted)]
    del incl
    return Graded("mag", str(sec.solver), wanted, est - x_true, sd, hw, crb, "aligned model")


def grade_warmup(warm: Session, cal: Calibration, truth: Calibration) -> dict[str, Graded | str]:
    """The temperature terms a warm-up recording gave (``calibrate SESSION --warmup WARM``):
    each channel's bias polynomial coefficients ``bias_tempco`` (counts per C^k, k = 1..3)
    against the truth's cubic, over the Cramér-Rao bound of a cubic fitted to the warm-up's
    still blocks with white noise (:func:`polynomial_bound`, as ``bench/temperature.py``
    bounds the curve's shape; each channel's own noise)."""
    out: dict[str, Graded | str] = {}
    warm = with_segments(warm)[0]  # as calibrate --warmup finds its still periods
    blocks = still_blocks(warm, BLOCK_S)
    if not blocks:
        raise ValueError("the warm-up holds no still period")
    temp = np.array([warm.temperature[a:b].mean() for a, b, _ in blocks])
    groups = np.array([k for _, _, k in blocks])
    for name in ("accel", "gyro"):
        sec, true = getattr(cal, name), getattr(truth, name)
        if sec is None or true is None or sec.temperature_terms is None:
            out[name] = "no temperature terms"
            continue
        ref, tc = sec.temperature_terms
        tc_true = np.asarray(true.to_dict()["bias_tempco"], float)
        K, n = tc_true.shape
        est = np.zeros((K, n))
        est[: min(K, tc.shape[0])] = tc[:K]
        std = np.zeros((K, n))
        given = np.asarray(sec.to_dict()["temperature_model"]["bias_tempco_std"], float)
        std[: min(K, given.shape[0])] = given[:K]
        data = getattr(warm, name)
        crb = np.zeros((K, n))
        for c in range(n):
            resid = np.concatenate([np.diff(data[a:b, c]) / np.sqrt(2) for a, b, _ in blocks])
            sig = np.array([float(np.std(resid)) / np.sqrt(b - a) for a, b, _ in blocks])
            cov = polynomial_bound(temp, sig, K, float(ref), groups)
            crb[:, c] = np.diag(cov)[-K:]
        names = np.array([f"tc{k}_{a}" for k in range(1, K + 1) for a in "xyz"[:n]])
        fitted = std.ravel() > 0  # a degree the F-tests left out states no interval
        out[name] = Graded(name, "temperature (warm-up)", list(names[fitted]),
                           (est - tc_true).ravel()[fitted], std.ravel()[fitted],
                           1.96 * std.ravel()[fitted], crb.ravel()[fitted],
                           f"bias_tempco of the fitted degrees ({int((~fitted).sum())} left "
                           "out by the degree's F-test), against the bound of a cubic on the "
                           "warm-up's blocks")  # fmt: skip
    return out


GRADERS = {"accel": grade_accel, "gyro": grade_gyro, "mag": grade_mag}


def grade(session: Session, cal: Calibration, truth: Calibration) -> dict[str, Graded | str]:
    """Every section of ``cal`` graded against ``truth`` (a section that cannot be graded:
    the reason, as text)."""
    out: dict[str, Graded | str] = {}
    for name, sec in cal.sections().items():
        if getattr(truth, name, None) is None:
            out[name] = "no truth for this sensor"
            continue
        try:
            out[name] = GRADERS[name](session, cal, truth)
        except Exception as exc:  # noqa: BLE001 - reported in the table
            out[name] = f"not graded: {type(exc).__name__}: {exc}"
        del sec
    return out
