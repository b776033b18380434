"""Session data shared by every solver step: per-pose statistics, the nominal sensor an
uncalibrated user would assume, design checks and physical-sense checks."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal_cli.errors import DesignError
from imucal_cli.formats.config import Config, per_channel
from imucal_cli.formats.session import Segment, Session
from imucal_cli.solvers.poses import count_distinct, describe_direction, spread_deg, unit

#: Every pose within this angle of one direction cannot separate bias from scale.
MIN_SPREAD_DEG = 20.0
#: Sensor range assumed for SI-unit data when the config gives none: +-16 g.
SI_RANGE_G = 16.0


@dataclass
class StaticPoses:
    """Per-pose statistics of the static segments of a session.

    Attributes
    ----------
    segments : list of Segment
    a_mean : ndarray, shape (N, na)
        Mean raw accelerometer reading per pose, raw units.
    cov_mean : ndarray, shape (N, na, na)
        Covariance of each mean (sample covariance / samples), raw units^2.
    up : ndarray, shape (N, 3)
        Labelled up directions, NaN rows where unlabelled.
    samples : ndarray of int, shape (N,)
    """

    segments: list[Segment]
    a_mean: np.ndarray
    cov_mean: np.ndarray
    up: np.ndarray
    samples: np.ndarray


def static_poses(session: Session) -> StaticPoses:
    """Mean and covariance of the accelerometer over each static segment."""
    segs = session.static_segments()
    if not segs or session.accel is None:
        raise DesignError(
            f"{session_name(session)}: no static segments with accelerometer data; "
            "capture poses held still (e.g. `imucal capture --plan qureshi18`)"
        )
    na = session.accel.shape[1]
    a_mean = np.empty((len(segs), na))
    cov_mean = np.zeros((len(segs), na, na))
    up = np.full((len(segs), 3), np.nan)
    samples = np.empty(len(segs), dtype=int)
    for k, s in enumerate(segs):
        block = session.accel[s.start : s.stop]
        n = len(block)
        samples[k] = n
        a_mean[k] = block.mean(axis=0)
        if n > 1:
            cov_mean[k] = np.cov(block, rowvar=False) / n
        if s.up is not None:
            up[k] = s.up
    return StaticPoses(segs, a_mean, cov_mean, up, samples)


# --------------------------------------------------------------------------- nominal sensor


@dataclass
class Nominal:
    """What an uncalibrated user would assume: datasheet sensitivity and zero-g offset."""

    sensitivity: float | None  # raw units per m/s^2; None when unknown
    bias: np.ndarray  # raw units (n,)
    range: tuple[float, float] | None  # raw output range
    basis: str  # words for the report
    notes: list[str] = field(default_factory=list)


def adc_range(data_min: float, data_max: float) -> tuple[float, float] | None:
    """The smallest standard ADC word (signed or unsigned) that holds the data."""
    for bits in (8, 10, 12, 14, 16, 18, 20, 24, 32):
        if data_min >= 0 and data_max <= 2**bits - 1:
            return 0.0, float(2**bits - 1)
        if -(2 ** (bits - 1)) <= data_min and data_max <= 2 ** (bits - 1) - 1:
            return float(-(2 ** (bits - 1))), float(2 ** (bits - 1) - 1)
    return None


def nominal_sensor(session: Session, cfg: Config, g: float) -> Nominal:
    """Nominal sensitivity, bias and range from the config, else from the units and data."""
    a = cfg.accel
    units = session.accel_units or "unknown units"
    accel = session.accel
    n = accel.shape[1]
    sens = a.nominal_sensitivity
    rng = tuple(a.range) if a.range else None
    if sens is None:
        sens = {"m/s^2": 1.0, "g": 1.0 / g}.get(units)
    if rng is None:
        if units in ("m/s^2", "g"):
            full = SI_RANGE_G * (g if units == "m/s^2" else 1.0)
            rng = (-full, full)
        elif units == "counts":
            finite = accel[np.isfinite(accel).all(axis=1)]
            rng = adc_range(float(finite.min()), float(finite.max())) if len(finite) else None
    if a.nominal_bias is not None:
        bias = np.array(per_channel(a.nominal_bias, n, "accel.nominal_bias"))
    elif rng is not None and rng[0] == 0.0 and units == "counts":
        bias = np.full(n, (rng[1] + 1) / 2)  # unsigned ADC: zero-g at mid-scale
    else:
        bias = np.zeros(n)
    if sens is not None:
        basis = f"nominal sensitivity {sens:.6g} {units} per m/s^2, offset {fmt_bias(bias)} {units}"
    else:
        basis = f"one scale fitted to the raw magnitudes, offset {fmt_bias(bias)} {units}"
    return Nominal(sens, bias, rng, basis)


def fmt_bias(b: np.ndarray) -> str:
    return "0" if not np.any(b) else "[" + ", ".join(f"{v:.6g}" for v in b) + "]"


# --------------------------------------------------------------------------- design checks


def check_design(
    poses: StaticPoses, nominal: Nominal, min_separation_deg: float, where: str
) -> None:
    """Refuse poses that cannot determine a triad's 9 parameters, with advice."""
    N = len(poses.a_mean)
    centre = nominal.bias
    if nominal.sensitivity is None and nominal.range is None:
        # No idea of the offset: the middle of what was seen on each axis.
        centre = (poses.a_mean.min(axis=0) + poses.a_mean.max(axis=0)) / 2
    directions = unit(poses.a_mean - centre)
    distinct = count_distinct(directions, min_separation_deg)
    if distinct < 9:
        raise DesignError(
            f"{where}: {N} static poses give only {distinct} distinct gravity directions "
            f"(>{min_separation_deg:g} deg apart); the 9-parameter model needs at least 9: "
            "capture the 6 faces and the 45-degree edges (plan qureshi18)"
        )
    spread = spread_deg(directions)
    if spread <= MIN_SPREAD_DEG:
        mean_dir = describe_direction(directions.sum(axis=0))
        raise DesignError(
            f"{where}: every pose is within {spread:.0f} deg of {mean_dir} up, which cannot "
            "separate bias from scale; turn the unit over: capture each face up, then the edges"
        )


