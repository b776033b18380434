"""The noise step (``imucal noise``): a still recording -> Allan deviation -> noise figures.

1. The samples: the longest static segment of the session, or the whole recording when the
   session has no segments, read once, block by block (memory stays constant: a day at 100 Hz
   in under 200 MiB).  :class:`~imucal_cli.design.static_stream.StaticStream` checks that they
   are still as :func:`~imucal_cli.design.segmentation.find_static` does (thresholds from the
   data's own noise, estimated from the span, or from :data:`NOISE_PIECES` pieces of it when
   it is longer than :data:`NOISE_SAMPLES`): a recording mostly moving is refused, one that
   moved for more than :data:`MOVED_WARN_FRACTION` of its duration is analysed with a warning
   (motion inflates every figure).
2. Raw -> SI: with a calibration, ``calibrated = matrix @ (raw - bias)`` per sensor; without,
   the session's nominal units (``m/s^2``, ``g``; ``rad/s``, ``deg/s``).  ``counts`` or ``V``
   need a calibration: such a sensor is skipped with a warning, and when no sensor is left the
   step refuses with advice.
3. Per axis: the overlapping Allan deviation summed block by block
   (:class:`imucal_cli.numerics.allan.AllanAccumulator`), and the random walk, bias instability
   and rate random walk read from it (:func:`~imucal_cli.design.allan.noise_from_curve`),
   converted to the units people put in their filters.

:func:`analyse_noise` returns a :class:`NoiseReport`; :meth:`NoiseReport.to_dict` is the
``imucal noise --json`` output.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from imucal_cli.design.allan import AxisNoise, noise_from_curve
from imucal_cli.design.segmentation import estimate_noise
from imucal_cli.design.static_stream import StaticStream
from imucal_cli.errors import InputError
from imucal_cli.formats.noise import NOISE_FORMAT
from imucal_cli.formats.session import Session, SessionSamples, samples_of
from imucal_cli.model.calibration import Calibration, SensorCalibration
from imucal_cli.numerics.allan import AllanAccumulator
from imucal_cli.use.apply import other_unit
from imucal_cli.use.export_set import set_members
from imucal_cli.use.report.load import load_for_report

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
    imu : str or None
        The IMU measured when the session holds several (``imucal noise --imu``), else None.
    imus : list of str
        The session's IMUs when it holds several, the reference's first (else empty).
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
    imu: str | None = None
    imus: list[str] = field(default_factory=list)

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
            "imu": self.imu,
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


NOISE_SAMPLES = 1 << 16
"""Samples the still test's noise is estimated from: the whole span when it is no longer (the
noise :func:`~imucal_cli.design.segmentation.find_static` estimates), else
:data:`NOISE_PIECES` pieces spread evenly over it."""

NOISE_PIECES = 16


def _span(samples: SessionSamples) -> tuple[int, int, str]:
    """The longest static segment, or the whole recording when there are no segments."""
    if not samples.segments:
        return 0, samples.n, "whole recording (no segments)"
    statics = [s for s in samples.segments if s.kind == "static"]
    if not statics:
        raise InputError(
            f"{samples.path or 'session'}: no static segment to analyse; record the unit still "
            "(imucal capture --plan still:20)"
        )

    def length(s) -> float:
        return float(samples.read("time", s.stop - 1, s.stop)[0]
                     - samples.read("time", s.start, s.start + 1)[0])  # fmt: skip

    best = max(statics, key=length)
    label = f" ({best.label})" if best.label else ""
    return best.start, best.stop, f"segment {best.name}{label}, the longest still one"


def _si_transform(
    kind: str, width: int, units: str | None, cal: SensorCalibration | None,
    gravity: float, where: str,
) -> tuple[Callable[[np.ndarray], np.ndarray], int, str]:  # fmt: skip
    """Raw channels -> SI rate: the function, its number of output channels, and how."""
    if cal is not None:
        bias = np.asarray(cal.bias, float)
        matrix = np.asarray(cal.matrix, float)
        if matrix.shape[1] != width:
            raise InputError(
                f"{where}: the calibration's {kind} takes {matrix.shape[1]} channels, the "
                f"session has {width}"
            )
        return (lambda raw: (raw - bias) @ matrix.T), matrix.shape[0], \
            f"calibration ({cal.solver})"  # fmt: skip
    table = _NOMINAL[kind]
    if units not in table:
        raise _NeedsCalibration(f"{kind} in {units or 'unstated units'}")
    factor = table[units] if table[units] is not None else gravity
    return (lambda raw: raw * factor), width, f"nominal units ({units})"


class _NeedsCalibration(Exception):
    pass


def _noise_sample(samples: SessionSamples, names: tuple[str, ...], start: int,
                  stop: int) -> list[np.ndarray]:  # fmt: skip
    """``names`` over the whole span when it holds at most :data:`NOISE_SAMPLES` samples, else
    over :data:`NOISE_PIECES` pieces spread evenly over it (concatenated)."""
    n = stop - start
    if n <= NOISE_SAMPLES:
        pieces = [(start, stop)]
    else:
        size = NOISE_SAMPLES // NOISE_PIECES
        pieces = [(a, a + size) for a in (start + (n - size) * i // (NOISE_PIECES - 1)
                                          for i in range(NOISE_PIECES))]  # fmt: skip
    return [np.concatenate([samples.read(name, a, b) for a, b in pieces]) for name in names]


def analyse_noise(
    session: Session | SessionSamples, calibration: Calibration | None = None, *,
    max_tau_fraction: float = MAX_TAU_FRACTION,
) -> NoiseReport:  # fmt: skip
    """Allan deviation of a still recording and the noise figures per axis.

    The samples are read once, block by block (:func:`~imucal_cli.formats.session.open_samples`
    gives a file that way): memory stays constant however long the recording.

    Parameters
    ----------
    session : Session or SessionSamples
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
    samples = session if isinstance(session, SessionSamples) else samples_of(session)
    where = str(samples.path) if samples.path else "session"
    start, stop, span = _span(samples)
    n = stop - start
    duration = _duration(samples, start, stop)
    if duration < MIN_DURATION_S:
        raise InputError(
            f"{where}: {span} lasts {duration:.1f} s, too short for an Allan deviation; record "
            f"at least {MIN_DURATION_S:g} s, better tens of minutes (capture --plan still:20)"
        )
    rate = (n - 1) / duration
    sensors_in = tuple(kind for kind in ("accel", "gyro") if kind in samples.channels)
    analysed, skipped = _analysers(samples, sensors_in, calibration, n, rate, max_tau_fraction,
                                   where)  # fmt: skip
    still, longest_step, steps = _one_pass(samples, sensors_in, analysed, start, stop)
    warnings: list[str] = []
    if longest_step > 5 * np.median(steps):
        warnings.append(
            f"the sampling has gaps (longest {longest_step:.3g} s at {rate:.4g} Hz): the Allan "
            "deviation assumes even samples"
        )
    still_fraction = sum(iv.stop - iv.start for iv in still.intervals()) / n
    warnings += _motion_warnings(1.0 - still_fraction, where, span)
    sensors = _sensor_noise(analysed)
    if not sensors:
        what = " and ".join(skipped) if skipped else "no accelerometer or gyroscope data"
        raise InputError(
            f"{where}: {what}: raw units need a calibration to give noise in SI units; "
            "pass --calibration CAL.json (from imucal calibrate)"
        )
    for item in skipped:
        warnings.append(f"{item} skipped: raw units need --calibration CAL.json")
    if calibration is not None:  # another unit's gains made its figures, said nowhere (audit)
        warnings += other_unit(calibration.sensor, samples.sensor, "the calibration", where)
    return NoiseReport(
        session=Path(samples.path).name if samples.path else where,
        sensor=samples.sensor,
        span=span,
        start=int(start),
        stop=int(stop),
        duration_s=duration,
        rate_hz=rate,
        still_fraction=float(still_fraction),
        sensors=sensors,
        warnings=warnings,
        imu=samples.imu,
        imus=list(samples.imus) if samples.imu is not None else [],
    )


