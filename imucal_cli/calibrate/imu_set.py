"""Calibrating a set of IMUs on one rigid body (issue 28; ``docs/imu-set.md``).

:func:`calibrate_set` takes a session with several IMUs (``/raw`` the reference, ``/imus/...``
the others) and returns one calibration: the reference's sections at the top level and
``imus`` (the spec's): each other IMU's sections, ``rotation_to_reference`` with
``rotation_std_deg`` and ``time_offset_s`` with ``time_offset_std_s``.

1. The reference's segments (found in its data when the session has none) are mapped to each
   IMU's samples by time (:func:`~imucal_cli.formats.session.map_segments`) after a coarse
   time offset (:func:`~imucal_cli.estimators.imu_set.time_offset.coarse_offset` of the raw
   gyro signals).
2. Each IMU is calibrated on its own exactly as a single-IMU session
   (:func:`~imucal_cli.calibrate.session.calibrate_session`; the reference's result alone
   is what ``calibrate`` gives its ``/raw``).
3. Where every IMU's accelerometer is a gravity-solver triad (9 parameters) and they share the
   poses, their accelerometers are fitted jointly (:mod:`imucal_cli.estimators.imu_set.accel`): more
   precise than each alone, and each IMU's rotation to the reference with its covariance
   comes with it; each gyro is then calibrated again with its joint accelerometer.
   Otherwise each rotation is fitted in two steps from the IMUs' own calibrations
   (:mod:`imucal_cli.estimators.imu_set.rotation`): the shared poses, and the turns too when the
   poses all point one way.
4. Each time offset is fitted to the gyro signals
   (:mod:`imucal_cli.estimators.imu_set.time_offset`): the calibrated rates where both gyros
   are calibrated in full (eq. T4), else the raw rates with the matrix between the gyros
   fitted too (eq. T5: a gyro calibrated in part, its matrix held at nominal values, or not
   at all).
"""

from __future__ import annotations

import warnings
from dataclasses import fields, replace

import numpy as np

from imucal_cli.errors import DesignError, ImucalWarning, InputError, SolverError
from imucal_cli.estimators.imu_set.accel import fit_set_accel
from imucal_cli.estimators.imu_set.rotation import RotationFit, relative_rotation
from imucal_cli.estimators.imu_set.time_offset import (
    TimeOffset,
    coarse_offset,
    fit_time_offset,
    fit_time_offset_gains,
)
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session, imu_session, set_names
from imucal_cli.model.calibration import SENSORS, Calibration, ImuEntry, SetDiagnostics

from .common import static_poses, with_segments
from .session import calibrate_session, suspect_error
from .set_parts import (
    calibrated_rates,
    joint_section,
    pose_means,
    pose_pairs,
    shared_poses,
    still_noise,
    still_raw,
    turn_pairs,
    turn_windows,
    used_segments,
)

__all__ = ["calibrate_set", "set_suspect_error"]

#: A time offset fit whose residual RMS exceeds what the noise predicts by this factor is said.
OFFSET_RMS_RATIO = 3.0


def calibrate_set(session: Session, cfg: Config, *, name: str | None = None) -> Calibration:
    """Calibrate every IMU of ``session`` and their places in the set (module notes).

    A session of one IMU is :func:`~imucal_cli.calibrate.session.calibrate_session`'s
    result, unchanged.

    Raises
    ------
    ImucalError
        What the reference's own calibration refuses; an IMU of the set whose own calibration
        fails is left out (``left_out``) with its reason.
    """
    if not session.imus:
        return calibrate_session(session, cfg, name=name)
    names = set_names(session)
    alone = calibrate_session(replace(session, imus={}), cfg, name=name)  # today's result
    ref, note = with_segments(imu_session(session, session.reference_name))
    subs, coarse, left_out = {names[0]: ref}, {}, {}
    for key in names[1:]:
        coarse[key] = _coarse(ref, session, key)
        subs[key] = imu_session(session, key, coarse[key], segments=ref.segments)
    cals = {names[0]: alone}
    for key in names[1:]:
        try:
            cals[key] = calibrate_session(subs[key], cfg, name=f"{name or ''}:{key}")
        except (DesignError, SolverError, InputError) as exc:
            left_out[key] = f"{key} not calibrated: {exc}"
    kept = [k for k in names if k in cals]
    joint, rotations = _rotations(subs, cals, kept, cfg, session, coarse)
    if joint is not None:
        cals = _with_joint(subs, cals, joint, kept, cfg, name, note)
    offsets = {key: _offset(subs, cals, key, rotations, coarse[key]) for key in kept[1:]}
    out = _assemble(cals, kept, rotations, offsets, coarse, joint, left_out)
    out.reference_name = names[0]  # export/apply --imu NAME find it by the session's name
    return out


