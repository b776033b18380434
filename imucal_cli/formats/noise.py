"""Noise figures JSON (``imucal noise --json``, format ``imucal-noise`` version 1): the reader
the exporters use for filter noise parameters.

``imucal noise`` writes, per sensor and axis, the white-noise density read off the Allan
deviation at tau = 1 s (velocity / angle random walk: ``vrw_m_s_per_sqrt_s``,
``arw_rad_per_sqrt_s``), the rate random walk where the curve shows a +1/2 slope
(``rrw_m_s2_per_sqrt_s``, ``rrw_rad_s_per_sqrt_s``), and the curve itself (``tau_s``,
``adev`` in m/s^2 or rad/s).  This module turns that into :class:`NoiseFigures` in the units
filters take (continuous-time densities):

==========================  =========================  =====================================
figure                      accelerometer              gyroscope
==========================  =========================  =====================================
white noise density         m/s^2/sqrt(Hz)             rad/s/sqrt(Hz)
bias random walk            m/s^3/sqrt(Hz)             rad/s^2/sqrt(Hz)
==========================  =========================  =====================================

(m/s/sqrt(s) equals m/s^2/sqrt(Hz), and m/s^2/sqrt(s) equals m/s^3/sqrt(Hz).)

Where the curve shows no region for a figure, the figure is replaced by the largest value the
curve allows and marked as an upper bound: a white noise ``N`` gives ``sigma(tau) =
N / sqrt(tau)``, so ``N <= min sigma(tau) sqrt(tau)``; a bias random walk ``K`` gives
``sigma(tau) = K sqrt(tau / 3)``, so ``K <= min sigma(tau) sqrt(3 / tau)`` (IEEE Std 952
slopes).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.inputs import read_text_input
from imucal_cli.model.calibration import OFFSET_LIMIT
from imucal_cli.model.session import RATE_RANGE_HZ

__all__ = ["NOISE_FORMAT", "NoiseFigures", "SensorFigures", "noise_from_dict", "read_noise"]

NOISE_FORMAT = "imucal-noise"
NOISE_FORMAT_VERSION = 1

# Per sensor: (key of the white density, key of the random walk, SI unit of the rate)
_KEYS = {
    "accel": ("vrw_m_s_per_sqrt_s", "rrw_m_s2_per_sqrt_s", "m/s^2"),
    "gyro": ("arw_rad_per_sqrt_s", "rrw_rad_s_per_sqrt_s", "rad/s"),
}
WHITE_UNITS = {"accel": "m/s^2/sqrt(Hz)", "gyro": "rad/s/sqrt(Hz)"}
WALK_UNITS = {"accel": "m/s^3/sqrt(Hz)", "gyro": "rad/s^2/sqrt(Hz)"}


@dataclass
class SensorFigures:
    """Continuous-time noise of one sensor, per axis.

    Attributes
    ----------
    kind : str
        ``accel`` or ``gyro``.
    axes : list of str
        Axis names (``x y z``, or ``ch0 ...`` for a redundant unit).
    white : ndarray, shape (n,)
        White-noise density, :data:`WHITE_UNITS`.
    white_bound : list of bool
        True where ``white`` is an upper bound (no -1/2 region on the curve).
    random_walk : ndarray, shape (n,)
        Bias random walk, :data:`WALK_UNITS`.
    random_walk_bound : list of bool
        True where ``random_walk`` is an upper bound (no +1/2 region on the curve).
    """

    kind: str
    axes: list[str]
    white: np.ndarray
    white_bound: list[bool]
    random_walk: np.ndarray
    random_walk_bound: list[bool]

    def worst(self, what: str) -> tuple[float, str, bool]:
        """The largest value of ``white`` or ``random_walk`` over the axes: (value, axis, bound)."""
        values = getattr(self, what)
        i = int(np.argmax(values))
        return float(values[i]), self.axes[i], bool(getattr(self, what + "_bound")[i])


@dataclass
class NoiseFigures:
    """What one ``imucal noise`` run found, ready for a filter's configuration.

    Attributes
    ----------
    source : str
        The file it was read from.
    session : str or None
    rate_hz : float
        Sample rate of the recording analysed, Hz.
    duration_s : float
    accel, gyro : SensorFigures or None
    notes : list of str
        What was bounded rather than measured.
    """

    source: str
    session: str | None
    rate_hz: float
    duration_s: float
    accel: SensorFigures | None = None
    gyro: SensorFigures | None = None
    notes: list[str] = field(default_factory=list)

    def sensor(self, kind: str) -> SensorFigures | None:
        return self.accel if kind == "accel" else self.gyro


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return float(value)


def _curve(axis: dict, fail) -> tuple[np.ndarray, np.ndarray]:
    curve = axis.get("curve")
    if not isinstance(curve, dict):
        raise fail("an axis without a value has no 'curve' to bound it from")
    try:
        tau = np.asarray(curve.get("tau_s"), dtype=float)
        adev = np.asarray(curve.get("adev"), dtype=float)
    except (TypeError, ValueError):
        raise fail("'curve' must hold lists of numbers tau_s and adev") from None
    ok = np.isfinite(tau) & np.isfinite(adev) & (tau > 0) & (adev > 0)
    if tau.ndim != 1 or tau.shape != adev.shape or not ok.any():
        raise fail("'curve' must hold lists of positive numbers tau_s and adev of one length")
    return tau[ok], adev[ok]


def _sensor(kind: str, d: Any, fail) -> SensorFigures:
    white_key, walk_key, unit = _KEYS[kind]
    if not isinstance(d, dict) or not isinstance(d.get("axes"), list) or len(d["axes"]) < 3:
        raise fail(f"sensors.{kind} must be an object with an 'axes' list of 3 or more")
    if d.get("units", unit) != unit:
        raise fail(f"sensors.{kind}.units is {d.get('units')!r}, expected {unit!r}")
    names, white, walk, white_bound, walk_bound = [], [], [], [], []
    for i, axis in enumerate(d["axes"]):
        if not isinstance(axis, dict):
            raise fail(f"sensors.{kind}.axes[{i}] must be an object")
        name = str(axis.get("axis", f"ch{i}"))

        def axis_fail(problem: str, name=name) -> InputError:
            return fail(f"sensors.{kind} axis {name}: {problem}")

        w, k = _number(axis.get(white_key)), _number(axis.get(walk_key))
        if w is not None and w <= 0 or k is not None and k <= 0:
            raise axis_fail(f"{white_key} and {walk_key} must be positive")
        if w is None or k is None:
            tau, adev = _curve(axis, axis_fail)
            if w is None:
                w = float(np.min(adev * np.sqrt(tau)))  # sigma = N / sqrt(tau)
            if k is None:
                k = float(np.min(adev * np.sqrt(3.0 / tau)))  # sigma = K sqrt(tau / 3)
        if not (w <= OFFSET_LIMIT[unit] and k <= OFFSET_LIMIT[unit]):  # 1e300: an overflow
            raise axis_fail(f"{white_key} or {walk_key} is beyond any sensor (more than "
                            f"{OFFSET_LIMIT[unit]:g} {WHITE_UNITS[kind]} or "
                            f"{WALK_UNITS[kind]})")  # fmt: skip
        names.append(name)
        white.append(w)
        walk.append(k)
        white_bound.append(_number(axis.get(white_key)) is None)
        walk_bound.append(_number(axis.get(walk_key)) is None)
    return SensorFigures(kind, names, np.array(white), white_bound, np.array(walk), walk_bound)


def noise_from_dict(d: Any, source: str = "<dict>") -> NoiseFigures:
    """Validate an ``imucal noise --json`` document and return its figures.

    Raises
    ------
    InputError
        Not a noise document, or a figure missing with no curve to bound it; one line naming
        ``source``.
    """

    def fail(problem: str) -> InputError:
        return InputError(f"{source}: {problem}")

    if not isinstance(d, dict) or d.get("format") != NOISE_FORMAT:
        got = d.get("format") if isinstance(d, dict) else type(d).__name__
        raise fail(f"not an imucal noise file (format {got!r}; make one with imucal noise --json)")
    if d.get("format_version") != NOISE_FORMAT_VERSION:
        raise fail(f"unsupported format_version {d.get('format_version')!r}")
    rate, duration = _number(d.get("rate_hz")), _number(d.get("duration_s"))
    lo, hi = RATE_RANGE_HZ
    if rate is None or not lo <= rate <= hi:  # 1e300 Hz was written as the filter's rate
        raise fail(f"rate_hz must be an IMU's sample rate ({lo:g} to {hi:g} Hz), got "
                   f"{d.get('rate_hz')!r}")  # fmt: skip
    sensors = d.get("sensors")
    if not isinstance(sensors, dict):
        raise fail("'sensors' must be an object")
    figures = NoiseFigures(
        source=source,
        session=d.get("session") if isinstance(d.get("session"), str) else None,
        rate_hz=rate,
        duration_s=duration or 0.0,
        **{k: _sensor(k, sensors[k], fail) for k in ("accel", "gyro") if k in sensors},
    )
    if figures.accel is None and figures.gyro is None:
        raise fail("holds neither accelerometer nor gyroscope figures")
    for s in (figures.accel, figures.gyro):
        if s is None:
            continue
        for what, flags, slope in (("white noise", s.white_bound, "-1/2"),
                                   ("bias random walk", s.random_walk_bound, "+1/2")):  # fmt: skip
            axes = [a for a, b in zip(s.axes, flags, strict=True) if b]
            if axes:
                figures.notes.append(
                    f"{s.kind} {what} on axes {', '.join(axes)}: no {slope} slope on the Allan "
                    "curve, written as the upper bound the curve allows"
                )
    return figures


def read_noise(path: str | os.PathLike) -> NoiseFigures:
    """Read an ``imucal noise --json`` file.

    Raises
    ------
    InputError
        Missing or unreadable file, invalid JSON, or not a noise document.
    """
    src = str(path)
    text = read_text_input(path, what="noise file")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{src}: invalid JSON at line {exc.lineno}: {exc.msg}") from None
    except (ValueError, RecursionError) as exc:
        raise InputError(f"{src}: invalid JSON ({' '.join(str(exc).split())[:120]})") from None
    return noise_from_dict(doc, src)
