"""The noise step (``imucal noise``): a still recording -> Allan deviation -> noise figures.

1. The samples: the longest static segment of the session, or the whole recording when the
   session has no segments.  :func:`~imucal_cli.solvers.segmentation.find_static` checks that
   they are still (thresholds from the data's own noise): a recording mostly moving is refused,
   one that moved for more than :data:`MOVED_WARN_FRACTION` of its duration is analysed with a
   warning (motion inflates every figure).
2. Raw -> SI: with a calibration, ``calibrated = matrix @ (raw - bias)`` per sensor; without,
   the session's nominal units (``m/s^2``, ``g``; ``rad/s``, ``deg/s``).  ``counts`` or ``V``
   need a calibration: such a sensor is skipped with a warning, and when no sensor is left the
   step refuses with advice.
3. Per axis: :func:`imucal_cli.solvers.allan.axis_noise` (random walk, bias instability, rate
   random walk), converted to the units people put in their filters.

:func:`analyse_noise` returns a :class:`NoiseReport`; :meth:`NoiseReport.to_dict` is the
``imucal noise --json`` output.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import Calibration, SensorCalibration
from imucal_cli.formats.noise import NOISE_FORMAT
from imucal_cli.formats.session import Session
from imucal_cli.solvers.allan import AxisNoise, axis_noise

__all__ = [
    "MIN_DURATION_S",
    "MOVED_REFUSE_FRACTION",
    "MOVED_WARN_FRACTION",
    "NOISE_FORMAT",
    "NoiseReport",
    "SensorNoise",
    "analyse_noise",
    "figures",
]

STANDARD_GRAVITY = 9.80665
"""m/s^2, for micro-g figures."""

MIN_DURATION_S = 10.0
"""Shortest recording analysed, s (its longest tau is then 1 s)."""

MOVED_WARN_FRACTION = 0.1
"""Warn when more than this fraction of the recording is not still."""

MOVED_REFUSE_FRACTION = 0.5
"""Refuse when more than this fraction is not still."""

MAX_TAU_FRACTION = 0.1
"""Longest tau as a fraction of the recording."""

_DEG = 180.0 / math.pi
_NOMINAL = {"accel": {"m/s^2": 1.0, "g": None}, "gyro": {"rad/s": 1.0, "deg/s": 1.0 / _DEG}}

# Per sensor: (key, attribute of AxisNoise, factor from SI, unit, column title)
_FIGURES = {
    "accel": (
        ("vrw_m_s_per_sqrt_s", "random_walk", 1.0, "m/s/sqrt(s)", "VRW"),
        ("vrw_ug_per_sqrt_hz", "random_walk", 1e6 / STANDARD_GRAVITY, "ug/sqrt(Hz)", "VRW"),
        ("vrw_m_s_per_sqrt_h", "random_walk", 60.0, "m/s/sqrt(h)", "VRW"),
        ("bias_instability_m_s2", "bias_instability", 1.0, "m/s^2", "bias instab."),
        ("bias_instability_ug", "bias_instability", 1e6 / STANDARD_GRAVITY, "ug", "bias instab."),
        ("rrw_m_s2_per_sqrt_s", "rate_random_walk", 1.0, "m/s^2/sqrt(s)", "RRW"),
    ),
    "gyro": (
        ("arw_rad_per_sqrt_s", "random_walk", 1.0, "rad/sqrt(s)", "ARW"),
        ("arw_deg_per_sqrt_h", "random_walk", _DEG * 60.0, "deg/sqrt(h)", "ARW"),
        ("bias_instability_rad_s", "bias_instability", 1.0, "rad/s", "bias instab."),
        ("bias_instability_deg_h", "bias_instability", _DEG * 3600.0, "deg/h", "bias instab."),
        ("rrw_rad_s_per_sqrt_s", "rate_random_walk", 1.0, "rad/s/sqrt(s)", "RRW"),
        ("rrw_deg_h_per_sqrt_h", "rate_random_walk", _DEG * 3600.0 * 60.0, "deg/h/sqrt(h)", "RRW"),
    ),
}


def figures(kind: str) -> tuple[tuple[str, str, float, str, str], ...]:
    """The figures reported for ``kind`` (``accel``/``gyro``): ``(key, attribute, factor from
    SI, unit, title)`` each."""
    return _FIGURES[kind]


@dataclass
class SensorNoise:
    """Noise of one sensor.

    Attributes
    ----------
    kind : str
        ``accel`` or ``gyro``.
    units : str
        SI units of the rate analysed (``m/s^2`` or ``rad/s``).
    basis : str
        How raw became SI (the calibration, or the nominal units).
    axes : list of str
        Axis names.
    noise : list of AxisNoise
        Per axis.
    """

    kind: str
    units: str
    basis: str
    axes: list[str]
    noise: list[AxisNoise]


@dataclass
class NoiseReport:
    """What :func:`analyse_noise` found.

    Attributes
    ----------
    session : str
    sensor : str or None
        The session's ``sensor`` attribute.
    span : str
        Which samples: ``"segment 0003 (hold still ...)"`` or ``"whole recording"``.
    start, stop : int
        Half-open sample range analysed.
    duration_s, rate_hz : float
    still_fraction : float
        Fraction of the samples :func:`find_static` calls still.
    sensors : list of SensorNoise
    warnings : list of str
    """

    session: str
    sensor: str | None
    span: str
    start: int
    stop: int
    duration_s: float
    rate_hz: float
    still_fraction: float
    sensors: list[SensorNoise]
    warnings: list[str] = field(default_factory=list)

    @property
    def longest_tau_s(self) -> float:
        """Longest averaging time computed, s."""
        taus = [a.curve.tau_s[-1] for s in self.sensors for a in s.noise if len(a.curve.tau_s)]
        return float(max(taus)) if taus else 0.0

    def limits(self) -> str:
        """One line: how long the recording is and what that limits."""
        minutes = self.duration_s / 60.0
        text = (
            f"{minutes:.1f} min at {self.rate_hz:.4g} Hz: taus up to {self.longest_tau_s:.3g} s "
            f"(a tenth of the recording)"
        )
        if self.duration_s < 20 * 60:
            text += "; bias instability needs tens of minutes (capture --plan still:20 or longer)"
        else:
            text += "; long enough to see bias instability if its minimum lies below that tau"
        return text

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` output: every figure with its unit in its key, plus the curves."""
        sensors = {}
        for s in self.sensors:
            axes = []
            for name, a in zip(s.axes, s.noise, strict=True):
                row: dict[str, Any] = {"axis": name}
                for key, attr, factor, _, _ in figures(s.kind):
                    value = getattr(a, attr)
                    row[key] = None if value is None else value * factor
                row["random_walk_fit_taus_s"] = list(a.random_walk_taus)
                row["bias_instability_tau_s"] = a.bias_instability_tau_s
                row["bias_instability_upper_bound"] = a.bias_instability_bound
                row["rrw_fit_taus_s"] = list(a.rate_random_walk_taus)
                row["notes"] = list(a.notes)
                row["curve"] = {
                    "tau_s": a.curve.tau_s.tolist(),
                    "adev": a.curve.adev.tolist(),
                    "adev_err": a.curve.adev_err.tolist(),
                    "unit": s.units,
                }
                axes.append(row)
            sensors[s.kind] = {"units": s.units, "basis": s.basis, "axes": axes}
        return {
            "format": NOISE_FORMAT,
            "format_version": 1,
            "session": self.session,
            "sensor": self.sensor,
            "span": self.span,
            "start": self.start,
            "stop": self.stop,
            "duration_s": self.duration_s,
            "rate_hz": self.rate_hz,
            "still_fraction": self.still_fraction,
            "longest_tau_s": self.longest_tau_s,
            "limits": self.limits(),
            "sensors": sensors,
            "warnings": list(self.warnings),
        }


