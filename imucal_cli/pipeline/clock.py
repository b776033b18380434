"""The calibrate step's sample clock (issue 17.2): the device's time stamps against the host's
arrival times (``/raw/host_time``, recorded by ``imucal capture`` when the device sends its
own time), and the session's time corrected to true seconds before any solver integrates it.

The gyro solvers integrate the rates over the session's time stamps, so a device clock that
runs ``s`` device seconds per true second would scale every integrated angle by ``s`` and the
fitted gyro scale by ``1 / s``. Dividing the device times by ``s`` first gives a gyro matrix in
true seconds; the calibration records ``sample_clock_scale`` (gyro section) and the estimate
(root ``sample_clock``: scale, ppm and its standard deviation, jitter, duration) for the
report. ``[clock] model = "off"`` leaves the time as it is.

Only a significant estimate is applied (issue 24.4: :attr:`~imucal_cli.solvers.clock.
ClockEstimate.significant`, ``|ppm|`` beyond three standard deviations of the arrivals' jitter
and bursts and of the host clock's own error): a correction within the noise would move the
gyro's scale by noise, and a device whose clock is right would come out worse for it.  The
estimate is reported either way, with ``applied`` saying whether the time was corrected.
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
    no host arrival times or the config turns it off; when the recording cannot give it, the
    estimate holds only a ``note`` saying why).  The time is corrected only when the estimate
    is significant (``applied``)."""
    host = session.host_time
    if host is None or cfg.clock.model == "off":
        return session, None
    try:
        est = estimate_clock_scale(session.time, host)
    except DesignError as exc:
        return session, {"note": f"sample clock not estimated: {exc}"}
    found = {**est.to_dict(), "basis": "host arrival times (/raw/host_time)"}
    if not est.significant:
        return session, {**found, "applied": False,
                         "corrected": f"not corrected: within {est.threshold_ppm:.3g} ppm "
                         "(3 standard deviations) of a clock that is right"}  # fmt: skip
    t0 = float(session.time[0])
    time = t0 + (session.time - t0) / est.scale
    rate = None if session.sample_rate_hz is None else session.sample_rate_hz * est.scale
    out = replace(session, time=time, sample_rate_hz=rate)
    return out, {**found, "applied": True,
                 "corrected": "session time divided by the scale before calibrating"}  # fmt: skip
