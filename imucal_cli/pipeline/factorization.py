"""The factorization steps (Hwangbo & Kanade): motion constraints from a session, the linear
solution, the nonlinear refinement, the rotation ambiguity resolved on purpose, and the
sensor's section of the calibration JSON.

Accelerometers (section IV-A): every static pose is a motion of magnitude 1 g; between two
labelled poses ``h_ik = up_i . up_k`` (orthogonal faces 0, opposite faces -1, 45-degree edges
0.707). Gyroscopes (section IV-B): samples of two turns about orthogonal axes of one mounting
are orthogonal (``h_ik = 0``); one turn of known angle fixes the global scale (eq. 31).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import DesignError
from imucal_cli.formats.calibration import MODEL_EQUATION, SensorCalibration
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Segment, Session
from imucal_cli.solvers import factorization as fz
from imucal_cli.solvers.crb import invariant_summary, propagate
from imucal_cli.solvers.poses import angle_deg, count_distinct

from .accel import coverage_dict
from .common import (
    accel_units,
    channel_names,
    nominal_sensor,
    num,
    physical_checks,
    rms,
    session_name,
    static_poses,
)
from .gyro import gyro_checks

#: Poses whose labelled up directions are this close to opposite form an eq.-(14) pair.
OPPOSITE_TOLERANCE_DEG = 5.0
#: Samples per pose used in ``use = "samples"`` (evenly spaced), to bound the problem size.
MAX_SAMPLES_PER_POSE = 50


# --------------------------------------------------------------------------- accelerometers


def _accel_rows(session: Session, use: str):
    """Measurement matrix rows, the pose each row belongs to, and each row's noise (raw)."""
    poses = static_poses(session)
    pooled = np.sqrt(
        np.mean(
            [
                np.trace(c) * n / c.shape[0]
                for c, n in zip(poses.cov_mean, poses.samples, strict=True)
            ]
        )
    )
    if use == "means":
        sigma = np.sqrt([np.trace(c) / c.shape[0] for c in poses.cov_mean])
        return poses, poses.a_mean, np.arange(len(poses.a_mean)), np.maximum(sigma, 1e-12), pooled
    rows, owner = [], []
    for k, s in enumerate(poses.segments):
        idx = np.linspace(s.start, s.stop - 1, min(s.n_samples, MAX_SAMPLES_PER_POSE)).astype(int)
        rows.append(session.accel[idx])
        owner.append(np.full(len(idx), k))
    return (
        poses,
        np.vstack(rows),
        np.concatenate(owner),
        np.full(sum(map(len, rows)), pooled),
        pooled,
    )


def accel_constraints(up: np.ndarray, owner: np.ndarray, use: str) -> fz.Constraints:
    """Eq. (15) for static data: magnitude 1 for every row; ``up_a . up_b`` between rows of
    two labelled poses (per-pose means: every pair; samples: sample j of one with sample j of
    the other)."""
    m = len(owner)
    i, k, h = list(range(m)), list(range(m)), [1.0] * m
    labelled = np.flatnonzero(np.isfinite(up).all(axis=1))
    for a_pos, a in enumerate(labelled):
        rows_a = np.flatnonzero(owner == a)
        for b in labelled[a_pos + 1 :]:
            rows_b = np.flatnonzero(owner == b)
            count = min(len(rows_a), len(rows_b))
            i += list(rows_a[:count])
            k += list(rows_b[:count])
            h += [float(up[a] @ up[b])] * count
    return fz.Constraints(np.array(i), np.array(k), np.array(h))


def opposite_pair_bias(poses, where: str) -> tuple[np.ndarray, int]:
    """Triad biases from opposite poses (eq. 14), averaged over every opposite pair."""
    up = poses.up
    labelled = np.flatnonzero(np.isfinite(up).all(axis=1))
    pairs = [
        (a, b)
        for n, a in enumerate(labelled)
        for b in labelled[n + 1 :]
        if angle_deg(up[a], -up[b]) < OPPOSITE_TOLERANCE_DEG
    ]
    if not pairs:
        raise DesignError(
            f"{where}: a triad's biases come from opposite poses (eq. 14), and this session has "
            "no labelled pair of opposite faces: capture a face up and the same face down, "
            "labelled with `up`"
        )
    bias = np.mean([(poses.a_mean[a] + poses.a_mean[b]) / 2 for a, b in pairs], axis=0)
    return bias, len(pairs)