def _span(session: Session) -> tuple[int, int, str]:
    """The longest static segment, or the whole recording when there are no segments."""
    if not session.segments:
        return 0, len(session.time), "whole recording (no segments)"
    statics = [s for s in session.segments if s.kind == "static"]
    if not statics:
        raise InputError(
            f"{session.path or 'session'}: no static segment to analyse; record the unit still "
            "(imucal capture --plan still:20)"
        )
    best = max(statics, key=lambda s: session.time[s.stop - 1] - session.time[s.start])
    label = f" ({best.label})" if best.label else ""
    return best.start, best.stop, f"segment {best.name}{label}, the longest still one"


def _to_si(
    kind: str, raw: np.ndarray, units: str | None, cal: SensorCalibration | None,
    gravity: float, where: str,
) -> tuple[np.ndarray, str]:  # fmt: skip
    """Raw channels -> SI rate (N, 3 or n) and how."""
    if cal is not None:
        bias = np.asarray(cal.bias, float)
        matrix = np.asarray(cal.matrix, float)
        if matrix.shape[1] != raw.shape[1]:
            raise InputError(
                f"{where}: the calibration's {kind} takes {matrix.shape[1]} channels, the "
                f"session has {raw.shape[1]}"
            )
        return (raw - bias) @ matrix.T, f"calibration ({cal.solver})"
    table = _NOMINAL[kind]
    if units not in table:
        raise _NeedsCalibration(f"{kind} in {units or 'unstated units'}")
    factor = table[units] if table[units] is not None else gravity
    return raw * factor, f"nominal units ({units})"


