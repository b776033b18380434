"""What a guided capture with targets has so far, as a design at the current fit.

The capture keeps its samples (:class:`~.samples.SampleHistory`) and the steps it took
(:class:`~.matching.Taken`).  For the Fisher information
(:mod:`imucal_cli.planning.information`) they become

- a **fit**: the last refit's accelerometer and gyroscope sections, or nominal values before
  there is one (the accelerometer's scale from the still poses' raw magnitude; the gyro's from
  the turns: the angle between the gravity directions before and after a turn over its
  integrated raw rate; 1 raw unit per rad/s before the first turn, which only scales what no
  target can use yet);
- **poses**: each hold's calibrated gravity direction and sample count, with the label's
  placement error when the accelerometer solver uses labels;
- **turns**: the motion between two holds, its rotation vector from the integrated gyro at
  the fit (``M int (z - b) dt``: the axis and angle of a turn about a fixed axis), and its
  duration from the end of one hold to the start of the next (the calibrate step integrates
  the whole of it, the person's pause before turning too: its noise counts);
- the **noise**: the holds' pooled scatter per sample, raw units.

It also builds the session so far (:func:`session_so_far`) that the capture refits after every
hold, and converts targets to the information's units (:func:`limits`).
"""

from __future__ import annotations

import math

import numpy as np

from imucal_cli.formats.session import Segment, Session, utc_now_iso
from imucal_cli.formats.targets import STANDARD_GRAVITY, Targets
from imucal_cli.model.calibration import Calibration
from imucal_cli.planning.information import TURN_MARGIN_S, Fit, Noise, Pose, Turn

from .matching import Taken
from .samples import SampleHistory

__all__ = ["Design", "design", "limits", "session_so_far"]

MIN_TURN_DEG = 10.0
"""A motion between two holds that turned the unit less than this is no turn, degrees."""


class Design:
    """The design of a guided capture: :attr:`fit`, :attr:`poses`, :attr:`turns`,
    :attr:`noise`, and for each pose the index of its :class:`Taken` (:attr:`taken`)."""

    def __init__(self, fit: Fit, poses: list[Pose], turns: list[Turn], noise: Noise,
                 taken: list[int]) -> None:  # fmt: skip
        self.fit, self.poses, self.turns, self.noise, self.taken = fit, poses, turns, noise, taken


def _pooled_std(blocks: list[np.ndarray]) -> float | None:
    """Per-sample std pooled over the holds (all channels), raw units."""
    ss, dof = 0.0, 0
    for b in blocks:
        if b is None or len(b) < 2:
            continue
        ss += float(np.sum((b - b.mean(axis=0)) ** 2))
        dof += (len(b) - 1) * b.shape[1]
    return math.sqrt(ss / dof) if dof else None


def _integral(hist: SampleHistory, start: int, stop: int, bias: np.ndarray) -> np.ndarray:
    """``int (z - b) dt`` over samples ``[start, stop)``, raw units x s (trapezoids)."""
    t = hist.rows(hist.time[:, None], start, stop)[:, 0]
    z = hist.rows(hist.gyro, start, stop) - bias
    if len(t) < 2:
        return np.zeros(3)
    return np.sum(0.5 * (z[1:] + z[:-1]) * np.diff(t)[:, None], axis=0)