def _rotation_to_labels(F: np.ndarray, up: np.ndarray, owner: np.ndarray):
    """Rotation taking the recovered motions onto the labelled up directions (Wahba)."""
    lab = np.isfinite(up[owner]).all(axis=1)
    targets = up[owner][lab]
    if len(np.unique(owner[lab])) < 2 or np.linalg.matrix_rank(targets, tol=0.1) < 2:
        return None
    src = F[lab] / np.linalg.norm(F[lab], axis=1, keepdims=True)
    rot, _ = Rotation.align_vectors(targets, src)
    return rot.as_matrix()


def _canonical_rotation(T: np.ndarray) -> np.ndarray:
    """Rotation making ``T[:, :3]`` upper triangular with a positive diagonal (the gauge of the
    gravity solver's 9-parameter model) when nothing else fixes the frame."""
    Q, R = np.linalg.qr(T[:, :3])
    D = np.diag(np.sign(np.diag(R)))
    Rot = (Q @ D).T
    if np.linalg.det(Rot) < 0:  # keep a proper rotation: flip the last axis instead
        Rot[2] *= -1
    return Rot


def _invariants_with_std(result: fz.FactorizationResult):
    """Biases, gains and pairwise angles (rotation invariant) and their standard deviations."""
    n = len(result.b)

    def summary(x):
        T = x[n:].reshape(3, n)
        return invariant_summary(np.linalg.pinv(T).T, x[:n])

    values = invariant_summary(result.S, result.b)
    if result.cov is None:
        return values, np.full(len(values), np.nan)
    cov = propagate(summary, np.concatenate([result.b, result.T.ravel()]), result.cov)
    return values, np.sqrt(np.clip(np.diag(cov), 0, None))


def _angle_matrix(values: np.ndarray, n: int) -> list[list[float | None]]:
    A = np.full((n, n), np.nan)
    iu = np.triu_indices(n, 1)
    A[iu] = values
    A[(iu[1], iu[0])] = values
    np.fill_diagonal(A, 0.0)
    return [[num(v) for v in row] for row in A]


def _factorization_extra(lin, res, units_in: str, motion_unit: str, to_si: float):
    """Fields shared by accel and gyro sections: the linear and refined invariants."""
    n = len(res.b)
    values, std = _invariants_with_std(res)
    lin_values = invariant_summary(lin.S, lin.b)
    names = channel_names(n)
    gains = values[n : 2 * n] / to_si
    return (
        gains,
        std[n : 2 * n] / to_si,
        {
            "configuration": res.configuration,
            "case": res.case,
            "elements": n,
            "sensitivity": [float(x) for x in gains],
            "sensitivity_std": [num(x) for x in std[n : 2 * n] / to_si],
            "sensitivity_unit": f"{units_in} per {motion_unit}",
            "angles_deg": _angle_matrix(values[2 * n :], n),
            "angles_std_deg": _angle_matrix(std[2 * n :], n),
            "axis_names": names,
            "constraint_rms": res.constraint_rms,
            "linear": {
                "method": "subspace" if any("subspace" in s for s in lin.notes) else "paper",
                "bias": [float(x) for x in lin_values[:n]],
                "sensitivity": [float(x) for x in lin_values[n : 2 * n] / to_si],
                "angles_deg": _angle_matrix(lin_values[2 * n :], n),
                "constraint_rms": lin.constraint_rms,
            },
            "refined": res.method == "nonlinear",
            "iterations": res.iterations,
            "converged": res.converged,
            "message": res.message,
            "noise_scale": res.noise_scale,
            "fixture_tolerance_deg": float(np.degrees(res.fixture_tolerance)),
            "singular_values": [float(x) for x in res.singular_values],
            "notes": res.notes,
        },
    )


def _parameters(res: fz.FactorizationResult, gains, gains_std, units_in: str, per: str):
    """The section's parameter rows: each channel's bias and gain (``units_in`` per ``per``)
    with their standard deviations."""
    n = len(res.b)
    bias_std = _invariants_with_std(res)[1][:n]
    return [
        {"name": f"b_{a}", "value": float(b), "std": num(s), "unit": units_in}
        for a, b, s in zip(channel_names(n), res.b, bias_std, strict=True)
    ] + [
        {"name": f"gain_{a}", "value": float(v), "std": num(s), "unit": f"{units_in} per {per}"}
        for a, v, s in zip(channel_names(n), gains, gains_std, strict=True)
    ]


