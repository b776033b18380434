"""Accuracy targets: ``imucal capture --until accel=0.05%,gyro=0.05%`` and ``[targets]`` in a
config.

A target is the largest standard deviation (1 std, the worst axis) a term of a calibration may
have, in the units the report uses: a **gain** in % (the sensitivity's relative std), a
**bias** in mg (accelerometer) or deg/s (gyroscope), a **misalignment** in degrees (the angles
between the sensor's own axes, minus 90, as ``misalignment_deg`` reports them).

``--until`` text is a comma-separated list of

``SENSOR.TERM=VALUE UNIT``
    one term: ``accel.gain=0.05%``, ``accel.bias=0.5mg``, ``gyro.bias=0.01deg/s``,
    ``gyro.misalignment=0.05deg`` (units: :data:`UNITS`);
``SENSOR=X%``
    every term of the sensor at the same relative size: the gain X %, the bias X % of a
    reference reading (1 g for the accelerometer, :data:`GYRO_REFERENCE_DPS` deg/s for the
    gyroscope), the misalignment the angle whose cross-axis error is X % of a reading (X/100
    rad).  ``accel=0.05%,gyro=0.05%``: gains 0.05 %, biases 0.49 mg and 0.01 deg/s,
    misalignments 0.029 deg.

A term named twice keeps the last value; a ``[targets]`` table of a config gives the same
terms (``gain_pct``, ``bias_mg`` / ``bias_dps``, ``misalignment_deg``), and ``--until`` then
overrides it term by term (:func:`merged`).

:func:`measure` reads each target's current std from a :class:`Calibration` (its sections'
``sensitivity``/``sensitivity_std``, the bias rows' ``std`` and ``misalignment_std_deg``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.model.calibration import Calibration, SensorCalibration

from .config import TargetsConfig

__all__ = [
    "GYRO_REFERENCE_DPS",
    "STANDARD_GRAVITY",
    "TERMS",
    "UNITS",
    "Target",
    "brief",
    "TargetStatus",
    "Targets",
    "measure",
    "merged",
    "parse_until",
    "targets_from_config",
]

STANDARD_GRAVITY = 9.80665
"""m/s^2 per g (mg figures, as the report's)."""

GYRO_REFERENCE_DPS = 20.0
"""The reading ``gyro=X%`` refers its bias to: a slow hand turn, deg/s (0.05 % -> 0.01 deg/s)."""

TERMS = {
    "accel": {"gain": "%", "bias": "mg", "misalignment": "deg"},
    "gyro": {"gain": "%", "bias": "deg/s", "misalignment": "deg"},
}
"""Sensors, their terms and each term's unit (the report's)."""

UNITS = {
    "gain": {"%": 1.0, "ppm": 1e-4},
    "accel.bias": {"mg": 1.0, "ug": 1e-3, "g": 1e3, "m/s^2": 1e3 / STANDARD_GRAVITY},
    "gyro.bias": {"deg/s": 1.0, "dps": 1.0, "deg/h": 1.0 / 3600.0, "rad/s": 180.0 / math.pi,
                  "mrad/s": 0.18 / math.pi},
    "misalignment": {"deg": 1.0, "mrad": 0.18 / math.pi, "arcmin": 1.0 / 60.0},
}  # fmt: skip
"""Units accepted per term, and the factor to the term's own unit (:data:`TERMS`)."""

_CONFIG_KEYS = {"gain": "gain_pct", "accel.bias": "bias_mg", "gyro.bias": "bias_dps",
                "misalignment": "misalignment_deg"}  # fmt: skip

_ITEM = re.compile(r"^(accel|gyro)(?:\.(gain|bias|misalignment))?=\s*([-+0-9.eE]+)\s*(\S*)$")


def _unit_table(sensor: str, term: str) -> dict[str, float]:
    return UNITS.get(f"{sensor}.{term}") or UNITS[term]


@dataclass(frozen=True)
class Target:
    """One target: the largest std ``value`` (in ``unit``, :data:`TERMS`) of ``sensor``'s
    ``term``, the worst axis."""

    sensor: str
    term: str
    value: float

    @property
    def unit(self) -> str:
        return TERMS[self.sensor][self.term]

    @property
    def key(self) -> str:
        """``"accel.gain"``."""
        return f"{self.sensor}.{self.term}"

    def describe(self) -> str:
        """``"accel gain 0.05 %"``."""
        return f"{self.sensor} {self.term} {self.value:.2g} {self.unit}"


@dataclass(frozen=True)
class Targets:
    """The targets of a capture, in :data:`TERMS` order (empty: none)."""

    items: tuple[Target, ...] = ()

    def __bool__(self) -> bool:
        return bool(self.items)

    def __iter__(self):
        return iter(self.items)

    def get(self, sensor: str, term: str) -> Target | None:
        return next((t for t in self.items if t.sensor == sensor and t.term == term), None)

    def sensors(self) -> tuple[str, ...]:
        """The sensors with a target, in :data:`TERMS` order."""
        return tuple(s for s in TERMS if any(t.sensor == s for t in self.items))

    def describe(self) -> str:
        """``"accel gain 0.05 %, bias 0.49 mg, ...; gyro ..."``."""
        parts = []
        for sensor in self.sensors():
            terms = [t for t in self.items if t.sensor == sensor]
            parts.append(f"{sensor} " + ", ".join(f"{t.term} {t.value:.2g} {t.unit}"
                                                 for t in terms))  # fmt: skip
        return "; ".join(parts)


def _ordered(values: dict[tuple[str, str], float]) -> Targets:
    return Targets(tuple(Target(s, t, values[(s, t)]) for s in TERMS for t in TERMS[s]
                         if (s, t) in values))  # fmt: skip


def _shorthand(sensor: str, pct: float) -> dict[tuple[str, str], float]:
    """``SENSOR=X%``: every term at X % of a reading (see the module notes)."""
    bias = 10.0 * pct if sensor == "accel" else pct / 100.0 * GYRO_REFERENCE_DPS
    return {(sensor, "gain"): pct, (sensor, "bias"): bias,
            (sensor, "misalignment"): math.degrees(pct / 100.0)}  # fmt: skip


def parse_until(text: str, option: str = "--until") -> Targets:
    """The targets of ``--until`` text (see the module notes).

    Raises
    ------
    InputError
        One line naming the item that is wrong and what would be right.
    """
    values: dict[tuple[str, str], float] = {}
    items = [item.strip() for item in str(text).split(",")]
    if not any(items):
        raise InputError(f"{option}: give targets, e.g. accel=0.05%,gyro=0.05% or "
                         "accel.bias=0.5mg")  # fmt: skip
    for item in items:
        m = _ITEM.match(item.replace(" ", ""))
        if not m:
            raise InputError(
                f"{option} {item!r}: expected SENSOR=X% or SENSOR.TERM=VALUE UNIT, sensors "
                "accel and gyro, terms gain, bias, misalignment (e.g. accel=0.05%, "
                "gyro.bias=0.01deg/s)"
            )
        sensor, term, number, unit = m.groups()
        try:
            value = float(number)
        except ValueError:
            raise InputError(f"{option} {item!r}: {number!r} is not a number") from None
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"{option} {item!r}: a target must be a positive number")
        if term is None:
            if unit != "%":
                raise InputError(f"{option} {item!r}: {sensor}=X% sets every term at X %; "
                                 f"for one term write {sensor}.gain=, .bias= or "
                                 ".misalignment= with its unit")  # fmt: skip
            values.update(_shorthand(sensor, value))
            continue
        table = _unit_table(sensor, term)
        if unit not in table:
            raise InputError(f"{option} {item!r}: {sensor} {term} in "
                             f"{', '.join(table)}" + ("" if unit else " (give a unit)"))
        values[(sensor, term)] = value * table[unit]
    return _ordered(values)


