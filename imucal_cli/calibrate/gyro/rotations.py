"""Gyroscope calibration from hand rotations and the calibrated accelerometer (issue 5).

Each rotation is turned between two still periods; the accelerometer, calibrated in the same
run, measures the gravity direction in both, and so how far the unit turned. Three solvers:

* ``static``  (Qureshi & Golnaraghi eq. 18): bias from the still periods, scale per axis;
* ``dynamic`` (eqs. 19-21): scale and bias per axis from the rotations alone;
* ``full``: 12 parameters (bias, scale and misalignment relative to the accelerometer frame),
  21 with the g-sensitivity, from arbitrary rotations, by integrating the gyro and matching
  the gravity direction.

This module finds the turns and the still periods around them, with noise pooled over all
still periods (issue 10.7), and builds the gyro section; the per-axis solvers are in
:mod:`.gyro_axes`, the full model in :mod:`.gyro_full`.

Rotation segments come from the session; where it has none, they are found in the stream
(motion between two still periods, thresholds from the data's own noise).
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from imucal_cli.calibrate.common import adc_range, rms, session_name, with_segments
from imucal_cli.calibrate.gyro.axes import fit_per_axis
from imucal_cli.calibrate.gyro.full import accel_derivative, fit_full_model, rotations_and_stills
from imucal_cli.calibrate.gyro.turn_windows import settle_turns
from imucal_cli.calibrate.gyro.turns import (
    AXES,
    MODEL_EQUATION_G,
    ClippedTurns,
    GyroData,
    Still,
    Turn,
)
from imucal_cli.design import holds
from imucal_cli.design.clipping import flat_top_levels
from imucal_cli.design.gaps import find_gaps, gaps_within
from imucal_cli.design.segmentation import find_rotations, find_static
from imucal_cli.errors import DesignError
from imucal_cli.estimators.accel.frame import frame_free
from imucal_cli.estimators.gyro.full import accel_sensitivity, full_information
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Segment, Session
from imucal_cli.model.calibration import MODEL_EQUATION, SensorCalibration
from imucal_cli.model.codec import build
from imucal_cli.model.gyro import GyroCalibration
from imucal_cli.numerics.quantisation import hold_rounding, rounding_covariance
from imucal_cli.numerics.segmented import moments_in_chunks, stacked_rows


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


def still_periods(session, accel_cal, cfg, statics) -> tuple[list[Still], float]:
    """Each still period's calibrated accel mean and raw gyro mean, with noise pooled over all
    of them (issue 10.7); and the pooled per-sample gyro noise, raw units.

    Without an accelerometer calibration (``accel_cal`` None: the known-angle solver with
    labelled axes) each period's ``g``, ``g_sigma`` and ``a_raw`` are NaN: only the gyro means
    and their noise are known. Many periods at once: their rows stacked end to end
    (:func:`moments_in_chunks`)."""
    g = cfg.gravity or session.gravity
    start = np.array([s.start for s in statics], dtype=np.int64)
    stop = np.array([s.stop for s in statics], dtype=np.int64)
    counts = stop - start
    z_means, z_ss = moments_in_chunks(session.gyro, start, stop)
    if accel_cal is not None:
        # The calibration is affine: the calibrated mean is the calibrated raw mean, and the
        # calibrated deviations are the raw ones times its matrix.
        raw_means, a_ss = moments_in_chunks(session.accel, start, stop,
                                            matrix=np.asarray(accel_cal.matrix, float))  # fmt: skip
        a_means = accel_cal.apply(raw_means)
        a_var = float(np.sum(a_ss.mean(axis=1)))
    else:
        a_means = raw_means = np.full((len(statics), 3), np.nan)
        a_var = 0.0
    # Pooled within-still variances (issue 10.7), per channel: a one-sample period adds 0.
    z_var = float(np.sum(z_ss.mean(axis=1)))
    dof = max(int(np.sum(counts - 1)), 1)
    a_sigma, z_sigma = np.sqrt(a_var / dof), np.sqrt(z_var / dof)
    # Each mean's noise from the pooled per-sample noise: one hold's few samples can make its
    # own estimate small by chance, and its weight too large (stated std below the bound).
    stills = [
        Still(s, am, max(a_sigma / (g * np.sqrt(n)), 1e-6) if accel_cal is not None else np.nan,
              zm, float(z_sigma / np.sqrt(n)), ar)
        for s, am, zm, n, ar in zip(statics, a_means, z_means, counts.tolist(), raw_means,
                                    strict=True)  # fmt: skip
    ]
    return stills, float(z_sigma)


def rounding(session, stills: list[Still], noise: float) -> tuple[float, np.ndarray | None]:
    """A quantised gyro's per-sample noise in a turn, and the covariance of the still means'
    rounding errors per channel (raw units; (3, P, P) raw units^2, None where nothing is
    rounded that the samples do not average).

    A gyro whose noise is below half a step reads nearly the same codes in every still
    period: each mean errs by the rounding of its true rate (the bias, the Earth's rate, any
    g-sensitivity), alike where the rates sit at one place within a count, which no number
    of samples or periods averages away (:mod:`imucal_cli.numerics.quantisation`: the noise
    before the rounding from the codes, the covariance from where the means sit).  The noise
    is one for the three channels: a still gyro's rates sit at one place within a count in
    every period, and a channel whose place shows two codes only cannot tell a small noise
    near a step's edge from a larger one further in (per channel, seed 100 of qureshi18 at
    0.28 counts gave 0.08), where places across the channels can.  In a turn the rate sweeps
    the codes and the rounding is white, ``q^2 / 12`` per sample beside that noise.
    Unquantised or dithered data: ``(noise, None)``.
    """
    q = holds.record_quantum(session.gyro)
    if q <= 0 or not stills:
        return noise, None
    blocks = [session.gyro[s.segment.start : s.segment.stop] for s in stills]
    sigma, v = hold_rounding(blocks, q, noise)
    moving = float(np.hypot(sigma, q / np.sqrt(12.0)))
    if v <= 0:
        return max(noise, moving), None
    means = np.array([s.z_mean for s in stills])
    cov = np.stack([rounding_covariance(means[:, c], sigma, q) for c in range(3)])
    return max(noise, moving), cov


def rounding_of_mean(cov: np.ndarray | None, counts: np.ndarray) -> float:
    """Variance of the count-weighted mean of the still means' rounding errors, the largest
    over the channels (0 without ``cov``: :func:`rounding`)."""
    if cov is None:
        return 0.0
    w = counts / counts.sum()
    return float(max(w @ cov[c] @ w for c in range(3)))


def turns_between(session, stills, turns, gap) -> tuple[list[Turn], list[str]]:
    """The turns with a still period right before and after, and the names of the others.

    For each turn: the last still period that ends by its first sample and the first that
    starts at its last. The samples between a still period and its turn (a person who held
    the pose longer than the capture needed, a pause before turning) are integrated with the
    turn when they are continuous (:func:`_continuous`, no other turn between): the turn's
    segment is extended to the still periods, so that any motion there is measured. A still
    period that cannot be reached so must end (start) within ``gap`` s of the turn, as the
    rule always was. All still periods are compared at once, in chunks of turns (memory
    bounded by :data:`PAIRS`).
    """
    time = session.time
    start = np.array([s.segment.start for s in stills], dtype=np.int64)
    stop = np.array([s.segment.stop for s in stills], dtype=np.int64)
    t_start, t_end = time[start], time[stop - 1]
    r_start = np.array([r.start for r in turns], dtype=np.int64)
    r_stop = np.array([r.stop for r in turns], dtype=np.int64)
    low, high = _other_turns(session, turns, r_start, r_stop)
    period = _mean_period(time)
    P = len(stills)
    before = np.full(len(turns), -1)
    after = np.full(len(turns), -1)
    reach = np.zeros((len(turns), 2), bool)
    step = max(1, PAIRS // max(P, 1))
    for i in range(0, len(turns) if P else 0, step):
        rs, re = r_start[i : i + step, None], r_stop[i : i + step, None]
        # (turns, stills): continuous samples reach the still period (integrated with the
        # turn), or it is within ``gap`` of the turn (the rule for what cannot be bridged)
        reach_b = (stop <= rs) & (stop >= low[i : i + step, None]) & _continuous(
            time, np.maximum(stop - 1, 0), rs, period)
        reach_a = (start >= re) & (start <= high[i : i + step, None]) & _continuous(
            time, re - 1, start, period)
        ok_before = (stop <= rs + 1) & (reach_b | (time[rs] - t_end <= gap))
        ok_after = (start >= re - 1) & (reach_a | (t_start - time[re - 1] <= gap))
        last_b = P - 1 - np.argmax(ok_before[:, ::-1], axis=1)
        before[i : i + step] = np.where(ok_before.any(axis=1), last_b, -1)
        after[i : i + step] = np.where(ok_after.any(axis=1), np.argmax(ok_after, axis=1), -1)
        rows = np.arange(len(rs))
        reach[i : i + step, 0] = reach_b[rows, before[i : i + step]]
        reach[i : i + step, 1] = reach_a[rows, after[i : i + step]]
    usable, skipped = [], []
    for k, (r, b, a) in enumerate(zip(turns, before.tolist(), after.tolist(), strict=True)):
        if b < 0 or a < 0:
            skipped.append(r.label or r.name)
            continue
        s0 = int(stop[b]) if reach[k, 0] else r.start
        s1 = int(start[a]) if reach[k, 1] else r.stop
        usable.append(Turn(r if (s0, s1) == (r.start, r.stop) else replace(r, start=s0, stop=s1),
                           b, a))  # fmt: skip
    return usable, skipped


def _mean_period(time: np.ndarray) -> float:
    """The session's sample period, s: the median over the recording of the mean step in
    :data:`PERIOD_WINDOW` samples (a host's read bursts and stalls average out within a
    window, and a hole in the data moves only the windows that hold it)."""
    w = min(PERIOD_WINDOW, len(time) - 1)
    if w < 1:
        return 0.0
    return float(np.median((time[w:] - time[:-w]) / w))


def _continuous(time: np.ndarray, a, b, period: float) -> np.ndarray:
    """Whether samples ``a`` .. ``b`` are continuous: their time span is at most
    :data:`HOLE_PERIODS` sample periods longer than their count makes it. A hole in the data
    (samples never received) stays in the span; a host that stamps lines as it reads them
    and stalled shows a late stamp and then a burst of early ones, which the span forgives."""
    return (time[b] - time[a]) - (b - a) * period <= HOLE_PERIODS * period


def _other_turns(session, turns, r_start: np.ndarray, r_stop: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """For each turn the end of the latest other turn before it (``low``, 0 when none) and the
    start of the next after it (``high``, N when none), of ``turns`` and of the session's
    rotation segments: a turn is not extended across another."""
    n = len(session.time)
    segments = list(turns) + list(getattr(session, "rotation_segments", list)())
    if not segments:
        return np.zeros(len(r_start), np.int64), np.full(len(r_start), n, np.int64)
    starts = np.sort(np.array([s.start for s in segments], dtype=np.int64))
    stops = np.sort(np.array([s.stop for s in segments], dtype=np.int64))
    k = np.searchsorted(stops, r_start, side="right") - 1
    low = np.where(k >= 0, stops[np.maximum(k, 0)], 0)
    k = np.searchsorted(starts, r_stop, side="left")
    high = np.where(k < len(starts), starts[np.minimum(k, len(starts) - 1)], n)
    return low, high


#: Samples between a still period and its turn whose time span exceeds their count by more than
#: this many sample periods have a hole (samples lost): the turn is not extended across it
#: (the unit may have moved unseen).
HOLE_PERIODS = 5.0
#: Samples over which a step is averaged for the sample period (:func:`_mean_period`).
PERIOD_WINDOW = 50


#: Turn-still pairs compared at once by :func:`turns_between`.
PAIRS = 1 << 18


def _stills_and_turns(session, accel_cal, cfg, where):
    statics, turns, source = _segments(session, where)
    stills, z_sigma = still_periods(session, accel_cal, cfg, statics)
    gap = cfg.gyro.rotations.max_gap_s
    usable, skipped = turns_between(session, stills, turns, gap)
    if not usable:
        raise DesignError(
            f"{where}: no rotation has still data right before and after it (within "
            f"{gap:g} s, or continuous samples between them): hold the unit still for a few "
            "seconds before and after every turn"
        )
    return stills, usable, skipped, source, z_sigma


def bridged_note(session, turns: list[Segment], usable: list[Turn]) -> list[str]:
    """Say how many turns were extended to their still periods (:func:`turns_between`)."""
    orig = {r.name: r for r in turns}
    added = [(orig[u.segment.name].start - u.segment.start,
              u.segment.stop - orig[u.segment.name].stop)
             for u in usable if u.segment.name in orig]  # fmt: skip
    added = [(a, b) for a, b in added if a or b]
    if not added:
        return []
    rate = session.sample_rate_hz or 1.0 / float(np.median(np.diff(session.time)))
    longest = max(a + b for a, b in added) / rate
    return [f"{len(added)} turn(s) extended through continuous samples to the still periods "
            f"around them (up to {longest:.1f} s: the unit held a pose longer than its segment, "
            "or paused before turning) and integrated whole"]  # fmt: skip


def _without_gaps(session: Session, turns: list[Turn], data) -> list[Turn]:
    """The turns whose samples have no gap (the rotation during missing samples is unknown:
    such a turn cannot be integrated); a warning names the others."""

    gaps = find_gaps(session.time)
    if not gaps:
        return turns
    kept, broken = [], []
    for t in turns:
        inside = gaps_within(gaps, t.segment.start, t.segment.stop)
        if inside:
            broken.append((t, max(inside, key=lambda g: g.length_s)))
        else:
            kept.append(t)
    if broken:
        said = ", ".join(f"{t.segment.name} ({g.length_s:.3g} s at {g.time_s:.6g} s)"
                         for t, g in broken[:5])  # fmt: skip
        text = (f"{len(broken)} rotation(s) have a gap in their samples, the turn unknown "
                f"across it: left out: {said}{' ...' if len(broken) > 5 else ''}")  # fmt: skip
        data.warnings.append(text)
        data.said.append(text)  # the fit of the other turns stands: said, not refused
    data.turns = kept
    return kept


def _clipped(session: Session, turns: list[Turn], limit: tuple[np.ndarray, np.ndarray] | None
             ) -> np.ndarray:  # fmt: skip
    """Whether each turn reaches ``limit`` (the gyro's clipping levels) in any channel."""
    if limit is None or not turns:
        return np.zeros(len(turns), bool)
    rows, counts = stacked_rows([t.segment.start for t in turns],
                                [t.segment.stop for t in turns])  # fmt: skip
    z = session.gyro.take(rows, axis=0)
    hit = np.any((z <= limit[0]) | (z >= limit[1]), axis=1)
    return np.logical_or.reduceat(hit, np.cumsum(counts) - counts)


def _saturation_limit(session: Session, cfg: Config
                      ) -> tuple[np.ndarray, np.ndarray] | None:  # fmt: skip
    """Raw levels at which each gyro channel clips, ``(low, high)`` of shape (3,) (-inf/+inf
    where a channel shows none): the configured range less 0.5 % of the span at both ends;
    else the ends of a counts gyro's ADC word (the word is the smallest that holds the data:
    a 16-bit gyro whose turns stay within +-2047 counts would otherwise be taken for a 12-bit
    one clipping at its 0.5 % margin; a clipped reading sits on the end, issue 24.6), or,
    nearer, a level a channel sits on for consecutive samples while the unit turns (a part
    whose range ends within its word, a float stream of a clipped part:
    :func:`~imucal_cli.design.clipping.flat_top_levels`)."""
    n = session.gyro.shape[1]
    if cfg.gyro.range is not None:
        lo, hi = cfg.gyro.range
        margin = 0.005 * (hi - lo)
        return np.full(n, lo + margin), np.full(n, hi - margin)
    low, high = _flat_tops(session)
    if session.gyro_units == "counts":
        gyro = session.gyro
        finite = gyro if np.isfinite(gyro).all() else gyro[np.isfinite(gyro).all(axis=1)]
        rng = adc_range(float(finite.min()), float(finite.max()))
        if rng is not None:
            low, high = np.maximum(low, rng[0]), np.minimum(high, rng[1])
    if np.all(np.isinf(low)) and np.all(np.isinf(high)):
        return None
    return low, high


def _flat_tops(session: Session) -> tuple[np.ndarray, np.ndarray]:
    """The gyro's flat tops while the unit moves (outside the still periods).  Over the gyro's
    own rows: a session read while it is written (``capture --until``'s refits) can hold a
    few more times than gyro samples."""
    still = np.zeros(len(session.gyro), bool)
    for s in session.static_segments():
        still[s.start : s.stop] = True
    return flat_top_levels(session.gyro, ~still, still)


def limit_words(limit: tuple[np.ndarray, np.ndarray], units: str | None) -> str:
    """The clipping levels of :func:`_saturation_limit` in words: ``raw -32768 .. 32767``,
    or per axis where they differ (``x -1500 .. 1500 counts``)."""
    low, high = np.broadcast_arrays(*limit)
    unit = f" {units}" if units else ""

    def pair(lo, hi):
        return f"{lo:.6g} .. {hi:.6g}".replace("-inf", "none").replace("inf", "none")

    if np.all(low == low[0]) and np.all(high == high[0]):
        return f"raw {pair(low[0], high[0])}{unit}"
    return ", ".join(f"{AXES[i]} {pair(lo, hi)}"
                     for i, (lo, hi) in enumerate(zip(low, high, strict=True))
                     if np.isfinite(lo) or np.isfinite(hi)) + unit  # fmt: skip


def _without_clipped(session: Session, turns: list[Turn], data: GyroData) -> str | None:
    """Leave out the turns that reach the gyro's clipping levels (:func:`_saturation_limit`:
    the rate beyond them is not measured, the turn's integral is short): said, not refused,
    the fit of the others stands (issue 24.2); where the others cannot determine the gyro,
    the design's warning says why (``data.left_out``). Returns the levels in words where a
    turn reached them."""
    limit = _saturation_limit(session, data.cfg)
    is_clipped = _clipped(session, turns, limit)
    if not is_clipped.any():
        return None
    words = limit_words(limit, session.gyro_units)
    names = [t.segment.label or t.segment.name for t, c in zip(turns, is_clipped, strict=True)
             if c]  # fmt: skip
    said = ", ".join(names[:5]) + (" ..." if len(names) > 5 else "")
    text = (f"{len(names)} rotation(s) reach the end of the gyro's range ({words}): the rate "
            f"beyond it is not measured, so their integral is short: left out ({said}); turn "
            "more slowly")  # fmt: skip
    data.warnings.append(text)
    data.said.append(text)
    data.left_out.append(f"{len(names)} more turn(s) were left out as clipped at the gyro's "
                         f"range ({words}): turn more slowly, still before and after each")
    data.turns = [t for t, c in zip(turns, is_clipped.tolist(), strict=True) if not c]
    return words


def clipped_known(session: Session, data: GyroData, known_z: list[np.ndarray]) -> None:
    """The known-angle solver's clipping: its turns between still periods that reach the
    gyro's range left out and said (:func:`_without_clipped`); a known turn that does, a
    warning that stops the save (its angle is the gyro's scale: no fit without it stands)."""
    if data.turns:
        _without_clipped(session, data.turns, data)
    limit = _saturation_limit(session, data.cfg)
    if limit is not None and any(np.any((z <= limit[0]) | (z >= limit[1])) for z in known_z):
        data.warnings.append(f"a turn of known angle reaches the end of the gyro's range "
                             f"({limit_words(limit, session.gyro_units)}): its integral is "
                             "short; turn more slowly")  # fmt: skip


def gyro_data(session: Session, cfg: Config, accel_cal: SensorCalibration) -> GyroData:
    """Turns with still data around them; clipped turns, and turns with a gap in their
    samples, left out (with a warning)."""
    where = session_name(session)
    if session.gyro is None:
        raise DesignError(f"{where}: no /raw/gyro in this session")

    session, settled = settle_turns(session)  # issue 24.5: each turn from rest to rest
    stills, turns, skipped, source, noise = _stills_and_turns(session, accel_cal, cfg, where)
    data = GyroData(session, cfg, where, accel_cal, stills, turns, max(noise, 1e-12),
                    np.zeros(3), 0.0, session.gyro_units or "unknown",
                    notes=[f"rotations: {source}"] + ([settled] if settled else []))  # fmt: skip
    data.notes += bridged_note(session, session.rotation_segments(), turns)
    if skipped:
        data.notes.append(f"{len(skipped)} rotation(s) without still data before and after: "
                          "skipped")  # fmt: skip
    turns = _without_gaps(session, turns, data)
    clipped = _without_clipped(session, turns, data)
    if not data.turns:
        raise (ClippedTurns if clipped else DesignError)(f"{where}: every rotation " + (
            f"reaches the end of the gyro's range ({clipped}): the rate beyond it is not "
            "measured, so no turn can be integrated; turn the unit more slowly, still before "
            "and after each turn" if clipped else "is interrupted by a gap in the samples: "
            "record again without losing samples"))  # fmt: skip
    n = sum(s.segment.stop - s.segment.start for s in stills)
    data.bias_still = np.sum([s.z_mean * (s.segment.stop - s.segment.start) for s in stills],
                             axis=0) / n  # fmt: skip
    data.noise, data.round_cov = rounding(session, stills, data.noise)
    counts = np.array([s.segment.stop - s.segment.start for s in stills], float)
    data.b_still_std = float(np.sqrt(data.noise**2 / n + rounding_of_mean(data.round_cov, counts)))
    return data


VARIANTS = {
    "static": "Qureshi static-bias approach (eq. 18)",
    "dynamic": "Qureshi dynamic approach (eqs. 19-21)",
    "full": "12 parameters from integrated rotations",
    "full-g": "21 parameters (with g-sensitivity) from integrated rotations",
}


def calibrate_gyro_rotations(session: Session, cfg: Config, accel_cal: SensorCalibration):
    """Gyro calibration with the ``static``, ``dynamic`` or ``full`` solver."""
    data = gyro_data(session, cfg, accel_cal)
    solver = cfg.gyro.solver
    if solver in ("static", "dynamic"):
        fit = fit_per_axis(data, solver)
    else:
        fit = fit_full_model(data)
    data.warnings += gyro_checks(session, cfg, fit.gains, data.units_in)
    members = dict(fit.members)
    variant = "full-g" if members.get("g_sensitivity") is not None else solver
    members.update({
        "model": MODEL_EQUATION if variant != "full-g" else MODEL_EQUATION_G,
        "units_in": data.units_in,
        "variant": VARIANTS[variant],
        "frame": _frame(data.accel_cal),
        "parameters": fit.parameters,
        "sensitivity": [float(x) for x in fit.gains],
        "sensitivity_unit": f"{data.units_in} per rad/s",
        "rotations": fit.rotations,
        "rotation_rms_deg": float(np.degrees(rms(fit.residual_rad))),
        "gyro_noise_raw": data.noise,
        "noise_basis": "pooled over the still periods",
        "notes": data.notes,
        "warnings": data.warnings,
    })  # fmt: skip
    if data.said:
        members["blocking"] = [w for w in data.warnings if w not in data.said]
    return build(
        GyroCalibration,
        solver=f"gyro-{solver}",
        units="rad/s",
        bias=np.asarray(fit.bias, float),
        matrix=np.asarray(fit.matrix, float),
        residual_rms=rms(fit.residual_rad),
        **members,
    )


def _frame(accel: SensorCalibration | None) -> str:
    """The frame the gyro is calibrated in: the accelerometer's, which its solver and model
    fix (another accelerometer solver is another frame: not drift); without one, the frame
    of the turns' labelled axes."""
    if accel is None:
        return "the labelled axes of the turns (no accelerometer calibration)"
    how = ", ".join(x for x in (accel.solver, accel.variant) if x)
    return f"the calibrated accelerometer's frame ({how})"


def full_problem(session: Session, cfg: Config, accel_cal: SensorCalibration):
    """The full model's data for a session, as :func:`calibrate_gyro_rotations` builds it:
    ``(Rotations, Stills, per-sample gyro noise)`` (for the Cramér-Rao bound of a design)."""

    session, _ = with_segments(session)
    data = gyro_data(session, cfg, accel_cal)
    rot, st = rotations_and_stills(data)
    return rot, st, data.noise


def full_bound(session: Session, cfg: Config, accel_cal: SensorCalibration,
               x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The Cramér-Rao bound of the full model's ``(b, vec(M)[, vec(G)])`` at ``x`` for a
    session, as :func:`calibrate_gyro_rotations` builds its data: the gyro's own (the
    accelerometer calibration taken as exact), and with the accelerometer calibration's
    covariance propagated through the turns (what an error against the truth is to be
    measured against when the accelerometer is calibrated from the same session: its own
    error moves the gyro's too; without its frame's rotation, which turns the gyro's frame
    with it: errors are measured in the calibrated accelerometer's frame). Both (n, n); the
    second equals the first without an accelerometer covariance."""

    session, _ = with_segments(session)
    data = gyro_data(session, cfg, accel_cal)
    rot, st = rotations_and_stills(data)
    crb = np.linalg.inv(full_information(x, rot, st, data.noise))
    cov = accel_cal.covariance
    dg = accel_derivative(data.stills, accel_cal)
    if cov is None or cov.values is None or dg is None:
        return crb, crb
    at = SimpleNamespace(b=x[:3], M=x[3:12].reshape(3, 3),
                         G=x[12:21].reshape(3, 3) if len(x) == 21 else None)  # fmt: skip
    A = accel_sensitivity(rot, st, data.noise, at, dg)
    return crb, crb + A @ frame_free(cov.values, accel_cal.matrix) @ A.T  # the frame: a gauge


def gyro_alternatives(session: Session, solver: str) -> list[str]:
    """What would calibrate the gyro from this session when ``solver`` refused it (issue 9.6):
    another solver for turns it already has, or a labelling step, before a new capture."""
    turns = session.rotation_segments()
    known = [s for s in turns if s.angle_deg is not None]
    path = session.path or "SESSION.h5"
    out = []
    if solver != "known" and len(known) >= 3:
        out.append(f'its {len(known)} turns of known angle: [gyro] solver = "known"')
    if solver != "factorization" and sum(s.axis is not None for s in turns) >= 3:
        out.append('its turns about labelled axes: [gyro] solver = "factorization" (Hwangbo & '
                   "Kanade; needs no accelerometer)")  # fmt: skip
    if turns and len(known) < 3:
        out.append(f"if its turns were of a known angle (a full turn flat on a table, a "
                   f"turntable), say so: imucal label {path} --segment NAME --angle DEG --axis "
                   "X,Y,Z for each (three axes), and the known-angle solver uses them")  # fmt: skip
    return out


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