def physical_checks(
    bias: np.ndarray,
    gains: np.ndarray,
    rms: float,
    nominal: Nominal,
    cfg: Config,
    units: str,
    g: float,
) -> list[str]:
    """Warnings for results outside physical sense: sensitivities far from nominal, a bias
    outside the sensor's range, poses that disagree on |g| after calibration."""
    warnings = []
    limit = cfg.accel.max_scale_error
    names = channel_names(len(gains))
    if nominal.sensitivity is not None:
        ref, what = np.full(len(gains), nominal.sensitivity), "nominal"
    else:
        ref, what = np.full(len(gains), np.median(gains)), "the median of the channels"
    for axis, gain, r in zip(names, gains, ref, strict=True):
        if abs(gain / r - 1) > limit:
            warnings.append(
                f"{axis} sensitivity {gain:.6g} {units} per m/s^2 is {100 * (gain / r - 1):+.0f}% "
                f"from {what} ({r:.6g}); more than {100 * limit:.0f}% is not a working part or "
                "the units are wrong"
            )
    if nominal.range is not None:
        lo, hi = nominal.range
        for axis, b in zip(names, bias, strict=True):
            if not lo <= b <= hi:
                warnings.append(
                    f"{axis} bias {b:.6g} {units} lies outside the sensor's range "
                    f"[{lo:.6g}, {hi:.6g}]"
                )
    if rms > 0.05 * g:
        warnings.append(
            f"the poses do not agree on one gravity magnitude even after calibration (RMS "
            f"{rms:.3g} m/s^2): was the unit moving during the holds?"
        )
    return warnings


def channel_names(n: int) -> list[str]:
    """``x, y, z`` for a triad, ``1 .. n`` for a redundant unit."""
    return list("xyz") if n == 3 else [str(i + 1) for i in range(n)]


def rms(x) -> float:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if len(x) else float("nan")


def num(x) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def session_name(session: Session) -> str:
    return str(session.path) if session.path is not None else "session"


def with_segments(session: Session) -> tuple[Session, str | None]:
    """The session itself, or, when it has no segments at all (a continuous recording of hold,
    turn, hold, ...), a copy segmented here: still periods and the motions between them,
    thresholds from the data's own noise. Returns a note saying so, or None."""
    if session.segments or session.accel is None:
        return session, None
    from dataclasses import replace

    from imucal_cli.formats.session import Segment
    from imucal_cli.solvers.segmentation import find_rotations, find_static

    still = find_static(session.time, session.accel, session.gyro)
    segs = [Segment(f"{i:04d}", "static", iv.start, iv.stop) for i, iv in enumerate(still)]
    if session.gyro is not None:
        moves = find_rotations(session.time, session.gyro, still)
        segs += [Segment("", "rotation", iv.start, iv.stop) for iv in moves]
    segs.sort(key=lambda s: s.start)
    segs = [replace(s, name=f"{i:04d}") for i, s in enumerate(segs)]
    note = (
        f"the session had no segments: {len(still)} still periods and "
        f"{len(segs) - len(still)} motions found in the stream"
    )
    return replace(session, segments=segs), note
