"""What calibrating a set of IMUs needs from each IMU's own calibration (issue 28;
:mod:`imucal_cli.calibrate.imu_set`): the vector pairs of the shared poses and turns, each
IMU's gyro noise, the turns' windows, and the accel sections of the joint fit."""

from __future__ import annotations

import copy

import numpy as np

from imucal_cli.estimators.accel.gravity import PARAM_NAMES_9, model_to_params, params_to_model
from imucal_cli.estimators.imu_set.rotation import PairGroup, calibration_derivative
from imucal_cli.formats.session import Session
from imucal_cli.model.accel import AccelCalibration, OwnFit, SetFit
from imucal_cli.model.section import SensorCalibration

from .accel.section import axes_summary_with_std, model_covariance, parameter_rows
from .common import StaticPoses

#: Still time taken on each side of a turn when it is integrated from rest to rest, s.
TURN_MARGIN_S = 0.1

GYRO_PARAMETERS = ["b_x", "b_y", "b_z"] + [f"m_{r}{c}" for r in "xyz" for c in "xyz"]


def section_covariance(sec: SensorCalibration | None) -> np.ndarray | None:
    """The 12 x 12 covariance of a triad section's ``(bias, matrix row-major)``: its
    ``covariance`` field, else (a gyro) the squares of its parameter rows' std when they are
    exactly those 12 (their correlations unknown: left out); None when it states neither."""
    if sec is None or sec.bias.shape != (3,):
        return None
    cov = None if sec.covariance is None else sec.covariance.values
    if cov is not None and np.shape(cov) == (12, 12):
        return np.asarray(cov, float)
    std = {r.name: r.std for r in sec.parameters or []}
    if all(isinstance(std.get(n), float | int) for n in GYRO_PARAMETERS):
        return np.diag(np.square([float(std[n]) for n in GYRO_PARAMETERS]))
    return None


def shared_poses(poses: dict[str, StaticPoses], used: dict[str, set[str]]) -> list[str]:
    """The static segments every IMU holds and every IMU's own fit used, by name."""
    names = None
    for key, p in poses.items():
        mine = {s.name for s in p.segments} & used[key]
        names = mine if names is None else names & mine
    order = [s.name for s in next(iter(poses.values())).segments]
    return [n for n in order if n in (names or set())]


def used_segments(sec: SensorCalibration, poses: StaticPoses) -> set[str]:
    """The static segments an accel section's fit used (its poses rows not ``excluded``)."""
    excluded = {r.segment for r in getattr(sec, "poses", None) or [] if r.excluded}
    return {s.name for s in poses.segments} - excluded


