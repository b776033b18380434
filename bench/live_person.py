"""The file as ``bench live``'s guided person streams it (issue 24.1): the reference a guided
row is paired with.

A guided capture records the first ``--hold`` s of each of the device's holds from its
stillness detector's delay after the move on, and the scripted person presses Enter a reaction
time after the capture took the pose: the device then moves on, the rest of its hold never
streamed.  The captured samples are the file's, cut so (random:12, seeds 0-7, 88 poses: the
file's samples cut at each capture's own delays and reactions give its error/bound to 0.001 on
7 of 8 seeds).  :func:`held_as_guided` cuts the file so at given delays and reactions (by
default their means); :func:`person_draws` draws them per pose as the capture and the person
take them, which is what makes a guided row's expectation and its sampling error.

Why draws: the still samples after a pose's window (the person's reaction) are integrated with
the turn that follows, and the gyro's error over its bound moves with them (random:12, 120
seeds, reactions of 0.4 and 1.2 s: per-seed spread of the log ratio 0.17, the mean 0.993 and
1.011, no trend).  One fixed cut is one draw of the person: seed 0's cut at the mean timing
gave the gyro 1.386 where its 24 draws average 1.144 (spread of the log 0.10), and the row
``random:12 guided`` on seeds 0-1 read -13 % against it, -8.5 % against the draws' mean.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from bench import live_run

#: How long after the device's hold begins the guided capture's window starts, s: its
#: stillness detector's delay after a move (captured windows against the file's samples, six,
#: qureshi18, qureshi-axes:6, hwangbo-iron and free:12, seeds 0 and 3: 7-24 samples at 100 Hz,
#: mean 17).  The first pose has none: the device streams the unit still from its first
#: sample, and the capture's window starts there (before the file's segment when it starts
#: at 1 s).
DETECT_S = 0.17
#: The detection delays :func:`person_draws` draws from (uniform), s: random:12's captured
#: windows, seeds 0-7 (88 poses beside 2 CPU burners): 14-21 samples at 100 Hz, mean 17.6,
#: std 1.8 (this range's: 2.0).
DETECT_RANGE_S = (0.14, 0.21)
#: What the stream adds to the person's reaction (:data:`bench.live_run.REACTION_S`), s: the
#: capture's screen, the Enter and the device's step.  The same 88 poses: 47-125 samples from
#: the window's end to the move, mean 88, std 23.6 (0.4-1.2 s uniform, plus 0.08: 88 and 23.1).
LATENCY_S = 0.08
#: Draws of the person's timing per seed in a guided row's reference (:func:`person_draws`).
PERSON_DRAWS = 12


def held_as_guided(session, hold_s: float, reaction_s=None, detect_s=DETECT_S):
    """The file as the bench's guided person streams it: each static segment's window the
    ``hold_s`` seconds the capture records of it, from ``detect_s`` after the hold begins
    (:data:`DETECT_S`; the first pose from the stream's first sample), and the rest of each
    hold from a reaction time after the window on never streamed (the person presses Enter
    a reaction time after the capture took the pose and the device moves on, ``--step``),
    the clock continuous as the device's; the samples streamed, the turns and the truth those
    of the file.  ``reaction_s``: the scripted person's mean
    (:data:`bench.live_run.REACTION_S`).  Either may be one value per static segment, s."""
    if session.imus:
        raise ValueError("a set of IMUs is not held as a guided capture holds it")
    reaction_s = float(np.mean(live_run.REACTION_S)) if reaction_s is None else reaction_s
    rate = float(session.sample_rate_hz or 1.0 / np.median(np.diff(session.time)))
    statics = session.static_segments()
    n = max(int(round(hold_s * rate)), 2)
    late = np.rint(np.broadcast_to(np.asarray(reaction_s, float), len(statics)) * rate)
    delay = np.rint(np.broadcast_to(np.asarray(detect_s, float), len(statics)) * rate)
    first = session.segments[0] if session.segments else None
    window = {}
    keep = np.ones(len(session.time), bool)
    for seg, lag, d in zip(statics, late.astype(int), delay.astype(int), strict=True):
        w0 = 0 if seg is first else max(seg.start, min(seg.start + d, seg.stop - 2))
        window[id(seg)] = (w0, min(w0 + n, seg.stop))
        keep[window[id(seg)][1] + lag : seg.stop] = False
    at = np.cumsum(keep) - 1  # each kept sample's index in the stream
    segments = []
    for seg in session.segments:
        start, stop = window.get(id(seg), (seg.start, seg.stop))
        segments.append(dataclasses.replace(seg, start=int(at[start]),
                                            stop=int(at[stop - 1]) + 1))  # fmt: skip
    cut = {name: None if getattr(session, name) is None else getattr(session, name)[keep]
           for name in ("accel", "gyro", "mag", "temperature", "host_time")}  # fmt: skip
    return dataclasses.replace(session, time=session.time[0] + np.arange(keep.sum()) / rate,
                               segments=segments, **cut)  # fmt: skip


def person_draws(session, hold_s: float, n: int, rng: np.random.Generator) -> list:
    """``n`` cuts of the file as a guided capture of it can come out (:func:`held_as_guided`):
    each pose's detection delay drawn from :data:`DETECT_RANGE_S` and the person's reaction
    from :data:`bench.live_run.REACTION_S` plus :data:`LATENCY_S` (uniform)."""
    k = len(session.static_segments())
    lo, hi = live_run.REACTION_S
    return [held_as_guided(session, hold_s, reaction_s=rng.uniform(lo, hi, k) + LATENCY_S,
                           detect_s=rng.uniform(*DETECT_RANGE_S, k)) for _ in range(n)]  # fmt: skip
