"""Session data shared by every solver step: per-pose statistics, the nominal sensor an
uncalibrated user would assume, design checks and physical-sense checks."""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace

import numpy as np

from imucal_cli.design import holds
from imucal_cli.design.holds import PooledNoise
from imucal_cli.design.poses import count_distinct, describe_direction, spread_deg, unit
from imucal_cli.design.segmentation import find_rotations, find_static
from imucal_cli.errors import DesignError
from imucal_cli.formats.config import Config, per_channel
from imucal_cli.formats.session import Segment, Session
from imucal_cli.numerics.quantisation import hold_rounding

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
        Mean raw accelerometer reading per pose (spike samples left out), raw units.
    cov_mean : ndarray, shape (N, na, na)
        Covariance of each mean: the pooled per-sample noise over the samples used
        (``noise.cov / samples``), raw units^2 (issue 10.7).
    up : ndarray, shape (N, 3)
        Labelled up directions, NaN rows where unlabelled.
    samples : ndarray of int, shape (N,)
        Samples in each mean (spikes left out).
    noise : PooledNoise
        Per-sample noise pooled over the still holds (holds that moved left out).
    spikes : ndarray of int, shape (N,)
        Spike samples left out of each mean.
    moved : ndarray of bool, shape (N,)
        Holds with a significant trend (the unit moved slowly while "still").
    drift : ndarray, shape (N, na)
        Fitted change over each hold, raw units.
    """

    segments: list[Segment]
    a_mean: np.ndarray
    cov_mean: np.ndarray
    up: np.ndarray
    samples: np.ndarray
    noise: PooledNoise | None = None
    spikes: np.ndarray | None = None
    moved: np.ndarray | None = None
    drift: np.ndarray | None = None

    def subset(self, keep: np.ndarray) -> StaticPoses:
        """The poses selected by a boolean mask or index array (noise estimate kept)."""
        idx = np.flatnonzero(keep) if np.asarray(keep).dtype == bool else np.asarray(keep)
        pick = lambda a: None if a is None else a[idx]  # noqa: E731
        return StaticPoses(
            [self.segments[i] for i in idx],
            self.a_mean[idx],
            self.cov_mean[idx],
            self.up[idx],
            self.samples[idx],
            self.noise,
            pick(self.spikes),
            pick(self.moved),
            pick(self.drift),
        )


def static_poses(session: Session) -> StaticPoses:
    """Mean of the accelerometer over each static segment, with pooled noise and hold checks.

    Spike samples (robust z-score against the pooled noise) are left out of the means; each
    hold is tested for slow motion (a trend over time); the per-sample noise is pooled over
    the holds that did not move, so every pose mean gets ``Sigma / n_k`` (issue 10.7).
    """
    segs = session.static_segments()
    if not segs or session.accel is None:
        raise DesignError(
            f"{session_name(session)}: no static segments with accelerometer data; "
            "capture poses held still (e.g. `imucal capture --plan qureshi18`)"
        )
    blocks = [session.accel[s.start : s.stop] for s in segs]
    times = [session.time[s.start : s.stop] for s in segs]
    na = session.accel.shape[1]
    step = holds.quantum(np.concatenate(blocks[: min(len(blocks), 50)]))
    # Robust per-sample sigma (median absolute deviation, pooled by the median over holds)
    # to find spikes before the covariance is pooled.
    medians, mad = holds.medians_and_spread(blocks)
    sigma0 = np.maximum(1.4826 * np.median(mad, axis=0), max(step, 1e-12))
    n_total = sum(len(b) for b in blocks)
    masks = [holds.spike_mask(b, sigma0, n_total, m) for b, m in zip(blocks, medians, strict=True)]
    # A hold that drifts (the unit tilting slowly) puts its ends far from its median: those
    # samples are motion, not spikes; the trend test below flags the hold instead.
    cov0 = np.diag(sigma0**2)
    for k, (t, b, m) in enumerate(zip(times, blocks, masks, strict=True)):
        if m.sum() > 2 and holds.trend(t, b, cov0, len(segs)).moved:
            masks[k] = np.zeros(len(b), bool)
    # Spike-free holds (most) are used as they are, not copied.
    keep = [None if not m.any() or (~m).sum() < 2 else ~m for m in masks]
    clean = [b if k is None else b[k] for b, k in zip(blocks, keep, strict=True)]
    ctimes = [t if k is None else t[k] for t, k in zip(times, keep, strict=True)]
    means = [b.mean(axis=0) for b in clean]  # each hold's mean, used thrice
    noise = holds.pooled_noise(clean, step, means)
    trends = holds.trends(ctimes, clean, noise.cov, len(segs), means=means)
    moved = np.array([tr.moved for tr in trends])
    if moved.any() and not moved.all():
        still = np.flatnonzero(~moved)
        noise = holds.pooled_noise([clean[k] for k in still], step, [means[k] for k in still])
    samples = np.array([len(b) for b in clean], dtype=int)
    a_mean = np.array(means).reshape(len(segs), na)
    cov_mean = noise.cov[None, :, :] / samples[:, None, None] + np.diag(
        _rounding(session.accel, clean, noise.cov))[None]
    up = np.full((len(segs), 3), np.nan)
    for k, s in enumerate(segs):
        if s.up is not None:
            up[k] = s.up
    spikes = np.array([len(b) - len(c) for b, c in zip(blocks, clean, strict=True)], dtype=int)
    drift = np.array([tr.change for tr in trends]).reshape(len(segs), na)
    return StaticPoses(segs, a_mean, cov_mean, up, samples, noise, spikes, moved, drift)


def _rounding(raw: np.ndarray, clean: list[np.ndarray], cov: np.ndarray) -> np.ndarray:
    """Per channel, the variance of a hold mean's rounding error that its samples do not
    average away: a quantised sensor too quiet to dither its rounding (noise below half a
    count; :mod:`imucal_cli.numerics.quantisation`), 0 otherwise.  The step from the whole
    record (the moves sweep the codes), the noise from each channel's codes in the holds."""
    q = holds.record_quantum(raw)
    return np.array([hold_rounding([b[:, [c]] for b in clean], q, float(np.sqrt(cov[c, c])))[1]
                     for c in range(cov.shape[0])])  # fmt: skip


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


