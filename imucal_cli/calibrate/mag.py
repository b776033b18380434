"""The magnetometer step: readings of a session -> hard iron, soft iron and the rotation onto the
accelerometer frame (:mod:`imucal_cli.estimators.mag.magnetometer`) -> the ``mag`` section, with
uncertainties, MotionCal-style quality figures, and refusals that say what to do.

Readings: every finite magnetometer row, less the clipped ones (the configured range, or a
channel stuck at its extreme while the unit moved) and, when the magnetometer was read faster
than it updates (more than :data:`HOLD_REPEATS` of the motion rows repeat the previous one
exactly), less the repeats: they are not new information.
Static segments give pose means (noise from their own spread, pooled into the per-sample
noise) and, with the accelerometer calibrated in the same run, their up directions; every
other row is a motion reading.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, replace

import numpy as np

from imucal_cli.calibrate.accel.section import fit_fields, parameter_rows
from imucal_cli.calibrate.common import num, rms, session_name
from imucal_cli.calibrate.mag_poses import accel_factor, changed_rows, pose_data
from imucal_cli.calibrate.registry import Determined, Needs, Refusal, register
from imucal_cli.design.clipping import clipped_rows
from imucal_cli.design.poses import describe_direction
from imucal_cli.design.sphere_quality import region_centres, sphere_quality, suggest_direction
from imucal_cli.errors import DesignError, SolverError
from imucal_cli.estimators.mag import magnetometer as mag_solver
from imucal_cli.estimators.mag.extrapolation import magnitude_std
from imucal_cli.formats.config import Config, MagConfig
from imucal_cli.formats.session import UT_PER_MAG_UNIT, Session
from imucal_cli.model.calibration import LOCAL_FIELD, MODEL_EQUATION, SensorCalibration
from imucal_cli.model.codec import build
from imucal_cli.model.mag import (
    MagCalibration,
    MagCoverage,
    MagPoseRow,
    Quality,
    QualityCheck,
    Readings,
    RowsLeftOut,
)

#: Folds of the held-out fit error: readings alternate between them in blocks of this length.
FOLD_BLOCK_S = 1.0
#: A mean soft-iron gain further than this from 1 (physical units, known field) is suspect.
MAX_GAIN_ERROR = 0.30
#: The Earth's field at its surface, uT (the WMM: about 22 in the South Atlantic anomaly, 67
#: near the south magnetic pole): a field outside it is most likely a unit slip.
EARTH_FIELD_UT = (20.0, 70.0)
#: ``[mag] field_uT`` and the session's ``magnetic_field_uT`` further apart than this fraction:
#: one of them is wrong (issue 24.7).
MAX_FIELD_MISMATCH = 0.10
#: Fraction of exact repeats among motion rows above which the magnetometer is taken to be read
#: faster than it updates (sample and hold): repeats are then left out everywhere.
HOLD_REPEATS = 0.2
#: Calibrated directions kept in the section for the coverage map.
MAP_DIRECTIONS = 400


@dataclass
class MagReadings:
    """What :func:`mag_readings` extracted from a session.

    Attributes
    ----------
    data : MagData
        The solver's input (motion readings, pose means, noise, up directions).
    sample_rows : ndarray of int
        Session rows of the motion readings.
    segments : list of Segment
        The static segments that gave a pose, in ``data.pose_mean`` order.
    pose_samples : ndarray of int
        Distinct readings in each pose.
    dropped : dict
        Rows left out: ``nonfinite`` (of which ``before_first``: before the magnetometer's
        first value, as in a ROS import before its first message), ``clipped``, ``repeated``.
    clip_limits : (low, high) or None
        The range used for clipping, raw units.
    notes : list of str
        What the fit should say of its input (an accelerometer without a covariance).
    """

    data: mag_solver.MagData
    sample_rows: np.ndarray
    segments: list
    pose_samples: np.ndarray
    dropped: dict
    clip_limits: tuple[float, float] | None
    notes: list[str] = dataclasses.field(default_factory=list)


def mag_readings(
    session: Session, cfg: MagConfig, accel: SensorCalibration | None, where: str
) -> MagReadings:
    """Split a session's magnetometer rows into motion readings and static poses.

    Raises
    ------
    DesignError
        Fewer than 3 channels or more than 3, or more readings clipped than
        ``cfg.max_saturated_pct``.
    """
    mag = session.mag
    if mag.shape[1] != 3:
        raise DesignError(
            f"{where}: the magnetometer solver calibrates 3 channels; /raw/mag has "
            f"{mag.shape[1]}"
        )
    finite = np.isfinite(mag).all(axis=1)
    if not finite.any():
        raise DesignError(
            f"{where}: /raw/mag has no reading with a value (every row is NaN): the "
            "magnetometer sent nothing; check its topic, column or connection, or set [mag] "
            'solver = "none" to calibrate the rest without it'
        )
    limits = None if cfg.range is None else (float(cfg.range[0]), float(cfg.range[1]))
    clipped = clipped_rows(mag, limits)
    n_finite = int(finite.sum())
    if n_finite and 100.0 * clipped.sum() / n_finite > cfg.max_saturated_pct:
        raise DesignError(_saturation_message(mag, clipped, limits, n_finite, cfg, where))
    usable = finite & ~clipped
    in_static = np.zeros(len(mag), bool)
    for seg in session.static_segments():
        in_static[seg.start : seg.stop] = True
    all_motion = np.flatnonzero(usable & ~in_static)
    motion = changed_rows(all_motion, mag)
    held = len(all_motion) > 0 and 1.0 - len(motion) / len(all_motion) > HOLD_REPEATS
    if not held:
        motion = all_motion
    notes: list[str] = []
    factor = accel_factor(accel, notes) if cfg.align else None
    data, segments, counts = pose_data(session, mag, (motion, usable), held, accel, factor)
    dropped = {
        "nonfinite": int((~finite).sum()),
        "before_first": int(np.argmax(finite)),
        "clipped": int(clipped.sum()),
        "repeated": int(len(all_motion) - len(motion)),
    }
    return MagReadings(data, motion, segments, counts, dropped, limits, notes)


def _saturation_message(mag, clipped, limits, n_finite, cfg, where) -> str:
    pct = 100.0 * clipped.sum() / n_finite
    channels = [("x", "y", "z")[c] for c in range(3)
                if np.any(clipped & ((mag[:, c] == np.nanmax(mag[:, c]))
                                     | (mag[:, c] == np.nanmin(mag[:, c]))))]  # fmt: skip
    what = (
        f"reach the range [{limits[0]:g}, {limits[1]:g}]" if limits is not None
        else f"are stuck at the end of the range (channel {', '.join(channels) or '?'})"
    )  # fmt: skip
    return (
        f"{where}: {pct:.1f} % of the magnetometer readings {what} (at most "
        f"{cfg.max_saturated_pct:g} % allowed): the magnetometer saturates. A magnet or a "
        "magnetised tool near the unit, or a range setting too small for the board's own "
        "field: move away from magnets, motors and speakers, choose a larger range, and "
        "capture again"
    )


# --------------------------------------------------------------------------------------------
# The step
# --------------------------------------------------------------------------------------------


def _field(session: Session, cfg: MagConfig) -> tuple[float, str, str]:
    """``(F, units, source)``: the field magnitude the output should have."""
    if cfg.field_uT is not None:
        return float(cfg.field_uT), "uT", "config [mag] field_uT"
    if session.magnetic_field_uT is not None:
        return float(session.magnetic_field_uT), "uT", "session magnetic_field_uT"
    return 1.0, LOCAL_FIELD, "unknown (no [mag] field_uT, no magnetic_field_uT in the session)"


def calibrate_mag(
    session: Session, cfg: Config, accel: SensorCalibration | None
) -> MagCalibration:
    """Calibrate a session's magnetometer (``[mag]`` config); the accelerometer calibrated in
    the same run (or None) gives the static poses' up directions for the alignment.

    Raises
    ------
    DesignError
        Readings that cannot determine the model: too few, in one plane, too little of the
        sphere covered, or too many clipped (the message says what to capture).
    SolverError
        No convergence.
    """
    where = session_name(session)
    mcfg = cfg.mag
    if session.mag is None:
        raise DesignError(f"{where}: no /raw/mag in this session")
    units_in = session.mag_units or "unknown"
    field, units, field_source = _field(session, mcfg)
    readings = mag_readings(session, mcfg, accel, where)
    data = readings.data
    if mcfg.solver == "ellipsoid":
        res = mag_solver.fit_plain_ellipsoid(data, field)
    else:
        res = mag_solver.fit_magnetometer(
            data, field, align=mcfg.align and accel is not None,
            max_iterations=mcfg.max_iterations,
        )  # fmt: skip
    if mcfg.solver == "ellipsoid":
        res.notes.append("plain algebraic ellipsoid fit: symmetric soft iron, not aligned, "
                         "not weighted (what the hobby tools do)")  # fmt: skip
    elif not mcfg.align:
        res.notes.append("not aligned to the accelerometer: [mag] align = false")
    elif accel is None:
        res.notes.append("not aligned to the accelerometer: no accelerometer calibrated in this "
                         "run (the static poses' gravity directions fix the rotation)")  # fmt: skip
    res.notes += _missing_note(readings.dropped, len(session.mag))
    if res.aligned:
        res.notes += readings.notes
    calibrated = res.calibrate(data.points)
    quality = sphere_quality(calibrated)
    _check_coverage(quality, res, mcfg, where)
    held = _held_out(session, readings, res, field, mcfg)
    sigmas = mag_solver.residual_sigmas(res, data)
    warnings = _field_checks(session, readings, res, sigmas, mcfg)
    warnings += _gain_check(res, units, units_in, field)
    warnings += _stated_field_check(session, mcfg, field, units, field_source)
    warnings += [res.ambiguity] if getattr(res, "ambiguity", None) else []
    members = _section_members(session, readings, res, units_in, field, units, field_source)
    members.update({
        "quality": _quality_figures(quality, held, res, mcfg),
        "coverage": MagCoverage(
            fraction=quality.covered_fraction,
            gaps_pct=quality.gaps_pct,
            regions=100,
            n_readings=len(data.points),
            n_poses=len(data.pose_mean),
        ),
        "directions": _thinned(calibrated / np.linalg.norm(calibrated, axis=1, keepdims=True)),
        "rms_held_out": rms(held),
        "warnings": warnings,
    })  # fmt: skip
    return build(
        MagCalibration,
        solver="magnetometer" if mcfg.solver == "magnitude" else "mag-ellipsoid",
        units=units,
        bias=res.bias,
        matrix=res.matrix,
        residual_rms=rms(res.residuals),
        **members,
    )


def _missing_note(dropped: dict, n_rows: int) -> list[str]:
    """Say how many rows had no magnetometer value (left out), and how many of them came
    before its first value (a ROS import's rows before the first magnetometer message)."""
    n, first = dropped["nonfinite"], dropped["before_first"]
    if not n:
        return []
    text = f"{n} of {n_rows} rows have no magnetometer value and were left out"
    if first:
        text += (f" ({first} before its first value, e.g. before a recording's first "
                 "magnetometer message)" if first < n else
                 " (all before its first value, e.g. before a recording's first magnetometer "
                 "message)")  # fmt: skip
    return [text]


def _check_coverage(quality, res, cfg: MagConfig, where: str) -> None:
    """Refuse readings that cover too little of the sphere of field directions."""
    if quality.covered_fraction >= cfg.min_coverage:
        return
    gap = suggest_direction(quality.counts)
    side = describe_direction(gap) if gap is not None else "?"
    frame = "the unit's" if res.aligned else "the magnetometer's"
    toward = "magnetic north and down" if (res.inclination_deg or 1.0) >= 0 else "magnetic north"
    raise DesignError(
        f"{where}: the magnetometer saw the field from {100 * quality.covered_fraction:.0f} % "
        f"of the directions around it (at least {100 * cfg.min_coverage:.0f} % needed, "
        f"MotionCal gap figure {quality.gaps_pct:.0f} %); the largest gap is the field along "
        f"{frame} {side} side. Turn the unit through every direction (a slow figure-eight in "
        f"the air, then each face up), pointing its {side} side towards {toward}"
    )


def _held_out(session, readings: MagReadings, res, field: float, cfg: MagConfig) -> np.ndarray:
    """Held-out magnitude residuals (2 folds of alternating 1 s blocks), output units."""
    data = readings.data
    t = session.time[readings.sample_rows]
    folds_s = (np.floor((t - session.time[0]) / FOLD_BLOCK_S).astype(int) % 2
               if len(t) else np.zeros(0, int))  # fmt: skip
    folds_p = np.arange(len(data.pose_mean)) % 2
    try:
        return mag_solver.held_out_residuals(
            data, folds_s, folds_p, field, align=res.aligned, max_iterations=cfg.max_iterations
        )
    except (DesignError, SolverError):
        return np.full(len(data.points), np.nan)


def _field_checks(session, readings: MagReadings, res, sigmas, cfg: MagConfig) -> list[str]:
    """Warnings when the residuals show a field that changes: |B| off beyond the noise (over
    the whole recording, over any 1 s of motion, or in a hold), and a hold whose angle between
    gravity and the field is off."""
    out = []
    r, F = res.residuals, res.field
    var = sigmas**2 if np.isfinite(sigmas).all() else np.zeros(len(r))
    limit = cfg.max_field_change_pct
    overall = 100.0 * np.sqrt(max(float(np.mean(r * r - var)), 0.0)) / F
    worst_pct, where = _worst_stretch(session, readings, r, var, F)
    if max(overall, worst_pct) > limit:
        out.append(
            f"the field changes from place to place: |B| off by up to {worst_pct:.1f} % beyond "
            f"the noise{where} ({overall:.1f} % RMS overall; limit {limit:g} %). A magnet or "
            "steel near the unit (a desk frame, screws, a phone, a laptop, a motor): calibrate "
            "again at least 1 m away from them"
        )
    dip = res.dip_residuals_deg
    if np.isfinite(dip).any():
        k = int(np.nanargmax(np.abs(dip)))
        if abs(dip[k]) > cfg.max_dip_error_deg:
            seg = readings.segments[k]
            out.append(
                f"the angle between gravity and the field is {dip[k]:+.2f} deg off in the hold "
                f"{seg.label or seg.name} (limit {cfg.max_dip_error_deg:g} deg; "
                f"{rms(dip):.2f} deg RMS over the holds): the field's direction changes from "
                "place to place (steel nearby), or the unit moved during that hold"
            )
    return out


def _worst_stretch(session, readings: MagReadings, r, var, F) -> tuple[float, str]:
    """The largest |B| departure beyond the noise, % of F, over 1 s blocks of motion and over
    the holds, and words for where it is."""
    n = len(readings.sample_rows)
    worst, where = 0.0, ""
    if n:
        t = session.time[readings.sample_rows]
        block = np.floor((t - t[0]) / FOLD_BLOCK_S).astype(int)
        count = np.bincount(block)
        excess = np.bincount(block, weights=r[:n] ** 2 - var[:n]) / np.maximum(count, 1)
        excess[count < 10] = 0.0  # too few readings to say
        b = int(np.argmax(excess))
        worst = 100.0 * np.sqrt(max(excess[b], 0.0)) / F
        mean = float(np.mean(r[:n][block == b])) if count[b] else 0.0
        t0 = t[0] + b * FOLD_BLOCK_S
        where = f" at {t0:.0f}-{t0 + FOLD_BLOCK_S:.0f} s (|B| {'high' if mean >= 0 else 'low'})"
    rp = r[n:]
    if len(rp):
        k = int(np.argmax(np.abs(rp)))
        pct = 100.0 * abs(rp[k]) / F
        if pct > worst:
            seg = readings.segments[k]
            worst, where = pct, f" in the hold {seg.label or seg.name}"
    return worst, where


def _gain_check(res, units: str, units_in: str, field: float) -> list[str]:
    """A mean gain far from 1 with physical raw units and a known field: wrong units?"""
    if units != "uT" or units_in not in UT_PER_MAG_UNIT:
        return []
    gain = float(np.cbrt(abs(np.linalg.det(res.matrix)))) / UT_PER_MAG_UNIT[units_in]
    if abs(gain - 1.0) <= MAX_GAIN_ERROR:
        return []
    return [
        f"the soft-iron matrix scales readings by {gain:.3g} on average (a working part in "
        f"{units_in} needs about 1, within {100 * MAX_GAIN_ERROR:.0f} %): are mag_units "
        f"({units_in}) and the field ({field:g} uT) right?"
    ]


def _stated_field_check(session: Session, cfg: MagConfig, field: float, units: str,
                        source: str) -> list[str]:  # fmt: skip
    """The field magnitude the output is scaled to, checked (issue 24.7): ``[mag] field_uT``
    against the session's ``magnetic_field_uT``, and either against the Earth's surface field
    (:data:`EARTH_FIELD_UT`). Each finding is a warning, which stops the save without
    ``--force``: a field 100 times too large makes every calibrated reading 100 times so."""
    if units != "uT":
        return []
    out = []
    stated = session.magnetic_field_uT
    if cfg.field_uT is not None and stated is not None and stated > 0 and \
            abs(cfg.field_uT / stated - 1.0) > MAX_FIELD_MISMATCH:  # fmt: skip
        out.append(
            f"[mag] field_uT = {cfg.field_uT:g} uT is {cfg.field_uT / stated:.3g} times the "
            f"session's field ({stated:g} uT, magnetic_field_uT): the output would be scaled "
            "by it; check the units (uT: 1 gauss = 100 uT, 1 uT = 1000 nT) and the place, or "
            "leave field_uT out to use the session's"
        )
    lo, hi = EARTH_FIELD_UT
    if not lo <= field <= hi:
        out.append(
            f"the field magnitude {field:g} uT ({source}) is outside the Earth's field at its "
            f"surface ({lo:g} to {hi:g} uT): a unit slip (1 gauss = 100 uT, 1 uT = 1000 nT)? "
            "Give the local field in uT (a geomagnetic model such as the WMM for your place)"
        )
    return out


def _quality_figures(quality, held: np.ndarray, res, cfg: MagConfig) -> Quality:
    """MotionCal's four figures (percent), each against its limit, and the verdict. The gaps
    figure over its limit still passes when the fit states the field magnitude in the missed
    directions (:func:`_missed_pct`, 2 std) to no worse than the fit error it shows where it
    has readings: the missed part is then held by the rest (the gravity-aligned poses, or
    enough of the ellipsoid), not guessed."""
    F = res.field
    fit_error = 100.0 * rms(held) / F if np.isfinite(held).any() else float("nan")
    q = cfg.quality
    rows = [
        ("gaps", quality.gaps_pct, q.max_gaps_pct, "of the sphere not covered"),
        ("variance", quality.variance_pct, q.max_variance_pct, "spread of |B| around its mean"),
        ("wobble", quality.wobble_pct, q.max_wobble_pct, "sphere off centre or lopsided"),
        ("fit error", fit_error, q.max_fit_error_pct, "held-out |B| residual RMS"),
    ]
    checks = [
        QualityCheck(name=n, value_pct=num(v), limit_pct=float(lim), meaning=what,
                     ok=bool(np.isfinite(v) and v <= lim))
        for n, v, lim, what in rows
    ]  # fmt: skip
    gaps = checks[0]
    if not gaps.ok and np.isfinite(quality.gaps_pct) and np.isfinite(fit_error):
        missed = _missed_pct(quality, res)
        gaps.held_pct = num(missed)
        if missed <= fit_error:
            gaps.ok = True
            gaps.meaning = (f"of the sphere not covered; the fit holds |B| there to "
                            f"{missed:.2g} % (2 std), within the fit error")  # fmt: skip
    failed = [c.name for c in checks if not c.ok]
    return Quality(verdict="pass" if not failed else "recapture", failed=failed, checks=checks)


def _missed_pct(quality, res) -> float:
    """The largest 2-std error of the calibrated field magnitude the fit states in the regions
    of the sphere with fewer than 3 readings (MotionCal's regions, output frame), percent of
    the field (:func:`~imucal_cli.estimators.mag.extrapolation.magnitude_std`)."""
    missed = region_centres()[np.asarray(quality.counts) < 3]
    if not len(missed):
        return 0.0
    return float(200.0 * np.max(magnitude_std(res, missed)) / res.field)


def _axes_words(R: np.ndarray) -> list[str]:
    """Where each magnetometer axis points in the output frame: ``"x -> +Y (0.8 deg)"``."""
    out = []
    for j, name in enumerate("xyz"):
        col = R[:, j]
        i = int(np.argmax(np.abs(col)))
        off = float(np.degrees(np.arccos(np.clip(abs(col[i]), -1.0, 1.0))))
        out.append(f"{name} -> {'+' if col[i] >= 0 else '-'}{'XYZ'[i]} ({off:.1f} deg)")
    return out


def _section_members(session, readings: MagReadings, res, units_in, field, units, source
                     ) -> dict:  # fmt: skip
    """The members of the ``mag`` section beyond the standard ones (see DEVELOPERS.md), for
    :func:`~imucal_cli.model.codec.build`."""
    data = readings.data
    n_w = len(res.params) - 3 - (1 if res.aligned else 0)  # the dip s is told as an angle
    param_units = [units_in] * 3 + [f"{units} per {units_in}"] * n_w
    parameters = parameter_rows(res.param_names[: 3 + n_w], res.params[: 3 + n_w],
                                res.std[: 3 + n_w], param_units,
                                None if res.ci95 is None else res.ci95[: 3 + n_w])  # fmt: skip
    R, P = mag_solver.polar(res.matrix)
    axis_gains = np.linalg.eigvalsh(P)
    soft_pct = 100.0 * float(axis_gains[-1] / axis_gains[0] - 1.0)
    hard_out = res.matrix @ res.bias
    raw_mag = np.linalg.norm(data.points, axis=1)
    members = {
        "model": MODEL_EQUATION,
        "units_in": units_in,
        "field_uT": field if units == "uT" else None,
        "field_source": source,
        "parameters": parameters,
        "aligned": res.aligned,
        "frame": (
            "the accelerometer's calibrated frame (rotation from the constant angle between "
            "gravity and the field)" if res.aligned
            else "the magnetometer's own axes (symmetric soft-iron matrix)"
        ),
        "inclination_deg": res.inclination_deg,
        "inclination_std_deg": res.inclination_std_deg,
        "inclination_ci95_deg": res.inclination_ci95_deg,
        "rotation": R.tolist(),
        "rotation_std_deg": res.rotation_std_deg,
        "axes": _axes_words(R) if res.aligned else None,
        "hard_iron_out": hard_out.tolist(),
        "hard_iron_out_magnitude": float(np.linalg.norm(hard_out)),
        "soft_iron_axis_ratio_pct": soft_pct,
        "variance_before_pct": float(100.0 * raw_mag.std() / raw_mag.mean()),
        **fit_fields(res),
        "rms_after": rms(res.residuals),
        "dip_rms_deg": rms(res.dip_residuals_deg) if np.isfinite(res.dip_residuals_deg).any()
        else None,
        "readings": Readings(motion=len(data.samples), poses=len(data.pose_mean),
                             left_out=RowsLeftOut(**readings.dropped)),  # fmt: skip
        "notes": list(res.notes),
    }
    if units == LOCAL_FIELD and units_in in UT_PER_MAG_UNIT:
        det = abs(np.linalg.det(res.matrix))
        members["field_estimate_uT"] = float(UT_PER_MAG_UNIT[units_in] / np.cbrt(det))
        members["field_estimate_basis"] = (
            "raw units taken at face value and the soft iron keeping the mean gain "
            "(|det matrix| = 1 in uT)"
        )
    if readings.clip_limits is not None:
        members["range"] = list(readings.clip_limits)
    members["poses"] = _pose_rows(readings, res)
    return members


def _pose_rows(readings: MagReadings, res) -> list[MagPoseRow]:
    """Each static pose's row: samples averaged, its calibrated magnitude and residual (output
    units) and its dip residual (degrees)."""
    n = len(readings.data.samples)
    return [
        MagPoseRow(
            segment=seg.name,
            label=seg.label,
            samples=int(readings.pose_samples[k]),
            magnitude_after=float(res.residuals[n + k] + res.field),
            residual=float(res.residuals[n + k]),
            dip_residual_deg=num(res.dip_residuals_deg[k]),
        )
        for k, seg in enumerate(readings.segments)
    ]


def _thinned(directions: np.ndarray) -> list[list[float]]:
    """At most :data:`MAP_DIRECTIONS` directions, evenly spaced in the recording order."""
    idx = np.linspace(0, len(directions) - 1, min(MAP_DIRECTIONS, len(directions))).astype(int)
    return np.round(directions[idx], 4).tolist()


@dataclass
class MagDesign:
    """A session's magnetometer readings and the accelerometer that aligns them."""

    session: Session
    cfg: Config
    accel: SensorCalibration | None


@dataclass(frozen=True)
class MagEstimator:
    """The maximum-likelihood magnitude fit (``"magnitude"``: soft iron, hard iron, aligned
    to the accelerometer, eqs. 1-3) or the plain algebraic ellipsoid (``"ellipsoid"``)."""

    name: str = "magnitude"
    sensor: str = "mag"
    needs: Needs = Needs()

    def assess(self, design: MagDesign) -> Determined | Refusal:
        if design.session.mag is None:
            return Refusal("no /raw/mag in this session", "a session with the magnetometer")
        if self.name == "ellipsoid":
            return Determined("the plain algebraic ellipsoid (what the hobby tools do)", tier=1)
        return Determined("readings of the field from every direction: the magnitude fit")

    def fit(self, design: MagDesign) -> SensorCalibration:
        cfg = replace(design.cfg, mag=replace(design.cfg.mag, solver=self.name))
        return calibrate_mag(design.session, cfg, design.accel)


for _estimator in (MagEstimator(), MagEstimator("ellipsoid")):
    register(_estimator)