def targets_from_config(cfg: TargetsConfig) -> Targets:
    """The targets of a config's ``[targets]`` table (its unset keys: no target)."""
    values = {}
    for sensor in TERMS:
        table = getattr(cfg, sensor)
        for term in TERMS[sensor]:
            key = _CONFIG_KEYS.get(f"{sensor}.{term}") or _CONFIG_KEYS[term]
            value = getattr(table, key)
            if value is not None:
                values[(sensor, term)] = float(value)
    return _ordered(values)


def merged(base: Targets, override: Targets) -> Targets:
    """``base`` with each term ``override`` names replaced (``--until`` over a config)."""
    values = {(t.sensor, t.term): t.value for t in base}
    values.update({(t.sensor, t.term): t.value for t in override})
    return _ordered(values)


# --------------------------------------------------------------------------------------------
# The std of a calibration's terms
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TargetStatus:
    """A target and what the calibration states: ``std`` (the worst axis, in the target's
    unit; None when the calibration does not determine it), ``axis`` (the worst) and
    ``why`` (what is missing, when ``std`` is None)."""

    target: Target
    std: float | None
    axis: str = ""
    why: str = ""

    @property
    def met(self) -> bool:
        return self.std is not None and self.std <= self.target.value

    @property
    def ratio(self) -> float:
        """``std / target`` (inf when not determined)."""
        return math.inf if self.std is None else self.std / self.target.value

    def describe(self) -> str:
        """``"accel gain 0.031 % (z) <= 0.05 %: met"``, ``"gyro bias: not determined yet"``."""
        t = self.target
        if self.std is None:
            return f"{t.sensor} {t.term}: not determined yet" + (f" ({self.why})" if self.why
                                                                 else "")  # fmt: skip
        sign, verdict = ("<=", "met") if self.met else (">", "not yet")
        axis = f" ({self.axis})" if self.axis else ""
        return (f"{t.sensor} {t.term} {self.std:.2g} {t.unit}{axis} {sign} {t.value:.2g} "
                f"{t.unit}: {verdict}")  # fmt: skip