def infer_accel_units(accel: np.ndarray, g: float) -> str | None:
    """The raw units an accelerometer's readings are plausibly in, from their magnitude
    (issue 10.4): ``"m/s^2"`` when |a| is near g, ``"g"`` near 1, ``"counts"`` for integer
    readings or magnitudes far above g; None when nothing fits."""
    finite = accel[np.isfinite(accel).all(axis=1)]
    if not len(finite) or accel.shape[1] != 3:
        return None
    mag = float(np.median(np.linalg.norm(finite, axis=1)))
    if 0.7 * g < mag < 1.3 * g:
        return "m/s^2"
    if 0.7 < mag < 1.3:
        return "g"
    sample = finite[:: max(1, len(finite) // 2000)]
    if mag > 3 * g or np.all(sample == np.round(sample)):
        return "counts"
    return None


def accel_units(session: Session, g: float) -> tuple[str, str | None]:
    """The accelerometer's raw units and, when the session does not state them, a note saying
    what was assumed from the magnitude and how to state them (issue 10.4)."""
    if session.accel_units:
        return session.accel_units, None
    how = (
        "state them with `imucal label SESSION --accel-units UNITS` (or --accel-units at "
        "import/capture)"
    )
    guess = infer_accel_units(session.accel, g)
    if guess is None:
        return "raw units", f"the session does not state the accelerometer units; {how}"
    finite = session.accel[np.isfinite(session.accel).all(axis=1)]
    mag = float(np.median(np.linalg.norm(finite, axis=1)))
    return guess, (
        f"the session does not state the accelerometer units: |a| at rest is about {mag:.4g}, "
        f"so they are taken as {guess}; {how}"
    )


def nominal_sensor(session: Session, cfg: Config, g: float) -> Nominal:
    """Nominal sensitivity, bias and range from the config, else from the units and data."""
    a = cfg.accel
    units = accel_units(session, g)[0]
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
        elif units == "counts":  # the finite rows copied only when some are not
            finite = accel if np.isfinite(accel).all() else accel[np.isfinite(accel).all(axis=1)]
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
    poses: StaticPoses,
    nominal: Nominal,
    min_separation_deg: float,
    where: str,
    model: str = "9",
) -> None:
    """Refuse poses that cannot determine a triad's gravity-magnitude model, naming the model
    (``"9"`` or ``"12"``) and what would work with what the session already has."""
    N = len(poses.a_mean)
    centre = nominal.bias
    if nominal.sensitivity is None and nominal.range is None:
        # No idea of the offset: the middle of what was seen on each axis.
        centre = (poses.a_mean.min(axis=0) + poses.a_mean.max(axis=0)) / 2
    directions = unit(poses.a_mean - centre)
    distinct = count_distinct(directions, min_separation_deg)
    name = (
        "the 9-parameter gravity-magnitude model"
        if model == "9"
        else "the 12-parameter gravity model (9 parameters from the magnitudes, the rotation "
        "from the labels)"
    )
    if distinct < 9:
        raise DesignError(
            f"{where}: {N} static poses give only {distinct} distinct gravity directions "
            f"(>{min_separation_deg:g} deg apart); {name} needs at least 9"
            + _what_would_work(poses, directions)
        )
    spread = spread_deg(directions)
    if spread <= MIN_SPREAD_DEG:
        mean_dir = describe_direction(directions.sum(axis=0))
        raise DesignError(
            f"{where}: every pose is within {spread:.0f} deg of {mean_dir} up, which cannot "
            "separate bias from scale; turn the unit over: capture each face up, then the edges"
        )


def labels_determine(up: np.ndarray) -> bool:
    """Whether labelled up directions can separate bias from sensitivity: at least four
    labels not in one plane (``[1, up_k]`` of rank 4)."""
    lab = np.isfinite(up).all(axis=1)
    if lab.sum() < 4:
        return False
    X = np.column_stack([np.ones(lab.sum()), up[lab]])
    return bool(np.linalg.matrix_rank(X, tol=1e-6) == 4)


def _what_would_work(poses: StaticPoses, directions: np.ndarray) -> str:
    """What would calibrate these poses, before a new capture (issue 9.6)."""
    if labels_determine(poses.up):
        return (
            "; these poses carry `up` labels, which the labelled-pose solver uses: "
            '[accel] solver = "labelled" (or the default "auto"), or capture the 45-degree '
            "edges too (plan qureshi18)"
        )
    near = int(np.sum(np.max(np.abs(directions), axis=1) > np.cos(np.radians(15.0))))
    if near >= 4:
        return (
            f"; {near} poses lie within 15 deg of a face: label them (`imucal label SESSION "
            '--faces`) and the labelled-pose solver ([accel] solver = "auto") calibrates them, '
            "or capture the 45-degree edges too (plan qureshi18)"
        )
    return ": capture the 6 faces and the 45-degree edges (plan qureshi18)"


def stored_accel_hint(session: Session) -> str:
    """A pointer to an accelerometer calibration already stored in the session, or ''."""

    for name in sorted(session.calibrations, reverse=True):
        try:
            accel = json.loads(session.calibrations[name]).get("accel")
        except (ValueError, AttributeError):
            continue
        if isinstance(accel, dict):
            solver = accel.get("solver", "an earlier")
            return (
                f"; this session already stores an accelerometer calibration "
                f"(/calibrations/{name}, {solver} solver): `imucal report SESSION` shows it"
            )
    return ""


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
