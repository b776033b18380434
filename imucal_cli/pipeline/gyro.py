"""Gyroscope calibration from hand rotations and the calibrated accelerometer (issue 5).

Each rotation is turned between two still periods; the accelerometer, calibrated in the same
run, measures the gravity direction in both, and so how far the unit turned. Three solvers:

* ``static``  (Qureshi & Golnaraghi eq. 18): bias from the still periods, scale per axis;
* ``dynamic`` (eqs. 19-21): scale and bias per axis from the rotations alone;
* ``full``: 12 parameters (bias, scale and misalignment relative to the accelerometer frame)
  from arbitrary rotations, by integrating the gyro and matching the gravity direction.

Rotation segments come from the session; where it has none, they are found in the stream
(motion between two still periods, thresholds from the data's own noise).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal_cli.errors import DesignError
from imucal_cli.formats.calibration import MODEL_EQUATION, SensorCalibration
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Segment, Session
from imucal_cli.solvers import gyro_axes, gyro_full
from imucal_cli.solvers.segmentation import find_rotations, find_static

from .common import num, rms, session_name, with_segments

AXES = "xyz"
#: Per-axis (static/dynamic) solvers: a turn whose axis is further than this from the sensor
#: axis it is attributed to is left out (the full model takes any turn).
MAX_AXIS_ERROR_DEG = 15.0
#: Per-axis solvers: rotation residuals above this RMS mean the per-axis model does not fit.
MAX_PER_AXIS_RMS_DEG = 1.0


@dataclass
class Turn:
    """One rotation with the still periods around it (indices into the still list)."""

    segment: Segment
    before: int
    after: int


@dataclass
class Still:
    segment: Segment
    g: np.ndarray  # calibrated accel mean, m/s^2
    g_sigma: float  # direction noise of the mean, rad
    z_mean: np.ndarray  # raw gyro mean
    z_sigma: float  # noise of the raw gyro mean, per channel


def _segments(session: Session, where: str) -> tuple[list[Segment], list[Segment], str]:
    """Static and rotation segments: the session's, else found in the stream."""
    statics, turns = session.static_segments(), session.rotation_segments()
    if turns and statics:
        return statics, turns, "the session's segments"
    if session.accel is None or session.gyro is None:
        raise DesignError(f"{where}: gyro calibration needs both /raw/accel and /raw/gyro")
    found = find_static(session.time, session.accel, session.gyro)
    found_statics = [
        Segment(f"s{i:04d}", "static", iv.start, iv.stop) for i, iv in enumerate(found)
    ]
    rot = find_rotations(session.time, session.gyro, found)
    found_turns = [Segment(f"r{i:04d}", "rotation", iv.start, iv.stop) for i, iv in enumerate(rot)]
    if not found_turns:
        raise DesignError(
            f"{where}: no rotation between two still periods was found: hold the unit still, "
            "turn it, hold it still again (about 5 s each), several times"
        )
    return found_statics, found_turns, "found in the stream (motion between still periods)"


def _stills_and_turns(session, accel_cal, cfg, where):
    statics, turns, source = _segments(session, where)
    g = cfg.gravity or session.gravity
    stills = []
    for s in statics:
        a = accel_cal.apply(session.accel[s.start : s.stop])
        z = session.gyro[s.start : s.stop]
        n = len(a)
        a_noise = float(np.sqrt(np.mean(np.var(a, axis=0)))) if n > 1 else 0.0
        stills.append(Still(
            s, a.mean(axis=0), max(a_noise / (g * np.sqrt(n)), 1e-6), z.mean(axis=0),
            float(np.sqrt(np.mean(np.var(z, axis=0)) / n)) if n > 1 else 0.0,
        ))  # fmt: skip
    gap = cfg.gyro.rotations.max_gap_s
    usable, skipped = [], []
    for r in turns:
        t0, t1 = session.time[r.start], session.time[r.stop - 1]
        before = [
            k
            for k, s in enumerate(stills)
            if s.segment.stop <= r.start + 1 and t0 - session.time[s.segment.stop - 1] <= gap
        ]
        after = [
            k
            for k, s in enumerate(stills)
            if s.segment.start >= r.stop - 1 and session.time[s.segment.start] - t1 <= gap
        ]
        if before and after:
            usable.append(Turn(r, before[-1], after[0]))
        else:
            skipped.append(r.label or r.name)
    if not usable:
        raise DesignError(
            f"{where}: no rotation has still data right before and after it (within "
            f"{gap:g} s): hold the unit still for a few seconds before and after every turn"
        )
    return stills, usable, skipped, source