def _duration(samples: SessionSamples, start: int, stop: int) -> float:
    """Seconds from sample ``start`` to sample ``stop - 1`` (0 for fewer than two)."""
    if stop - start <= 1:
        return 0.0
    return float(samples.read("time", stop - 1, stop)[0]
                 - samples.read("time", start, start + 1)[0])  # fmt: skip


def _analysers(samples: SessionSamples, sensors_in: tuple[str, ...],
               calibration: Calibration | None, n: int, rate: float, max_tau_fraction: float,
               where: str) -> tuple[dict[str, tuple], list[str]]:  # fmt: skip
    """Step 2, before any sample is read: per sensor its raw -> SI transform, an Allan
    accumulator and how raw became SI; the sensors left out (raw units, no calibration)."""
    analysed: dict[str, tuple] = {}
    skipped: list[str] = []
    for kind in sensors_in:
        units = samples.accel_units if kind == "accel" else samples.gyro_units
        cal = None if calibration is None else getattr(calibration, kind)
        try:
            to_si, width, basis = _si_transform(kind, samples.channels[kind], units, cal,
                                                samples.gravity, where)  # fmt: skip
        except _NeedsCalibration as exc:
            skipped.append(str(exc))
            continue
        allan = AllanAccumulator(n, rate, width, max_tau_fraction=max_tau_fraction)
        analysed[kind] = (to_si, allan, basis)
    return analysed, skipped