def calibrate_accel_factorization(session: Session, cfg: Config) -> SensorCalibration:
    """Hwangbo & Kanade for an accelerometer unit (triad or redundant) from static poses:
    the constraints of section IV-A, the linear solution and its refinement (IV-C), the
    rotation ambiguity resolved on purpose, and the section."""
    where = session_name(session)
    opts = cfg.accel.factorization
    poses, Z, owner, sigma, pooled = _accel_rows(session, opts.use)
    if len(poses.a_mean) < 3 or count_distinct(poses.a_mean - np.median(poses.a_mean, 0)) < 3:
        raise DesignError(f"{where}: too few distinct static poses for the factorization")
    c = accel_constraints(poses.up, owner, opts.use)  # eq. (15)
    bias = None
    notes = []
    if Z.shape[1] == 3:  # a triad's biases first: D = Z - b (eq. 13)
        bias, pairs = opposite_pair_bias(poses, where)
        notes.append(f"triad biases from {pairs} opposite pair(s) (eq. 14)")
    lin = fz.factorize(Z, c, bias=bias, linear=opts.linear)  # eqs. (7)-(28)
    res = lin
    if opts.refine:  # section IV-C
        res = fz.refine(Z, c, lin, sigma=sigma, row_owner=owner,
                        fixture_tolerance=_tolerance(opts),
                        max_iterations=opts.max_iterations)  # fmt: skip
    R, rotation = _accel_rotation(res, poses.up, owner)
    res, lin = fz.align(res, R), fz.align(lin, R)
    extra = _accel_extra(session, cfg, poses, lin, res, rotation, len(c), pooled)
    extra["notes"] = notes + extra["notes"]
    g = extra["gravity"]
    return SensorCalibration(
        solver="factorization",
        units="m/s^2",
        bias=res.b,
        matrix=g * res.T,  # motions are in g: calibrated m/s^2 = g T (z - b)
        # In output units: the constraint errors are in g^2; |f|^2 - 1 ~ 2 (|f| - 1).
        residual_rms=g * res.constraint_rms / 2,
        extra=extra,
    )


def _accel_rotation(res: fz.FactorizationResult, up: np.ndarray, owner: np.ndarray):
    """The rotation ambiguity (eq. 25: C up to R), resolved on purpose: onto the labels, or
    a canonical frame; returns the rotation and how it was fixed."""
    R = _rotation_to_labels(res.F, up, owner)
    if R is not None:
        return R, "aligned to the labelled up directions of the fixture (Wahba's problem)"
    return _canonical_rotation(res.T), (
        "no labels: canonical frame (calibrated x, y, z make the first three channels' "
        "matrix upper triangular)"
    )


def _magnitudes(poses, res: fz.FactorizationResult, g: float, nominal) -> dict:
    """Per pose: |a| before (nominal sensor, a triad only) and after calibration, m/s^2, the
    calibrated direction and its angle to the label."""
    f_pose = (poses.a_mean - res.b) @ (g * res.T).T
    mag_after = np.linalg.norm(f_pose, axis=1)
    directions = f_pose / mag_after[:, None]
    if len(res.b) == 3 and nominal.sensitivity is not None:
        mag_before = np.linalg.norm(poses.a_mean - nominal.bias, axis=1) / nominal.sensitivity
        before_basis = nominal.basis
    else:
        mag_before = np.full(len(poses.a_mean), np.nan)
        before_basis = "not available (no nominal shape for this unit)"
    up_angle = np.where(
        np.isfinite(poses.up).all(axis=1), angle_deg(directions, np.nan_to_num(poses.up)), np.nan
    )
    return {"before": mag_before, "before_basis": before_basis, "after": mag_after,
            "directions": directions, "up_angle": up_angle}  # fmt: skip


def _pose_rows(poses, mag: dict, residuals: np.ndarray) -> list[dict]:
    """The ``poses`` table of the factorization's accel section."""
    return [
        {
            "segment": s.name,
            "label": s.label,
            "up": None if s.up is None else [float(x) for x in s.up],
            "samples": int(poses.samples[k]),
            "magnitude_before": num(mag["before"][k]),
            "magnitude_after": float(mag["after"][k]),
            "residual": float(residuals[k]),
            "residual_loo": None,
            "angle_to_up_deg": num(mag["up_angle"][k]),
            "direction": [float(x) for x in mag["directions"][k]],
        }
        for k, s in enumerate(poses.segments)
    ]