class _NeedsCalibration(Exception):
    pass


def analyse_noise(
    session: Session, calibration: Calibration | None = None, *,
    max_tau_fraction: float = MAX_TAU_FRACTION,
) -> NoiseReport:  # fmt: skip
    """Allan deviation of a still recording and the noise figures per axis.

    Parameters
    ----------
    session : Session
        A still recording (``imucal capture --plan still:MINUTES``, or any session: its
        longest static segment is used).
    calibration : Calibration, optional
        Turns raw channels into SI; needed for ``counts``/``V``.
    max_tau_fraction : float
        Longest tau as a fraction of the recording.

    Returns
    -------
    NoiseReport

    Raises
    ------
    InputError
        No usable sensor (raw units need a calibration), a recording too short, or not still.
    """
    from imucal_cli.solvers.segmentation import find_static

    where = str(session.path) if session.path else "session"
    start, stop, span = _span(session)
    time = np.asarray(session.time[start:stop], float)
    n = len(time)
    duration = float(time[-1] - time[0]) if n > 1 else 0.0
    if duration < MIN_DURATION_S:
        raise InputError(
            f"{where}: {span} lasts {duration:.1f} s, too short for an Allan deviation; record "
            f"at least {MIN_DURATION_S:g} s, better tens of minutes (capture --plan still:20)"
        )
    rate = (n - 1) / duration
    warnings: list[str] = []
    dt = np.diff(time)
    if dt.max() > 5 * np.median(dt):
        warnings.append(
            f"the sampling has gaps (longest {dt.max():.3g} s at {rate:.4g} Hz): the Allan "
            "deviation assumes even samples"
        )
    accel = None if session.accel is None else np.asarray(session.accel[start:stop], float)
    gyro = None if session.gyro is None else np.asarray(session.gyro[start:stop], float)

    still = find_static(time, accel, gyro, min_still_s=1.0)
    still_fraction = sum(iv.stop - iv.start for iv in still) / n
    moved = 1.0 - still_fraction
    if moved > MOVED_REFUSE_FRACTION:
        raise InputError(
            f"{where}: {span} is not still ({100 * moved:.0f} % of it moved); record the unit "
            "untouched on a steady table (imucal capture --plan still:20)"
        )
    if moved > MOVED_WARN_FRACTION:
        warnings.append(
            f"{100 * moved:.0f} % of the recording moved: the figures include that motion "
            "and are too large"
        )

    sensors: list[SensorNoise] = []
    skipped: list[str] = []
    for kind, raw, units in (("accel", accel, session.accel_units),
                             ("gyro", gyro, session.gyro_units)):  # fmt: skip
        if raw is None:
            continue
        cal = None if calibration is None else getattr(calibration, kind)
        try:
            si, basis = _to_si(kind, raw, units, cal, session.gravity, where)
        except _NeedsCalibration as exc:
            skipped.append(str(exc))
            continue
        axes = list("xyz") if si.shape[1] == 3 else [f"ch{i}" for i in range(si.shape[1])]
        noise = [axis_noise(si[:, i], rate, max_tau_fraction=max_tau_fraction)
                 for i in range(si.shape[1])]  # fmt: skip
        sensors.append(SensorNoise(kind, "m/s^2" if kind == "accel" else "rad/s", basis,
                                   axes, noise))  # fmt: skip
    if not sensors:
        what = " and ".join(skipped) if skipped else "no accelerometer or gyroscope data"
        raise InputError(
            f"{where}: {what}: raw units need a calibration to give noise in SI units; "
            "pass --calibration CAL.json (from imucal calibrate)"
        )
    for item in skipped:
        warnings.append(f"{item} skipped: raw units need --calibration CAL.json")
    return NoiseReport(
        session=Path(session.path).name if session.path else where,
        sensor=session.sensor,
        span=span,
        start=int(start),
        stop=int(stop),
        duration_s=duration,
        rate_hz=rate,
        still_fraction=float(still_fraction),
        sensors=sensors,
        warnings=warnings,
    )


def load_calibration(path: str | os.PathLike[str]) -> Calibration:
    """A calibration JSON or the last one stored in a session (as ``imucal report`` reads)."""
    from imucal_cli.use.report import load_for_report

    return load_for_report(path)