_AXES = "xyz"


def _worst(values: np.ndarray | list, names: list[str]) -> tuple[float | None, str]:
    v = np.asarray(values, float)
    if v.size == 0 or not np.all(np.isfinite(v)):
        return None, ""
    k = int(np.argmax(v))
    return float(v[k]), names[k]


def section_std(sensor: str, sec: SensorCalibration | None) -> dict[str, tuple[float | None, str]]:
    """The std of each term of ``sensor``'s section (:data:`TERMS` units, the worst axis and
    its name); ``(None, "")`` for a term the section does not state."""
    out: dict[str, tuple[float | None, str]] = {t: (None, "") for t in TERMS[sensor]}
    if sec is None:
        return out
    s, s_std = sec.sensitivity, sec.sensitivity_std
    if s is not None and s_std is not None and len(s) == len(s_std) == 3:
        gains = 100.0 * np.asarray(s_std, float) / np.abs(np.asarray(s, float))
        out["gain"] = _worst(gains, list(_AXES))
        rows = {p.name: p.std for p in sec.parameters or []}
        b_std = [rows.get(f"b_{a}") for a in _AXES]
        if all(isinstance(x, int | float) for x in b_std):
            per = np.asarray(b_std, float) / np.abs(np.asarray(s, float))  # SI units
            scale = 1e3 / STANDARD_GRAVITY if sensor == "accel" else 180.0 / math.pi
            out["bias"] = _worst(per * scale, list(_AXES))
    mis = sec.misalignment_std_deg
    if isinstance(mis, dict) and mis:
        out["misalignment"] = _worst(list(mis.values()), list(mis))
    return out


def brief(statuses: list[TargetStatus]) -> str:
    """Every target in one line, by sensor: ``"accel gain 0.031/0.05 %, bias 0.2/0.49 mg
    (met), misalignment 0.12/0.029 deg; gyro: not calibrated yet"``."""
    parts = []
    for sensor in TERMS:
        mine = [s for s in statuses if s.target.sensor == sensor]
        if not mine:
            continue
        if all(s.std is None for s in mine):
            parts.append(f"{sensor}: not calibrated yet")
            continue
        terms = []
        for s in mine:
            t = s.target
            got = "-" if s.std is None else f"{s.std:.2g}"
            terms.append(f"{t.term} {got}/{t.value:.2g} {t.unit}" + (" (met)" if s.met else ""))
        parts.append(f"{sensor} " + ", ".join(terms))
    return "; ".join(parts)


def measure(cal: Calibration | None, targets: Targets,
            notes: dict[str, str] | None = None) -> list[TargetStatus]:  # fmt: skip
    """Each target against what ``cal`` states (None: nothing calibrated yet); ``notes``:
    why a sensor is not calibrated, per sensor (a refit's refusal)."""
    out = []
    notes = notes or {}
    for sensor in targets.sensors():
        sec = None if cal is None else getattr(cal, sensor)
        stds = section_std(sensor, sec)
        for t in (t for t in targets if t.sensor == sensor):
            std, axis = stds[t.term]
            why = ""
            if std is None:
                why = notes.get(sensor) or ("not calibrated yet" if sec is None else
                                            f"the {sec.solver} solver does not state it")
            out.append(TargetStatus(t, std, axis, why))
    return out