def _accel_extra(session, cfg: Config, poses, lin, res, rotation: str, n_constraints: int,
                 pooled: float) -> dict:  # fmt: skip
    """The accel section's fields (DEVELOPERS.md), diagnostics per pose and coverage;
    ``pooled`` is the raw noise per sample."""
    n = len(res.b)
    g = cfg.gravity or session.gravity
    units_in, units_note = accel_units(session, g)
    gains, gains_std, extra = _factorization_extra(lin, res, units_in, "m/s^2", g)
    nominal = nominal_sensor(session, cfg, g)
    mag = _magnitudes(poses, res, g, nominal)
    residuals = mag["after"] - g
    blocking = physical_checks(res.b, gains, rms(residuals), nominal, cfg, units_in, g)
    extra.update(
        {
            "model": MODEL_EQUATION,
            "units_in": units_in,
            "variant": f"factorization, {res.configuration} (n = {n}), {extra['case']} constraints",
            "gauge": rotation,
            "rotation": rotation,
            "gravity": g,
            "use": cfg.accel.factorization.use,
            "constraints": n_constraints,
            "noise_raw": pooled,
            "parameters": _parameters(res, gains, gains_std, units_in, "m/s^2"),
            "rms_before": rms(mag["before"] - g) if np.isfinite(mag["before"]).any() else None,
            "rms_after": rms(residuals),
            "rms_loo": None,
            "before_basis": mag["before_basis"],
            "coverage": coverage_dict(mag["directions"], len(poses.segments),
                                      cfg.accel.min_separation_deg),  # fmt: skip
            "poses": _pose_rows(poses, mag, residuals),
            "warnings": blocking + ([units_note] if units_note else []),
            "blocking": blocking,
        }
    )
    return extra


# --------------------------------------------------------------------------- gyroscopes


def _tolerance(opts) -> float | None:
    """Configured fixture tolerance in rad; None: estimate it from the data."""
    if opts.fixture_tolerance_deg is None:
        return None
    return float(np.radians(opts.fixture_tolerance_deg))


def _mounting(seg: Segment) -> int:
    return int(seg.extra.get("mounting", 1))


def _orthogonal_pairs(turns: list[Segment]) -> int:
    """Pairs of distinct, orthogonal axes among some turns."""
    axes = []
    for s in turns:
        if all(abs(abs(s.axis @ a) - 1) > 1e-3 for a in axes):
            axes.append(s.axis)
    return sum(abs(a @ b) < 1e-3 for n, a in enumerate(axes) for b in axes[n + 1 :])


def independent_constraints(turns: list[Segment]) -> int:
    """Independent orthogonality constraints that turns about labelled axes give (section
    IV-B): structure, not numerics: one mounting gives at most 3 (its three axes); the metric
    upgrade needs 5."""
    labelled = [s for s in turns if s.axis is not None]
    return sum(
        min(3, _orthogonal_pairs([s for s in labelled if _mounting(s) == mt]))
        for mt in {_mounting(s) for s in labelled}
    )


def _orthogonality_rms(res: fz.FactorizationResult, c: fz.Constraints) -> float:
    """RMS, in rad/s, of each turn's rate along the other turn's axis (f_i . f_k / |f_k|)."""
    F = res.F
    along = np.sum(F[c.i] * F[c.k], axis=1) / np.linalg.norm(F[c.k], axis=1)
    return rms(along)


def _gyro_bias(session: Session, where: str) -> tuple[np.ndarray, float]:
    """Gyro biases and per-sample noise from the still (static) segments."""
    still = [s for s in session.static_segments()]
    if not still or session.gyro is None:
        raise DesignError(
            f"{where}: gyroscope biases come from still periods: record the unit still (static "
            "segments) before and between the turns"
        )
    data = np.vstack([session.gyro[s.start : s.stop] for s in still])
    noise = float(np.sqrt(np.mean(np.var(data, axis=0))))
    return data.mean(axis=0), noise


def _pick_rows(z: np.ndarray, bias: np.ndarray, count: int, noise: float) -> np.ndarray:
    """Indices of up to ``count`` samples of a turn, evenly spread over its moving part."""
    moving = np.flatnonzero(np.linalg.norm(z - bias, axis=1) > 10 * noise)
    if len(moving) == 0:
        return moving
    return moving[np.linspace(0, len(moving) - 1, min(count, len(moving))).astype(int)]