def _accel_fit(cal: Calibration | None, means: list[np.ndarray], g: float, nominal_bias
               ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    sec = None if cal is None else cal.accel
    if sec is not None and np.shape(sec.matrix) == (3, 3):
        return np.asarray(sec.matrix, float), np.asarray(sec.bias, float)
    bias = np.zeros(3) if nominal_bias is None else np.broadcast_to(
        np.asarray(nominal_bias, float), (3,)).copy()  # fmt: skip
    mags = [np.linalg.norm(m - bias) for m in means]
    scale = float(np.median(mags)) / g if mags else 1.0
    return np.eye(3) / max(scale, 1e-300), bias


def _gyro_fit(cal: Calibration | None, hist: SampleHistory, statics: list[Taken],
              ups: list[np.ndarray], still_gyro: list[np.ndarray]
              ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    sec = None if cal is None else cal.gyro
    if sec is not None and np.shape(sec.matrix) == (3, 3):
        return np.asarray(sec.matrix, float), np.asarray(sec.bias, float)
    bias = np.mean(still_gyro, axis=0) if still_gyro else np.zeros(3)
    scales = []
    for k in range(1, len(statics)):
        turn = statics[k].turn
        if turn is None:
            continue
        seen = math.acos(float(np.clip(ups[k - 1] @ ups[k], -1.0, 1.0)))
        raw = float(np.linalg.norm(_integral(hist, *turn, bias)))
        if seen > math.radians(30.0) and raw > 0:
            scales.append(seen / raw)
    return np.eye(3) * (float(np.median(scales)) if scales else 1.0), bias


def design(hist: SampleHistory, taken: list[Taken], cal: Calibration | None, *,
           gravity: float, placement_deg: float, labelled: list[bool],
           nominal_bias=None, fallback_noise: tuple[float, float] = (1.0, 1.0),
           current: tuple[int, int] | None = None,
           current_turn: tuple[int, int] | None = None) -> Design:  # fmt: skip
    """The design of the holds taken (and the hold in progress, ``current``: samples
    ``(start, end)``, reached by the motion ``current_turn``) at the last refit ``cal`` (see
    the module notes).

    ``labelled[i]``: the i-th static step taken carries a label (its placement error counts
    as a prior when ``placement_deg`` is finite).  ``fallback_noise``: accel and gyro noise
    per sample (raw) before two holds give their own.
    """
    statics = [t for t in taken if t.kind == "static" and t.start >= hist.first]
    index = [taken.index(t) for t in statics]
    spans = [(t.start, t.stop) for t in statics]
    marks = list(labelled[: len(statics)])
    if current is not None and current[1] - current[0] >= 2:
        spans.append(current)
        marks.append(True)
    means = [hist.rows(hist.accel, a, b).mean(axis=0) for a, b in spans]
    still_gyro = ([hist.rows(hist.gyro, a, b).mean(axis=0) for a, b in spans]
                  if hist.gyro is not None else [])  # fmt: skip
    M_a, B_a = _accel_fit(cal, means, gravity, nominal_bias)
    ups = [v / np.linalg.norm(v) for v in (M_a @ (m - B_a) for m in means)]
    s_a = _pooled_std([hist.rows(hist.accel, a, b) for a, b in spans])
    s_g = (_pooled_std([hist.rows(hist.gyro, a, b) for a, b in spans])
           if hist.gyro is not None else None)  # fmt: skip
    rate = _rate(hist)
    noise = Noise(s_a or fallback_noise[0], s_g or fallback_noise[1], rate)
    M_g, b_g = _gyro_fit(cal, hist, statics, ups, still_gyro)
    fit = Fit(M_a, B_a, M_g, b_g, gravity)
    poses = [Pose(u, b - a, placement_deg if lab else math.inf)
             for u, (a, b), lab in zip(ups, spans, marks, strict=True)]  # fmt: skip
    turns = []
    turn_spans = [t.turn for t in statics[1:]]
    if len(spans) > len(statics) and statics:
        turn_spans.append(current_turn)
    for k, span in enumerate(turn_spans, start=1):
        if span is None or hist.gyro is None or span[0] < hist.first:
            continue
        rotvec = M_g @ _integral(hist, *span, b_g)
        angle = float(np.linalg.norm(rotvec))
        if math.degrees(angle) < MIN_TURN_DEG:
            continue
        gap = hist.t(spans[k][0]) - hist.t(spans[k - 1][1])  # hold to hold
        turns.append(Turn(k - 1, k, rotvec / angle, angle, max(gap - TURN_MARGIN_S, 0.2)))
    return Design(fit, poses, turns, noise, index)


def _rate(hist: SampleHistory) -> float:
    t = hist.time
    if len(t) < 2 or not t[-1] > t[0]:
        return 100.0
    return (len(t) - 1) / float(t[-1] - t[0])


def limits(targets: Targets) -> dict[tuple[str, str], float]:
    """The targets in the information's units: gains relative, biases in m/s^2 and rad/s,
    misalignments in degrees."""
    factor = {("accel", "bias"): STANDARD_GRAVITY / 1e3, ("gyro", "bias"): math.pi / 180.0}
    out = {}
    for t in targets:
        f = 0.01 if t.term == "gain" else factor.get((t.sensor, t.term), 1.0)
        out[(t.sensor, t.term)] = t.value * f
    return out


def session_so_far(hist: SampleHistory, taken: list[Taken], steps, *, accel_units, gyro_units,
                   gravity: float) -> Session:  # fmt: skip
    """The samples kept and the segments of the steps taken, as a session to refit (segment
    indices relative to the first sample kept; steps whose samples were dropped left out)."""
    first = hist.first
    segments: list[Segment] = []
    for t in sorted(taken, key=lambda x: x.start):
        if t.start < first:
            continue
        step = steps[t.step]
        if t.turn is not None and t.turn[0] >= first:
            segments.append(Segment(f"{len(segments):04d}", "rotation", t.turn[0] - first,
                                    t.turn[1] - first, label=f"turn to {step.label}"))
        attrs = step.segment_attrs()
        attrs.pop("extra", None)
        segments.append(Segment(f"{len(segments):04d}", t.kind, t.start - first,
                                t.stop - first, **attrs))  # fmt: skip
    rate = _rate(hist)
    return Session(time=hist.time.copy(), accel=None if hist.accel is None else hist.accel.copy(),
                   gyro=None if hist.gyro is None else hist.gyro.copy(), temperature=None,
                   segments=segments, created=utc_now_iso(), source="capture (so far)",
                   sample_rate_hz=rate, gravity=gravity, accel_units=accel_units,
                   gyro_units=gyro_units)  # fmt: skip