def _saturated(session: Session, turn: Turn, limit: tuple[float, float] | None) -> bool:
    if limit is None:
        return False
    z = session.gyro[turn.segment.start : turn.segment.stop]
    return bool(np.any((z <= limit[0]) | (z >= limit[1])))


def _saturation_limit(session: Session, cfg: Config) -> tuple[float, float] | None:
    """Raw levels at which the gyro clips: the configured range, else a counts gyro's ADC word,
    less 0.5 % of the span at both ends."""
    if cfg.gyro.range is not None:
        lo, hi = cfg.gyro.range
        margin = 0.005 * (hi - lo)
        return lo + margin, hi - margin
    if session.gyro_units != "counts":
        return None
    from .common import adc_range

    finite = session.gyro[np.isfinite(session.gyro).all(axis=1)]
    rng = adc_range(float(finite.min()), float(finite.max()))
    if rng is None:
        return None
    margin = 0.005 * (rng[1] - rng[0])
    return rng[0] + margin, rng[1] - margin


def _integral(session: Session, seg: Segment) -> tuple[np.ndarray, float]:
    t = session.time[seg.start : seg.stop]
    return np.trapezoid(session.gyro[seg.start : seg.stop], t, axis=0), float(t[-1] - t[0])


def _axis_of(turn: Turn, x: np.ndarray, bias: np.ndarray, T: float) -> int:
    """The gyro axis a turn is about: its labelled axis, else the dominant raw channel."""
    if turn.segment.axis is not None:
        return int(np.argmax(np.abs(turn.segment.axis)))
    return int(np.argmax(np.abs(x - bias * T)))


def calibrate_gyro_rotations(session: Session, cfg: Config, accel_cal: SensorCalibration):
    """Gyro calibration with the ``static``, ``dynamic`` or ``full`` solver."""
    where = session_name(session)
    if session.gyro is None:
        raise DesignError(f"{where}: no /raw/gyro in this session")
    solver = cfg.gyro.solver
    stills, turns, skipped, source = _stills_and_turns(session, accel_cal, cfg, where)
    notes = [f"rotations: {source}"]
    warnings = []
    if skipped:
        notes.append(f"{len(skipped)} rotation(s) without still data before and after: skipped")
    limit = _saturation_limit(session, cfg)
    clipped = [t for t in turns if _saturated(session, t, limit)]
    if clipped:
        warnings.append(
            f"{len(clipped)} rotation(s) reach the end of the gyro's range (raw "
            f"{limit[0]:.6g} .. {limit[1]:.6g}): left out; turn more slowly"
        )
        turns = [t for t in turns if t not in clipped]
    if not turns:
        raise DesignError(f"{where}: every rotation is clipped: turn the unit more slowly")
    z_still = np.vstack([session.gyro[s.segment.start : s.segment.stop] for s in stills])
    bias_still = z_still.mean(axis=0)
    gyro_noise = float(np.sqrt(np.mean(np.var(z_still, axis=0))))
    b_still_std = gyro_noise / np.sqrt(len(z_still))
    units_in = session.gyro_units or "unknown"

    rotations = []
    if solver in ("static", "dynamic"):
        # Pass 1 reads each angle about the nominal axis; pass 2 about the turn's own axis,
        # the rotation vector that the pass-1 calibration integrates (a hand is never exact).
        k = b = None
        for _ in range(2):
            k, b, k_std, b_std, rotations = _per_axis(
                session, solver, turns, stills, bias_still, b_still_std, cfg, where,
                notes if k is None else [], None if k is None else (k, b),
            )  # fmt: skip
        matrix = np.diag(k)
        parameters = [
            {"name": f"b_{a}", "value": float(b[i]), "std": num(b_std[i]), "unit": units_in}
            for i, a in enumerate(AXES)
        ] + [
            {"name": f"k_{a}", "value": float(k[i]), "std": num(k_std[i]),
             "unit": f"rad/s per {units_in}"}
            for i, a in enumerate(AXES)
        ]  # fmt: skip
        residual = np.radians([r["angle_error_deg"] for r in rotations])
        if np.degrees(rms(residual)) > MAX_PER_AXIS_RMS_DEG:
            warnings.append(
                f"the per-axis model does not fit these turns (angle residual RMS "
                f"{np.degrees(rms(residual)):.2f} deg): turn about one sensor axis at a time "
                '(x and y with z up, z on its side), or use [gyro] solver = "full"'
            )
        extra = {"model_paper": "omega = K (omega_s - B), eq. (15)", "approach": solver}
        scale_for_checks = 1 / np.abs(k)
    else:
        rot, st = _full_problem(session, stills, turns)
        res = gyro_full.fit_full(
            rot, st, max(gyro_noise, 1e-12), bias_still,
            max_iterations=cfg.gyro.full.max_iterations,
        )  # fmt: skip
        notes += res.notes
        b, matrix = res.b, res.M
        names = [f"m_{r}{c}" for r in AXES for c in AXES]
        parameters = [
            {"name": f"b_{a}", "value": float(b[i]), "std": num(res.std[i]), "unit": units_in}
            for i, a in enumerate(AXES)
        ] + [
            {"name": n, "value": float(v), "std": num(s), "unit": f"rad/s per {units_in}"}
            for n, v, s in zip(names, matrix.ravel(), res.std[3:], strict=True)
        ]
        for t, r_deg, a_deg in zip(turns, res.angle_residual_deg, res.rotation_angle_deg,
                                   strict=True):  # fmt: skip
            rotations.append({
                "segment": t.segment.name, "label": t.segment.label,
                "known_angle_deg": None, "measured_angle_deg": float(a_deg),
                "angle_error_deg": float(r_deg),
            })  # fmt: skip
        residual = np.radians(res.angle_residual_deg)
        S = np.linalg.inv(matrix)
        s_axes = S / np.linalg.norm(S, axis=1, keepdims=True)
        extra = {
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
        }  # fmt: skip
        scale_for_checks = np.linalg.norm(S, axis=1)
    warnings += gyro_checks(session, cfg, scale_for_checks, units_in)
    extra.update({
        "model": MODEL_EQUATION,
        "units_in": units_in,
        "variant": {"static": "Qureshi static-bias approach (eq. 18)",
                    "dynamic": "Qureshi dynamic approach (eqs. 19-21)",
                    "full": "12 parameters from integrated rotations"}[solver],
        "frame": "the calibrated accelerometer's frame",
        "parameters": parameters,
        "sensitivity": [float(x) for x in scale_for_checks],
        "sensitivity_unit": f"{units_in} per rad/s",
        "rotations": rotations,
        "rotation_rms_deg": float(np.degrees(rms(residual))),
        "gyro_noise_raw": gyro_noise,
        "notes": notes,
        "warnings": warnings,
    })  # fmt: skip
    return SensorCalibration(
        solver=f"gyro-{solver}",
        units="rad/s",
        bias=np.asarray(b, float),
        matrix=np.asarray(matrix, float),
        residual_rms=rms(residual),
        extra=extra,
    )