def pose_means(poses: StaticPoses, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """The mean raw readings (P, 3) and their covariances (P, 3, 3) of segments ``names``."""
    index = {s.name: k for k, s in enumerate(poses.segments)}
    rows = [index[n] for n in names]
    return poses.a_mean[rows, :3], poses.cov_mean[rows, :3, :3]


def pose_pairs(ref: tuple, imu: tuple, names: list[str] | None = None) -> PairGroup:
    """The pairs of the shared poses ``names``: each IMU's calibrated mean (``(z, cov,
    section)``).

    Where both sections are fits onto the poses' labels (the labelled solver's
    ``given_placement``), each calibration enters by its errors given the placement, which
    the set shares and which cancels from the rotation, and by its covariance with the pose
    means it was fitted to (``docs/imu-set.md``, eq. R3); otherwise by its ``covariance``,
    independent of the pairs (eq. R2)."""
    given = [getattr(sec, "given_placement", None) for sec in (ref[2], imu[2])]
    labelled = names is not None and all(
        gp is not None and set(names) <= set(gp.segments) for gp in given)  # fmt: skip

    def side(z, cov, sec, gp):
        d = z - sec.bias
        out = [d @ sec.matrix.T, np.einsum("ij,pjk,lk->pil", sec.matrix, cov, sec.matrix),
               calibration_derivative(sec.matrix, d), section_covariance(sec), None]
        if labelled:  # eq. R3: Sigma_c given the placement; X_cp = L_cp cov_p M^T
            rows = [gp.segments.index(n) for n in names]
            out[3] = gp.covariance
            out[4] = np.einsum("inj,njk,lk->nil", gp.response[:, rows], cov, sec.matrix)
        return out

    a, ca, da, sa, xa = side(*ref, given[0])
    b, cb, db, sb, xb = side(*imu, given[1])
    return PairGroup(a, b, ca, cb, da, db, sa, sb, name="poses", cross_ref=xa, cross_imu=xb)


def calibrated_rates(session: Session, sec: SensorCalibration,
                     accel: SensorCalibration | None = None,
                     rows: slice = slice(None)) -> np.ndarray:  # fmt: skip
    """A gyro's calibrated rates (k, 3), rad/s, of the samples ``rows``: a gyro calibrated
    with its g-sensitivity has it taken out with the calibrated accelerometer (``accel``) of
    the same samples; without one, the g-term is left in (still scatter, a turn's shape)."""
    raw = session.gyro[rows, : sec.bias.shape[0]]
    if sec.g_term is None:
        return sec.apply(raw)
    if accel is not None and session.accel is not None:
        return sec.apply(raw, accel=accel.apply(session.accel[rows, : accel.bias.shape[0]]))
    return (raw - sec.bias) @ sec.matrix.T


def still_noise(session: Session, sec: SensorCalibration,
                accel: SensorCalibration | None = None) -> float:  # fmt: skip
    """A gyro's calibrated white noise variance per axis per sample, (rad/s)^2: the
    within-segment scatter pooled over the static segments (the mean of the three axes);
    ``accel``: the IMU's accelerometer calibration (:func:`calibrated_rates`)."""
    total, dof = 0.0, 0
    for s in session.static_segments():
        w = calibrated_rates(session, sec, accel, slice(s.start, s.stop))
        if len(w) > 1:
            total += float(np.sum((w - w.mean(axis=0)) ** 2)) / 3.0
            dof += len(w) - 1
    return total / dof if dof else float("nan")


def still_raw(session: Session) -> tuple[np.ndarray, np.ndarray]:
    """A gyro's raw bias (the mean of its still periods' samples) and white noise variance
    per channel per sample (the within-period scatter pooled over them), raw units: NaN
    without a still period."""
    total, ss, n, dof = np.zeros(3), np.zeros(3), 0, 0
    for s in session.static_segments():
        w = session.gyro[s.start:s.stop, :3]
        if len(w) > 1:
            total += w.sum(axis=0)
            ss += np.sum((w - w.mean(axis=0)) ** 2, axis=0)
            n, dof = n + len(w), dof + len(w) - 1
    if not dof:
        return np.full(3, np.nan), np.full(3, np.nan)
    return total / n, ss / dof


def turn_windows(session: Session) -> list[tuple[float, float]]:
    """Each rotation segment of the reference from rest to rest: its times plus
    :data:`TURN_MARGIN_S` on each side, s."""
    t = session.time
    return [(float(t[s.start] - TURN_MARGIN_S), float(t[s.stop - 1] + TURN_MARGIN_S))
            for s in session.rotation_segments()]  # fmt: skip


def integrate(session: Session, sec: SensorCalibration, window: tuple[float, float],
              offset_s: float = 0.0) -> tuple[np.ndarray, float, float] | None:  # fmt: skip
    """A turn's raw rate integrated over ``window`` (reference time; the IMU's stamps plus
    ``offset_s``): ``(int raw dt (3,), duration s, mean step s)``, None with < 3 samples."""
    t = session.time + offset_s
    rows = np.flatnonzero((t >= window[0]) & (t <= window[1]))
    if rows.size < 3 or session.gyro is None:
        return None
    raw = session.gyro[rows, :3]
    tt = t[rows]
    return np.trapezoid(raw, tt, axis=0), float(tt[-1] - tt[0]), float(np.mean(np.diff(tt)))


def turn_pairs(ref: Session, imu: Session, ref_sec: SensorCalibration,
               imu_sec: SensorCalibration, offset_s: float, var: tuple[float, float],
               windows: list[tuple[float, float]]) -> PairGroup | None:  # fmt: skip
    """The pairs of the shared turns (each IMU's calibrated rate integrated from rest to
    rest), with the noise of the integrals and the gyro calibrations' parts; None when a gyro
    calibration states no covariance (the turns' weight would be unknown)."""
    cal_r, cal_i = section_covariance(ref_sec), section_covariance(imu_sec)
    if cal_r is None or cal_i is None:
        return None
    out: dict[str, list] = {k: [] for k in ("a", "b", "ca", "cb", "da", "db")}
    for w in windows:
        got_r, got_i = integrate(ref, ref_sec, w), integrate(imu, imu_sec, w, offset_s)
        if got_r is None or got_i is None:
            continue
        for (Z, T, dt), sec, v, key in ((got_r, ref_sec, var[0], "a"), (got_i, imu_sec, var[1],
                                                                         "b")):  # fmt: skip
            d = Z - sec.bias * T
            out[key].append(sec.matrix @ d)
            out["c" + key].append(np.eye(3) * v * dt * T)
            out["d" + key].append(calibration_derivative(sec.matrix, d, T)[0])
    if len(out["a"]) == 0:
        return None
    arr = {k: np.array(v) for k, v in out.items()}
    return PairGroup(arr["a"], arr["b"], arr["ca"], arr["cb"], arr["da"], arr["db"], cal_r,
                     cal_i, name="turns")  # fmt: skip


def joint_section(sec: AccelCalibration, bias: np.ndarray, matrix: np.ndarray,
                  cov: np.ndarray, residual_rms: float, fit_fields: dict) -> AccelCalibration:
    """An IMU's accel section from the set's joint fit: its own fit's section (poses, checks,
    choice) with the joint bias, matrix, parameters, covariance, sensitivities and
    misalignments, and a ``set_fit`` field saying so."""
    out = copy.deepcopy(sec)
    out.bias, out.matrix = np.asarray(bias, float), np.asarray(matrix, float)
    params = model_to_params(out.bias, out.matrix)
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    units = [out.units_in or "raw"] * 3 + ["m/s^2 per raw unit"] * 6
    old = {r.name: r for r in out.parameters or []}
    units = [old[n].unit if n in old and old[n].unit is not None else u
             for n, u in zip(PARAM_NAMES_9, units, strict=True)]  # fmt: skip
    out.parameters = parameter_rows(list(PARAM_NAMES_9), params, std, units)
    out.covariance = model_covariance(model_to_params, out.bias, out.matrix, cov)
    derived, derived_std = axes_summary_with_std(lambda p: params_to_model(p)[1], params, cov)
    out.sensitivity = [float(x) for x in derived[:3]]
    out.sensitivity_std = [float(x) for x in derived_std[:3]]
    keys = ("xy", "xz", "yz")
    out.misalignment_deg = dict(zip(keys, map(float, derived[3:]), strict=True))
    out.misalignment_std_deg = dict(zip(keys, map(float, derived_std[3:]), strict=True))
    out.residual_rms = float(residual_rms)
    out.set_fit = SetFit(own_fit=OwnFit(bias=sec.bias.tolist(), matrix=sec.matrix.tolist(),
                                        residual_rms=sec.residual_rms), **fit_fields)
    out.notes = [
        "bias and matrix from the set's joint fit (every IMU's accelerometer in the shared "
        "poses, their gravity directions common); the poses table is this IMU's own fit",
        *(out.notes or [])]  # fmt: skip
    return out
