"""The turns' integration windows from the data (issue 24.5): a still period's edges that
already move are given to the turn beside it (:mod:`imucal_cli.design.turn_windows`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from imucal_cli.design.turn_windows import settled_bounds, still_noise
from imucal_cli.formats.session import Segment, Session


def settle_turns(session: Session) -> tuple[Session, str | None]:
    """The session with each still period next to a turn cut where the unit already moves,
    and the turn widened to meet it; a note saying how much moved (None when nothing did).

    Only edges that touch a rotation segment move (a still period ends where the turn
    begins): what lies between a still period and a turn that do not touch is the turn
    finder's (:func:`.gyro.turns_between`)."""
    statics, turns = session.static_segments(), session.rotation_segments()
    if session.gyro is None or not statics or not turns:
        return session, None
    gyro = np.asarray(session.gyro, float)
    start = np.array([s.start for s in statics], np.int64)
    stop = np.array([s.stop for s in statics], np.int64)
    sigma = still_noise(gyro, start, stop)
    turn_starts = {r.start for r in turns}
    turn_stops = {r.stop for r in turns}
    new_static, moved, longest = {}, 0, 0
    for s in statics:
        a, b = settled_bounds(gyro, s.start, s.stop, sigma, trim_start=s.start in turn_stops,
                              trim_stop=s.stop in turn_starts)  # fmt: skip
        if (a, b) != (s.start, s.stop):
            new_static[s.name] = replace(s, start=a, stop=b)
            moved += 1
            longest = max(longest, a - s.start, s.stop - b)
    if not new_static:
        return session, None
    ends = {s.stop: new_static[s.name].stop for s in statics if s.name in new_static}
    begins = {s.start: new_static[s.name].start for s in statics if s.name in new_static}
    segments = []
    for seg in session.segments:
        if seg.name in new_static:
            seg = new_static[seg.name]
        elif seg.kind == "rotation":
            seg = replace(seg, start=ends.get(seg.start, seg.start),
                          stop=begins.get(seg.stop, seg.stop))  # fmt: skip
        segments.append(seg)
    n = len(session.time)
    dt = float(session.time[-1] - session.time[0]) / (n - 1) if n > 1 else 0.0
    note = (f"{moved} still period(s) already moving at an edge next to a turn (up to "
            f"{longest} samples, {longest * dt:.2f} s): those samples integrated with the turn")
    return replace(session, segments=segments), note


def rest_to_rest(session: Session, seg: Segment) -> slice:
    """The samples a known turn ``seg`` is integrated over: its segment, and the still periods'
    edge samples it touches (the last still sample before it, the first after), as the full
    model's :func:`~imucal_cli.calibrate.gyro.full.turn_windows`. The unit rests up to the
    still period's last sample, so the interval from there to the turn's first sample belongs
    to the turn: integrated from its own first sample, a turn loses ``h/2 (w_first + w_last)``
    (qureshi-axes at 50 Hz, 400 deg/s turns labelled with their angles: 0.055 % short, the
    gains 0.055 % large, 8 sem over 19 seeds)."""
    a, b, n = seg.start, seg.stop, len(session.time)
    statics = session.static_segments()
    if a > 0 and any(s.stop == a for s in statics):
        a -= 1
    if b < n and any(s.start == b for s in statics):
        b += 1
    return slice(a, b)