def _per_axis(session, solver, turns, stills, bias_still, b_still_std, cfg, where, notes, first):
    """Per-axis fits (static or dynamic) of every axis; ``first`` = (k, b) of a previous pass
    whose calibration gives each turn's actual axis."""
    k, b, k_std, b_std = np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
    min_lev = np.sin(np.radians(cfg.gyro.rotations.min_tilt_deg)) ** 2
    per_axis = {i: [] for i in range(3)}
    oblique = 0
    for turn in turns:
        x, T = _integral(session, turn.segment)
        i = _axis_of(turn, x, bias_still, T)
        sign = np.sign(turn.segment.axis[i]) if turn.segment.axis is not None else 1.0
        axis = np.eye(3)[i] * sign
        # The per-axis model holds for turns about one sensor axis only: the turn's own axis
        # (raw integral in pass 1, calibrated in pass 2) must be near it.
        turned = (x - bias_still * T) if first is None else first[0] * (x - first[1] * T)
        off = np.degrees(np.arccos(min(1.0, abs(turned[i]) / max(np.linalg.norm(turned), 1e-300))))
        if off > MAX_AXIS_ERROR_DEG:
            oblique += 1
            notes.append(
                f"{turn.segment.label or turn.segment.name}: turned {off:.0f} deg away from the "
                f"{AXES[i]} axis, not about one sensor axis: left out of the per-axis fit"
            )
            continue
        if first is not None:
            rotvec = first[0] * (x - first[1] * T)
            axis = rotvec / np.linalg.norm(rotvec) * np.sign(rotvec[i]) * sign
        angle, lev = gyro_axes.rotation_angle_about_axis(
            stills[turn.before].g, stills[turn.after].g, axis
        )
        if lev < min_lev:
            notes.append(
                f"{turn.segment.label or turn.segment.name}: axis within "
                f"{cfg.gyro.rotations.min_tilt_deg:g} deg of vertical, invisible to gravity: "
                "skipped"
            )
            continue
        # Channel i sees the rotation vector's component along i: the angle times the axis's
        # i-th component (1 for a turn exactly about the axis; the paper assumes that).
        per_axis[i].append((turn, x[i], T, sign * angle * abs(axis[i])))
    rotations = []
    for i in range(3):
        rows = per_axis[i]
        if len(rows) < (2 if solver == "static" else 3):
            raise DesignError(
                f"{where}: {len(rows)} usable rotation(s) about {AXES[i]}; the {solver} "
                f"approach needs {'2' if solver == 'static' else '3'} or more per axis (the "
                f"paper turns 18 times per axis; {AXES[i]} turns need {AXES[i]} horizontal)"
                + (
                    f"; {oblique} turn(s) not about one sensor axis were left out: "
                    '[gyro] solver = "full" takes any turn'
                    if oblique
                    else ""
                )
            )
        x = np.array([r[1] for r in rows])
        T = np.array([r[2] for r in rows])
        ang = _unwrap(np.array([r[3] for r in rows]), x - bias_still[i] * T)
        if solver == "static":
            fit = gyro_axes.fit_axis_static(x, T, ang, bias_still[i], b_still_std)
        else:
            fit = gyro_axes.fit_axis_dynamic(x, T, ang)
        k[i], b[i], k_std[i], b_std[i] = fit.k, fit.b, fit.k_std, fit.b_std
        for (turn, xi, Ti, ai), res in zip(rows, fit.residuals_rad, strict=True):
            rotations.append({
                "segment": turn.segment.name, "label": turn.segment.label, "axis": AXES[i],
                "known_angle_deg": float(np.degrees(ai)),
                "measured_angle_deg": float(np.degrees(fit.k * (xi - fit.b * Ti))),
                "angle_error_deg": float(np.degrees(-res)),
            })  # fmt: skip
    return k, b, k_std, b_std, rotations