def _coarse(ref: Session, session: Session, key: str) -> float:
    imu = session.imus[key]
    if ref.gyro is None or imu.gyro is None:
        return 0.0
    try:
        return coarse_offset(ref.time, ref.gyro[:, :3], imu.time, imu.gyro[:, :3])
    except DesignError:
        return 0.0


def _triads_of_gravity(cals: dict, kept: list[str]) -> bool:
    return all(cals[k].accel is not None and cals[k].accel.solver == "gravity"
               and cals[k].accel.variant == "9-parameter"
               and cals[k].accel.bias.shape == (3,) for k in kept)  # fmt: skip


def _rotations(subs: dict, cals: dict, kept: list[str], cfg: Config, session: Session,
               coarse: dict[str, float]):
    """The joint fit (or None) and each IMU's :class:`RotationFit` (or the reason it has none)."""
    poses = {k: static_poses(subs[k]) for k in kept if cals[k].accel is not None}
    joint = None
    if len(kept) > 1 and _triads_of_gravity(cals, kept):
        used = {k: used_segments(cals[k].accel, poses[k]) for k in kept}
        shared = shared_poses(poses, used)
        if len(shared) >= 9:
            joint = _joint(poses, cals, kept, shared, cfg, session)
    rotations: dict[str, RotationFit | str] = {}
    for i, key in enumerate(kept[1:], start=1):
        if joint is not None:
            rotations[key] = RotationFit(matrix=joint.rotation[i], cov=joint.rotation_cov[i],
                                         pairs={"poses": len(joint.directions)})  # fmt: skip
            continue
        rotations[key] = _two_steps(subs, cals, poses, kept[0], key, coarse[key])
    return joint, rotations


def _joint(poses, cals, kept, shared, cfg, session):
    """The set's accelerometers fitted jointly; None (with a warning) when the fit fails."""
    z, cov = zip(*(pose_means(poses[k], shared) for k in kept), strict=True)
    secs = [cals[k].accel for k in kept]
    start = [np.eye(3)]
    for k in kept[1:]:
        pairs = pose_pairs((z[0], cov[0], secs[0]), (z[kept.index(k)], cov[kept.index(k)],
                                                      cals[k].accel))  # fmt: skip
        start.append(relative_rotation([pairs]).matrix)
    g = cfg.gravity or session.gravity
    try:
        return fit_set_accel(np.array(z), np.array(cov), g, np.array([s.bias for s in secs]),
                             np.array([s.matrix for s in secs]), np.array(start))  # fmt: skip
    except (DesignError, np.linalg.LinAlgError) as exc:
        warnings.warn(f"the set's joint accelerometer fit failed ({exc}): each IMU's own fit "
                      "is kept", ImucalWarning, stacklevel=3)  # fmt: skip
        return None