def calibrate_gyro_factorization(session: Session, cfg: Config) -> SensorCalibration:
    """Hwangbo & Kanade for a gyroscope unit from turns about labelled axes (section IV-B):
    orthogonality constraints between turns (IV-B.1-3), the linear factorization scaled by a
    known turn and refined (III-B, IV-C), the rotation fixed by the labelled axes (IV-B.5)."""
    where = session_name(session)
    opts = cfg.gyro.factorization
    if session.gyro is None:
        raise DesignError(f"{where}: no /raw/gyro in this session")
    turns = [s for s in session.rotation_segments() if s.axis is not None]
    if not turns:
        raise DesignError(
            f"{where}: the gyroscope factorization needs rotation segments with an `axis` "
            "(turns about the faces of a square block)"
        )
    bias, noise = _gyro_bias(session, where)
    Z, seg_of_row, c = _gyro_constraints(session, turns, bias, noise, opts, where)
    lin, res, ref = _gyro_solve(session, turns, Z, seg_of_row, c, bias, noise, opts, where)
    R = _gyro_rotation(res, turns, seg_of_row, ref)
    res, lin = fz.align(res, R), fz.align(lin, R)
    return _gyro_section(session, cfg, lin, res, ref, c, noise)


def _gyro_constraints(session, turns, bias, noise, opts, where):
    """Rows of ``Z`` (samples of each turn) and the orthogonality constraints between turns
    about orthogonal axes of one mounting (section IV-B.1-3); refused when they cannot give
    the metric upgrade its 5 independent constraints."""
    rows, seg_of_row = [], []
    for k, s in enumerate(turns):  # every turn, known-angle ones too, gives orthogonality
        z = session.gyro[s.start : s.stop]
        idx = _pick_rows(z, bias, opts.samples_per_segment, noise)
        rows.append(z[idx])
        seg_of_row += [k] * len(idx)
    if not rows:
        raise DesignError(f"{where}: no turn shows motion above the gyro noise")
    Z = np.vstack(rows)
    seg_of_row = np.array(seg_of_row)
    i, k = [], []
    for a in range(len(turns)):
        for b in range(a + 1, len(turns)):
            sa, sb = turns[a], turns[b]
            if _mounting(sa) != _mounting(sb) or abs(sa.axis @ sb.axis) > 1e-3:
                continue
            # Sample j of one turn with sample j of the other: every sample enters few
            # constraints, so the residuals stay nearly independent.
            ra, rb = np.flatnonzero(seg_of_row == a), np.flatnonzero(seg_of_row == b)
            count = min(len(ra), len(rb))
            i += list(ra[:count])
            k += list(rb[:count])
    if not i:
        raise DesignError(
            f"{where}: no two turns about orthogonal axes in one mounting: turn the block on "
            "three orthogonal faces"
        )
    independent = independent_constraints(turns)
    if independent < 5:
        raise DesignError(
            f"{where}: the turns give {independent} independent orthogonality constraints, the "
            "metric upgrade needs 5: the constraints are not independent enough; repeat the "
            "three turns with the unit in a second mounting inside the block (section IV-B)"
        )
    return Z, seg_of_row, fz.Constraints(np.array(i), np.array(k), np.zeros(len(i)))


@dataclass
class _KnownTurn:
    """The turn of known angle that fixes the gyro's scale (eq. 31)."""

    segment: Segment
    w_raw: np.ndarray  # raw integral over the turn
    duration: float
    w: np.ndarray  # integral less the still periods' bias


def _gyro_solve(session, turns, Z, seg_of_row, c, bias, noise, opts, where):
    """The linear factorization with the known turn's scale (section III-B, eq. 31), then the
    nonlinear refinement with the still readings and the known turn (section IV-C)."""
    known = [s for s in turns if s.angle_deg is not None]
    if not known:
        raise DesignError(
            f"{where}: orthogonality fixes the gyro gains only up to one scale: add one turn of "
            "known angle (a ruler-guided 90-degree turn with `angle_deg`)"
        )
    ref_seg = known[0]
    t = session.time[ref_seg.start : ref_seg.stop]
    dt = float(np.median(np.diff(t)))
    # Raw integral and its duration: the bias term is subtracted by whoever knows the bias.
    duration = float(t[-1] - t[0])
    w_raw = np.trapezoid(session.gyro[ref_seg.start : ref_seg.stop], t, axis=0)
    w = w_raw - duration * bias
    ref = fz.ScaleReference(w_raw, np.radians(abs(ref_seg.angle_deg)), duration)
    lin = fz.factorize(Z, c, bias=bias, scale_reference=ref, linear=opts.linear)
    res = lin
    if opts.refine:
        # The reference's uncertainty: integrated white noise plus the bias error over its
        # duration, in rad through the linear gains.
        still = np.vstack([session.gyro[s.start : s.stop] for s in session.static_segments()])
        integ = noise * (np.sqrt(len(t)) * dt + (t[-1] - t[0]) / np.sqrt(len(still)))
        ref = fz.ScaleReference(
            w_raw, ref.magnitude, duration, sigma=float(np.linalg.norm(lin.T, 2) * integ)
        )
        zero = (still.mean(axis=0)[None, :], np.array([noise / np.sqrt(len(still))]))
        res = fz.refine(Z, c, lin, sigma=noise, scale_reference=ref, zero_motion=zero,
                        row_owner=seg_of_row, fixture_tolerance=_tolerance(opts),
                        max_iterations=opts.max_iterations)  # fmt: skip
    return lin, res, _KnownTurn(ref_seg, w_raw, duration, w)


