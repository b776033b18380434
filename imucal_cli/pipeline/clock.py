"""The calibrate step's sample clock (issue 17.2): the device's time stamps against the host's
arrival times (``/raw/host_time``, recorded by ``imucal capture`` when the device sends its
own time), and the session's time corrected to true seconds before any solver integrates it.

The gyro solvers integrate the rates over the session's time stamps, so a device clock that
runs ``s`` device seconds per true second would scale every integrated angle by ``s`` and the
fitted gyro scale by ``1 / s``. Dividing the device times by ``s`` first gives a gyro matrix in
true seconds; the calibration records ``sample_clock_scale`` (gyro section) and the estimate
(root ``sample_clock``: scale, ppm and its standard deviation, jitter, duration) for the
report. ``[clock] model = "off"`` leaves the time as it is.
"""

from __future__ import annotations

from dataclasses import replace

from imucal_cli.errors import DesignError
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.solvers.clock import estimate_clock_scale

__all__ = ["correct_clock"]


def correct_clock(session: Session, cfg: Config) -> tuple[Session, dict | None]:
    """The session with its time in true seconds, and the estimate (None when the session has
    no host arrival times, the config turns it off, or the recording cannot give it: the
    estimate then holds only a ``note`` saying why)."""
    host = session.host_time
    if host is None or cfg.clock.model == "off":
        return session, None
    try:
        est = estimate_clock_scale(session.time, host)
    except DesignError as exc:
        return session, {"note": f"sample clock not estimated: {exc}"}
    t0 = float(session.time[0])
    time = t0 + (session.time - t0) / est.scale
    rate = None if session.sample_rate_hz is None else session.sample_rate_hz * est.scale
    out = replace(session, time=time, sample_rate_hz=rate)
    return out, {**est.to_dict(), "basis": "host arrival times (/raw/host_time)",
                 "corrected": "session time divided by the scale before calibrating"}  # fmt: skip