def _two_steps(subs, cals, poses, ref_key: str, key: str, offset_s: float) -> RotationFit | str:
    """The rotation from the IMUs' own calibrations: shared poses and turns."""
    ref_cal, cal = cals[ref_key], cals[key]
    groups = []
    if ref_cal.accel is not None and cal.accel is not None and key in poses:
        used = {k: used_segments(cals[k].accel, poses[k]) for k in (ref_key, key)}
        shared = shared_poses({k: poses[k] for k in (ref_key, key)}, used)
        if shared and ref_cal.accel.bias.shape == cal.accel.bias.shape == (3,):
            z_r, c_r = pose_means(poses[ref_key], shared)
            z_i, c_i = pose_means(poses[key], shared)
            groups.append(pose_pairs((z_r, c_r, ref_cal.accel), (z_i, c_i, cal.accel),
                                     shared))  # fmt: skip
    if ref_cal.gyro is not None and cal.gyro is not None and not _spans(groups):
        var = (still_noise(subs[ref_key], ref_cal.gyro, ref_cal.accel),
               still_noise(subs[key], cal.gyro, cal.accel))
        turns = turn_pairs(subs[ref_key], subs[key], ref_cal.gyro, cal.gyro, offset_s, var,
                           turn_windows(subs[ref_key])) if np.isfinite(var).all() else None
        if turns is not None:
            groups.append(turns)
    try:
        return relative_rotation(groups)
    except DesignError as exc:
        return f"rotation to the reference not determined: {exc}"


def _spans(groups) -> bool:
    """Whether the shared poses point two ways at least (they determine the rotation alone:
    the turns, whose gyro frame is tied to the accelerometer's, then add errors correlated
    with the poses' and are left out)."""
    if not groups:
        return False
    a = groups[0].ref / np.linalg.norm(groups[0].ref, axis=1, keepdims=True)
    return len(a) >= 2 and np.linalg.matrix_rank(a, tol=0.05) >= 2


def _with_joint(subs, cals, joint, kept, cfg, name, note) -> dict:
    """Each IMU's calibration again, its accelerometer the joint fit's (its gyro measured
    with it)."""
    fields = {"method": "joint maximum likelihood (docs/imu-set.md, eq. S1)",
              "imus": len(kept), "poses": len(joint.directions), "chi2": joint.chi2,
              "dof": joint.dof, "noise_scale": joint.noise_scale,
              "converged": joint.converged}  # fmt: skip
    out = {}
    for i, key in enumerate(kept):
        sec = joint_section(cals[key].accel, joint.bias[i], joint.matrix[i],
                            joint.params_cov[i], joint.residual_rms[i], fields)
        label = name if i == 0 else f"{name or ''}:{key}"
        cal = calibrate_session(subs[key], cfg, name=label, accel=sec)
        if i == 0:
            _keep_root(cal, cals[key])
            if note and cal.gyro is not None:
                cal.gyro.notes = [note, *(cal.gyro.notes or [])]
        out[key] = cal
    return out


def _keep_root(cal: Calibration, own: Calibration) -> None:
    """The reference's root members after its joint refit: the refit's, its own fit's where
    the refit has none, and its own completeness (the set's left-out sensors are added after)."""
    for f in fields(Calibration):
        if f.name in SENSORS or f.name == "imus" or f.name in ("unknown", "nulls"):
            continue
        if f.name in ("complete", "left_out") or getattr(cal, f.name) is None:
            setattr(cal, f.name, getattr(own, f.name))
    cal.unknown = {**own.unknown, **cal.unknown}
    cal.nulls = own.nulls | cal.nulls


def _offset(subs, cals, key, rotations, coarse_s) -> TimeOffset | str:
    """The IMU's time offset: from the calibrated rates (eq. T4) where both gyros are
    calibrated in full and the rotation is known, else from the raw rates with the matrix
    between them fitted too (eq. T5)."""
    ref_key = next(iter(subs))
    ref, imu = subs[ref_key], subs[key]
    g_r, g_i = cals[ref_key].gyro, cals[key].gyro
    rot = rotations.get(key)
    windows = [(t0, t1) for t0, t1 in _windows(ref)]
    if not windows:
        return "time offset not determined: the reference has no turns"
    if not (_full(g_r) and _full(g_i) and isinstance(rot, RotationFit)):
        return _offset_raw(ref, imu, windows, coarse_s)
    a_r, a_i = cals[ref_key].accel, cals[key].accel  # a g-sensitive gyro's g-term
    w_r = calibrated_rates(ref, g_r, a_r)
    w_i = calibrated_rates(imu, g_i, a_i) @ rot.matrix.T
    var = (still_noise(ref, g_r, a_r), still_noise(imu, g_i, a_i))
    try:
        return fit_time_offset(ref.time, w_r, imu.time, w_i, windows, var[0], var[1], coarse_s)
    except DesignError as exc:
        return f"time offset not determined: {exc}"