def _one_pass(samples: SessionSamples, sensors_in: tuple[str, ...], analysed: dict[str, tuple],
              start: int, stop: int):  # fmt: skip
    """The still test's noise first (find_static's, from the span or pieces of it), then one
    pass over the samples: the still test, the Allan sums and the longest time step.  Returns
    the still test, the longest step and the steps of the noise sample."""
    n = stop - start
    sample = _noise_sample(samples, ("time", *sensors_in), start, stop)
    noise = estimate_noise(*_by_sensor(sample[0], sensors_in, sample[1:]))
    steps = np.diff(sample[0])
    if n > NOISE_SAMPLES:  # leave out the steps between pieces
        size = NOISE_SAMPLES // NOISE_PIECES
        steps = np.delete(steps, np.arange(size - 1, len(steps), size))
    still = StaticStream(n, noise, accel="accel" in sensors_in, gyro="gyro" in sensors_in,
                         min_still_s=1.0)  # fmt: skip
    longest_step, last = 0.0, None
    for block in samples.blocks(("time", *sensors_in), start, stop):
        time, raw = block[0], dict(zip(sensors_in, block[1:], strict=True))
        edge = time if last is None else np.concatenate([[last], time])
        if len(edge) > 1:
            longest_step = max(longest_step, float(np.max(np.diff(edge))))
        last = float(time[-1])
        still.add(*(raw[kind] for kind in sensors_in))
        for kind, (to_si, allan, _) in analysed.items():
            allan.add(to_si(raw[kind]))
    if start > 0 or stop < samples.n:  # the rest of /raw/time, as read_session checks it
        samples.check_time(0, start)
        samples.check_time(stop, samples.n)
    return still, longest_step, steps


def _motion_warnings(moved: float, where: str, span: str) -> list[str]:
    """Refuse a recording mostly moving; warn when more than a tenth of it moved."""
    if moved > MOVED_REFUSE_FRACTION:
        raise InputError(
            f"{where}: {span} is not still ({100 * moved:.0f} % of it moved); record the unit "
            "untouched on a steady table (imucal capture --plan still:20)"
        )
    if moved > MOVED_WARN_FRACTION:
        return [f"{100 * moved:.0f} % of the recording moved: the figures include that motion "
                "and are too large"]  # fmt: skip
    return []


def _sensor_noise(analysed: dict[str, tuple]) -> list[SensorNoise]:
    """Step 3: each sensor's Allan curves and the noise figures read from them."""
    sensors: list[SensorNoise] = []
    for kind, (_, allan, basis) in analysed.items():
        curves = allan.curves()
        axes = list("xyz") if len(curves) == 3 else [f"ch{i}" for i in range(len(curves))]
        for axis, curve in zip(axes, curves, strict=True):
            if len(curve.tau_s) == 0:  # every deviation 0: said as 'only 0 averaging times:
                raise InputError(  # the recording is too short' of a minute's recording
                    f"{kind} axis {axis} reads one value through the span analysed (a stuck "
                    "or dead axis): it has no noise to measure; check the sensor"
                )
        sensors.append(SensorNoise(kind, "m/s^2" if kind == "accel" else "rad/s", basis,
                                   axes, [noise_from_curve(c) for c in curves]))  # fmt: skip
    return sensors


def _by_sensor(time: np.ndarray, kinds: tuple[str, ...], arrays: list[np.ndarray]):
    """``(time, accel, gyro)`` with None for a sensor absent."""
    given = dict(zip(kinds, arrays, strict=True))
    return time, given.get("accel"), given.get("gyro")


def load_calibration(path: str | os.PathLike[str]) -> Calibration:
    """A calibration JSON or the last one stored in a session (as ``imucal report`` reads)."""
    return load_for_report(path)


def imu_calibration(cal: Calibration, samples: SessionSamples) -> Calibration:
    """The part of ``cal`` for the IMU ``samples`` holds: of a set's calibration (``imus``),
    that IMU's own sections (the reference's for the reference); a calibration of one IMU
    as it is (the user gave it for this IMU).

    Raises
    ------
    InputError
        A set's calibration without that IMU.
    """
    if not cal.imus or samples.imu is None:
        return cal
    members = set_members(cal)
    if samples.imu == samples.imus[0]:
        return members[0].calibration
    for m in members[1:]:
        if m.name == samples.imu:
            return m.calibration
    raise InputError(f"the calibration has no IMU {samples.imu!r} (it has "
                     f"{', '.join(m.name for m in members)})")  # fmt: skip