def _unwrap(angle: np.ndarray, integral: np.ndarray) -> np.ndarray:
    """Gravity gives each angle only modulo 360 degrees: a turn of 179 degrees may read -181.
    Take the branch nearest the gyro's own estimate (a rough scale from the turns clear of
    +-180 degrees times each turn's bias-free integral)."""
    clear = np.abs(angle) < np.radians(150)
    if not clear.any():
        return angle
    k = np.median(angle[clear] / integral[clear])
    return angle + 2 * np.pi * np.round((k * integral - angle) / (2 * np.pi))


def _full_problem(session, stills, turns) -> tuple[gyro_full.Rotations, gyro_full.Stills]:
    rot = gyro_full.Rotations(
        t=[session.time[t.segment.start : t.segment.stop] for t in turns],
        z=[session.gyro[t.segment.start : t.segment.stop] for t in turns],
        before=np.array([t.before for t in turns]),
        after=np.array([t.after for t in turns]),
    )
    st = gyro_full.Stills(
        g=np.array([s.g for s in stills]),
        g_sigma=np.array([s.g_sigma for s in stills]),
        z_mean=np.array([s.z_mean for s in stills]),
        z_sigma=np.array([max(s.z_sigma, 1e-12) for s in stills]),
    )
    return rot, st


def full_problem(session: Session, cfg: Config, accel_cal: SensorCalibration):
    """The full model's data for a session, as :func:`calibrate_gyro_rotations` builds it:
    ``(Rotations, Stills, per-sample gyro noise)`` (for the Cramér-Rao bound of a design)."""
    session, _ = with_segments(session)
    stills, turns, _, _ = _stills_and_turns(session, accel_cal, cfg, session_name(session))
    z = np.vstack([session.gyro[s.segment.start : s.segment.stop] for s in stills])
    rot, st = _full_problem(session, stills, turns)
    return rot, st, float(np.sqrt(np.mean(np.var(z, axis=0))))


def gyro_checks(session, cfg, gains, units) -> list[str]:
    """Sensitivities far from nominal (units or config)."""
    nominal = cfg.gyro.nominal_sensitivity or {"rad/s": 1.0, "deg/s": 180 / np.pi}.get(
        session.gyro_units or ""
    )
    if nominal is None:
        ref, what = np.median(gains), "the median of the three axes"
    else:
        ref, what = nominal, "nominal"
    out = []
    for a, gval in zip(AXES, gains, strict=True):
        if abs(gval / ref - 1) > cfg.gyro.max_scale_error:
            out.append(
                f"gyro {a} sensitivity {gval:.6g} {units} per rad/s is "
                f"{100 * (gval / ref - 1):+.0f}% from {what} ({ref:.6g})"
            )
    return out