def _full(sec) -> bool:
    """A gyro calibrated in full (not absent, not a partial fit's matrix held at a prior)."""
    return sec is not None and sec.approach != "partial" and sec.bias.shape == (3,)


def _offset_raw(ref: Session, imu: Session, windows, coarse_s: float) -> TimeOffset | str:
    """Eq. T5 on both IMUs' raw rates, each one's bias and noise from its still periods."""
    if ref.gyro is None or imu.gyro is None:
        return "time offset not determined: an IMU has no gyro"
    (b_r, v_r), (b_i, v_i) = still_raw(ref), still_raw(imu)
    try:
        return fit_time_offset_gains(ref.time, ref.gyro[:, :3] - b_r, imu.time,
                                     imu.gyro[:, :3] - b_i, windows, v_r, v_i, coarse_s)
    except (DesignError, np.linalg.LinAlgError) as exc:
        return f"time offset not determined: {exc}"


def _windows(ref: Session) -> list[tuple[float, float]]:
    t = ref.time
    return [(float(t[s.start]), float(t[s.stop - 1])) for s in ref.rotation_segments()]


def _assemble(cals, kept, rotations, offsets, coarse, joint, left_out) -> Calibration:
    out = cals[kept[0]]
    imus = {}
    for key in kept[1:]:
        entry = ImuEntry(**cals[key].sections())
        rot, off = rotations[key], offsets[key]
        warn = []
        if isinstance(rot, RotationFit):
            entry.rotation_to_reference = rot.matrix.tolist()
            entry.rotation_std_deg = [float(x) for x in rot.std_deg]
            entry.rotation_deg = _angle_deg(rot.matrix)
        else:
            warn.append(rot)
            entry.nulls.add("rotation_deg")
        if isinstance(off, TimeOffset):
            entry.time_offset_s, entry.time_offset_std_s = off.value_s, off.std_s
            if off.rms > OFFSET_RMS_RATIO * off.rms_expected:
                warn.append(f"the gyros disagree in the turns by {off.rms:.3g} {off.units} RMS, "
                            f"{off.rms / off.rms_expected:.2g} times their noise: is {key} "
                            "rigidly mounted with the reference?")  # fmt: skip
        else:
            warn.append(off)
        entry.set = _diagnostics(rot, off, coarse[key], joint)
        if cals[key].left_out:
            entry.left_out = dict(cals[key].left_out)
        entry.warnings = warn
        imus[key] = entry
    out.imus = imus
    if left_out:
        out.left_out = {**(out.left_out or {}), **left_out}
        out.complete = False
    return out


def _angle_deg(R: np.ndarray) -> float:
    """The angle of a rotation matrix, degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))


def _diagnostics(rot, off, coarse_s: float, joint) -> SetDiagnostics:
    d = SetDiagnostics(rotation_method="joint maximum likelihood (poses)" if joint is not None
                       else "two steps (each IMU's own calibration)",
                       coarse_offset_s=coarse_s)  # fmt: skip
    if isinstance(rot, RotationFit):
        d.rotation_pairs = dict(rot.pairs)
        d.rotation_residual_deg = dict(rot.residual_deg)
        d.rotation_cov_rad2 = rot.cov.tolist()
    if isinstance(off, TimeOffset):
        d.offset_samples, d.offset_rms = off.samples, off.rms
        d.offset_rms_expected, d.offset_iterations = off.rms_expected, off.iterations
        if off.method is not None:  # eq. T5 (T4, both gyros calibrated, says nothing: as before)
            d.offset_method, d.offset_rms_units = off.method, off.units
    return d


def set_suspect_error(cal: Calibration) -> SolverError | None:
    """:func:`~imucal_cli.calibrate.session.suspect_error` of the reference and of every
    other IMU's sections (their blocking warnings stop a save without ``--force``)."""
    first = suspect_error(cal)
    if first is not None:
        return first
    for key, entry in (cal.imus or {}).items():
        problem = suspect_error(Calibration(**entry.sections()))
        if problem is not None:
            return SolverError(f"{key}: {problem}")
    return None