def _gyro_rotation(res, turns, seg_of_row, ref: _KnownTurn) -> np.ndarray:
    """The rotation that section IV-B.5 leaves: the known turn along its labelled axis, the
    other turns of its mounting along theirs."""
    ref_seg = ref.segment
    target = np.sign(ref_seg.angle_deg) * ref_seg.axis
    primary = res.T @ ref.w
    lines_src, lines_dst = [primary / np.linalg.norm(primary)], [target]
    weights = [np.inf]
    for kk, s in enumerate(turns):
        sel = seg_of_row == kk
        if _mounting(s) != _mounting(ref_seg) or not sel.any() or s.angle_deg is not None:
            continue
        F = res.F[sel]
        _, _, Vt = np.linalg.svd(F, full_matrices=False)
        d = Vt[0]
        lines_src.append(d)
        lines_dst.append(s.axis)
        weights.append(1.0)
    # Lines have no sign: choose each to agree with the primary alignment first.
    R0, _ = Rotation.align_vectors([target], [lines_src[0]])
    for j in range(1, len(lines_src)):
        if R0.apply(lines_src[j]) @ lines_dst[j] < 0:
            lines_src[j] = -lines_src[j]
    rot, _ = Rotation.align_vectors(np.array(lines_dst), np.array(lines_src), weights=weights)
    R = rot.as_matrix()
    # Turns back and forth give axes without a sign, so a half turn about the known axis is
    # still free: take the one where every channel responds positively along its own
    # calibrated axis (the diagonal of the matrix; misalignments are small).
    half = Rotation.from_rotvec(np.pi * target).as_matrix()
    if np.sum(np.sign(np.diag((half @ R @ res.T)[:, :3]))) > np.sum(
        np.sign(np.diag((R @ res.T)[:, :3]))
    ):
        R = half @ R
    return R


#: How the factorization's rotation is fixed (step IV-B.5).
GYRO_ROTATION = ("the known-angle turn along its labelled axis, the other turns of its mounting "
                 "along theirs (step IV-B.5)")  # fmt: skip


def _gyro_section(session, cfg, lin, res, ref: _KnownTurn, c, noise) -> SensorCalibration:
    """The gyro section of the factorization: gains and biases with their std, the known
    turn's measured angle."""
    n = session.gyro.shape[1]
    ref_seg, rotation = ref.segment, GYRO_ROTATION
    units_in = session.gyro_units or "unknown"
    gains, gains_std, extra = _factorization_extra(lin, res, units_in, "rad/s", 1.0)
    measured = np.degrees(np.linalg.norm(res.T @ (ref.w_raw - ref.duration * res.b)))
    parameters = _parameters(res, gains, gains_std, units_in, "rad/s")
    extra.update(
        {
            "model": MODEL_EQUATION,
            "units_in": units_in,
            "variant": f"factorization, {res.configuration} (n = {n}), orthogonal + known turns",
            "gauge": rotation,
            "rotation": rotation,
            "parameters": parameters,
            "constraints": len(c),
            "noise_raw": noise,
            "rotations": [
                {
                    "segment": ref_seg.name,
                    "label": ref_seg.label,
                    "known_angle_deg": ref_seg.angle_deg,
                    "measured_angle_deg": float(np.sign(ref_seg.angle_deg) * measured),
                    "angle_error_deg": float(
                        np.sign(ref_seg.angle_deg) * measured - ref_seg.angle_deg
                    ),
                }
            ],
            "warnings": gyro_checks(session, cfg, gains, units_in),
        }
    )
    return SensorCalibration(
        solver="factorization",
        units="rad/s",
        bias=res.b,
        matrix=res.T,
        residual_rms=_orthogonality_rms(res, c),
        extra=extra,
    )
