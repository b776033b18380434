"""The virtual IMU's sample clock (issue 17.2): a device clock that runs off by a scale, and
the host's arrival times of the samples.

A simulated part samples at true times ``t_i``; its own clock stamps them ``d_i = s t_i``
(``s`` device seconds per true second, the formats page's ``sample_clock_scale``), and the
host receives them in batches (a USB frame every :data:`BATCH_S`) with a small jitter, so the
arrival times are ``ceil(t_i / BATCH_S) BATCH_S + |jitter|``. The session then records the
device times as ``/raw/time`` and the arrivals as ``/raw/host_time``. Draws come from
``SeedSequence(seed, spawn_key=(8,))``, so the same seed is the same part with or without it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from imucal_cli.errors import InputError

__all__ = ["BATCH_S", "JITTER_S", "busy_arrivals", "clocked", "host_arrivals", "with_clock"]

#: Host delivery batches, s (a USB full-speed frame is 1 ms; serial drivers deliver ~10 ms).
BATCH_S = 0.01
#: Standard deviation of the host's extra latency, s.
JITTER_S = 0.0005
SPAWN_KEY = 8


def host_arrivals(true_time: np.ndarray, seed: int, batch_s: float = BATCH_S,
                  jitter_s: float = JITTER_S) -> np.ndarray:  # fmt: skip
    """Host arrival time of each sample (true seconds; never decreasing: a batch arrives
    together)."""
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(SPAWN_KEY,)))
    t = np.asarray(true_time, float)
    arrive = np.ceil((t - t[0]) / batch_s + 1e-9) * batch_s + t[0]
    arrive = arrive + np.abs(jitter_s * rng.standard_normal(len(t)))
    return np.maximum.accumulate(arrive)


def busy_arrivals(true_time: np.ndarray, seed: int, *, backlog_s: float = 5.0,
                  drift: bool = True) -> np.ndarray:  # fmt: skip
    """Host arrival times as a capture on a busy host sees them (issue 24.4): the host reads
    every 5-15 ms and sometimes not for 0.1-0.4 s (a burst follows), more often so as the
    load grows through the recording (``drift``), and starts reading only ``backlog_s`` after
    the first sample (the capture starting up); each read takes every line sent before it,
    all stamped with the read's time (true seconds, never decreasing)."""
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(SPAWN_KEY, 1)))
    t = np.asarray(true_time, float)
    reads, now, end = [], t[0] + backlog_s, t[-1] + 1.0
    while now < end:
        reads.append(now)
        busy = 0.02 + (0.1 * (now - t[0]) / (end - t[0]) if drift else 0.0)
        now += rng.uniform(0.1, 0.4) if rng.random() < busy else rng.uniform(0.005, 0.015)
    reads = np.asarray(reads)
    return reads[np.searchsorted(reads, t + 1e-4)]  # the first read after each line


def check_ppm(ppm: float) -> float:
    """A clock error in ppm as the scale ``1 + ppm 1e-6``; refused beyond +-5 %."""
    if not (np.isfinite(ppm) and abs(ppm) < 50_000):
        raise InputError(f"--clock-ppm {ppm:g}: give a clock error within +-50000 ppm (5 %)")
    return 1.0 + ppm * 1e-6


def with_clock(session, scale: float, seed: int):
    """``session`` (true times) as a part whose clock runs ``scale`` device s per true s
    records it: device times in ``time``, host arrivals in ``host_time``."""
    true_time = np.asarray(session.time, float)
    rate = None if session.sample_rate_hz is None else session.sample_rate_hz / scale
    return replace(session, time=true_time * scale, host_time=host_arrivals(true_time, seed),
                   sample_rate_hz=rate)  # fmt: skip


def clocked(session, truth, scale: float | None, seed: int):
    """A simulator's ``session`` recorded by a clock of ``scale`` (:func:`with_clock`; None:
    as it is); the truth ``Calibration`` records the scale (gyro ``sample_clock_scale``, the
    simulator's ``clock_scale``)."""
    if scale is None:
        return session
    truth.gyro.extra["sample_clock_scale"] = float(scale)
    truth.extra["simulator"]["clock_scale"] = float(scale)
    return with_clock(session, scale, seed)
