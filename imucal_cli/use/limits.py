"""Acceptance limits of a product (issue 29.2): the TOML file, the figures of a calibration they
bound, and the verdict of a unit.

A product file::

    [product]
    name = "IMU-9000"

    [limits.accel]
    units = "m/s^2"                # optional: the calibration's units these limits are in
    bias_max = 0.5                 # |bias| per axis, calibration units (matrix @ bias)
    nominal_sensitivity = 835.0    # raw units per m/s^2 (one, or one per axis): gain error's 0
    gain_error_max_pct = 3.0       # |sensitivity / nominal - 1| per axis, %
    misalignment_max_deg = 1.0     # |angle between two sensitivity axes - 90 deg|
    noise_max = 0.02               # white noise per sample and axis, calibration units
    residual_rms_max = 0.005       # the fit's residual_rms, calibration units
    held_out_rms_max = 0.01        # held-out RMS (accel: rms_loo; mag: rms_held_out)

    [limits.gyro]
    bias_max = 0.05                # rad/s
    ...

Every number is in the unit the calibration states for it: ``bias``, ``noise``, the residuals
in the section's output ``units`` (m/s^2, rad/s, uT), gain error in %, misalignment in degrees.
A limit whose figure the calibration does not state (a sensor not calibrated, a held-out RMS
the solver does not give) fails the unit, naming why: a unit is accepted only on what was
measured.

The figures (:func:`unit_figures`) are the history's tracked parameters
(:func:`~imucal_cli.use.report.history.tracked_rows`: ``b_x``, ``sensitivity x``,
``misalignment xy``, ...) and the acceptance figures of :func:`section_figures` (``bias x``,
``noise x``, ``residual rms``, ``held-out rms``); :func:`judge` reads only these rows, so that
the registry judges (and computes Cpk of) units from its stored rows exactly as ``calibrate``
judges a fresh calibration.
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from imucal_cli.errors import ConfigError
from imucal_cli.formats.inputs import read_text_input
from imucal_cli.model.calibration import SENSORS, Calibration, SensorCalibration

from .report.fields import as_list, as_number, as_text
from .report.history import section_basis, tracked_rows

__all__ = [
    "LIMIT_KEYS", "Acceptance", "Check", "Limit", "ProductLimits", "judge", "judge_calibration",
    "limits_from_dict", "load_limits", "section_figures", "unit_figures",
]  # fmt: skip

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class LimitKind:
    """What one key of a ``[limits.SENSOR]`` table bounds."""

    figure: str  #: the figure rows it bounds: ``"bias"`` bounds ``bias x``, ``bias y``, ...
    two_sided: bool  #: ``|value| <= max`` (a spec of -max..max), else ``value <= max``
    unit: str | None  #: fixed unit, or None: the section's output units
    meaning: str


LIMIT_KEYS: dict[str, LimitKind] = {
    "bias_max": LimitKind("bias", True, None, "|bias| per axis (matrix @ bias)"),
    "gain_error_max_pct": LimitKind(
        "gain error", True, "%", "|sensitivity / nominal_sensitivity - 1| per axis"
    ),
    "misalignment_max_deg": LimitKind(
        "misalignment", True, "deg", "|angle between two sensitivity axes - 90 deg|"
    ),
    "noise_max": LimitKind("noise", False, None, "white noise per sample and axis"),
    "residual_rms_max": LimitKind("residual rms", False, None, "the fit's residual RMS"),
    "held_out_rms_max": LimitKind("held-out rms", False, None, "held-out RMS"),
}
"""The limit keys of a ``[limits.SENSOR]`` table."""

_OTHER_KEYS = ("units", "nominal_sensitivity")


@dataclass(frozen=True)
class Limit:
    """One limit: ``sensor``'s figures named ``kind.figure <...>`` at most ``maximum``."""

    sensor: str
    key: str
    maximum: float

    @property
    def kind(self) -> LimitKind:
        return LIMIT_KEYS[self.key]

    def bounds(self, name: str) -> bool:
        """Whether this limit bounds the figure row ``name``."""
        figure = self.kind.figure
        return name == figure or name.startswith(figure + " ")


@dataclass(frozen=True)
class ProductLimits:
    """A product file: its name, its limits, the units they are in, nominal sensitivities.

    Attributes
    ----------
    product : str or None
    limits : tuple of Limit
    units : dict
        ``{sensor: units}`` declared (``units = "m/s^2"``): a calibration in other units fails.
    nominal : dict
        ``{sensor: (s,) or (s_x, s_y, s_z)}`` nominal sensitivity, raw units per output unit.
    source : str
        Where they came from (the file, or ``"registry"``).
    """

    product: str | None
    limits: tuple[Limit, ...]
    units: dict[str, str] = field(default_factory=dict)
    nominal: dict[str, tuple[float, ...]] = field(default_factory=dict)
    source: str = "<dict>"

    def for_sensor(self, sensor: str) -> list[Limit]:
        return [lim for lim in self.limits if lim.sensor == sensor]

    def to_dict(self) -> dict[str, Any]:
        """The product file as a JSON-ready dict (what :func:`limits_from_dict` reads)."""
        tables: dict[str, dict[str, Any]] = {}
        for sensor in SENSORS:
            table: dict[str, Any] = {}
            if sensor in self.units:
                table["units"] = self.units[sensor]
            if sensor in self.nominal:
                nominal = self.nominal[sensor]
                table["nominal_sensitivity"] = nominal[0] if len(nominal) == 1 else list(nominal)
            table.update({lim.key: lim.maximum for lim in self.for_sensor(sensor)})
            if table:
                tables[sensor] = table
        out: dict[str, Any] = {"limits": tables}
        if self.product:
            out = {"product": {"name": self.product}, **out}
        return out


def load_limits(path: str | os.PathLike) -> ProductLimits:
    """Read and check a product file (TOML; see the module notes).

    Raises
    ------
    ConfigError
        Unreadable, not TOML, an unknown key, a limit that is not a positive number, a gain
        error limit without ``nominal_sensitivity``, or no limit at all; one line.
    """
    text = read_text_input(path, what="product file", max_bytes=1 << 20, error=ConfigError)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({' '.join(str(exc).split())})") from None
    except RecursionError:
        raise ConfigError(f"{path}: not valid TOML (nested too deeply)") from None
    return limits_from_dict(data, str(path))


def limits_from_dict(data: Any, source: str) -> ProductLimits:
    """Check a parsed product file (TOML, or the JSON the registry keeps) and build it.

    Raises
    ------
    ConfigError
        See :func:`load_limits`.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a product file is a table ([product], [limits.SENSOR])")
    unknown = sorted(set(data) - {"product", "limits"})
    if unknown:
        raise ConfigError(f"{source}: unknown key `{unknown[0]}` (a product file has [product] "
                          "and [limits.accel], [limits.gyro], [limits.mag])")  # fmt: skip
    product = _product_name(data.get("product", {}), source)
    tables = data.get("limits")
    if not isinstance(tables, dict) or not tables:
        raise ConfigError(f"{source}: no limits: give [limits.accel], [limits.gyro] or "
                          "[limits.mag] with e.g. bias_max = 0.5")  # fmt: skip
    limits: list[Limit] = []
    units: dict[str, str] = {}
    nominal: dict[str, tuple[float, ...]] = {}
    for sensor, table in tables.items():
        where = f"{source}: [limits.{sensor}]"
        if sensor not in SENSORS:
            raise ConfigError(f"{source}: unknown sensor [limits.{sensor}] (accel, gyro, mag)")
        if not isinstance(table, dict):
            raise ConfigError(f"{where} must be a table")
        for key, value in table.items():
            if key == "units":
                if not isinstance(value, str) or not value.strip():
                    raise ConfigError(f"{where}: `units` must be a unit such as \"m/s^2\"")
                units[sensor] = value.strip()
            elif key == "nominal_sensitivity":
                nominal[sensor] = _nominal(value, where)
            elif key in LIMIT_KEYS:
                limits.append(Limit(sensor, key, _positive(value, key, where)))
            else:
                known = ", ".join((*LIMIT_KEYS, *_OTHER_KEYS))
                raise ConfigError(f"{where}: unknown key `{key}` (known: {known})")
        if "gain_error_max_pct" in table and sensor not in nominal:
            raise ConfigError(f"{where}: gain_error_max_pct needs nominal_sensitivity (raw units "
                              "per output unit; 1 for raw data already in SI units)")  # fmt: skip
    if not limits:
        raise ConfigError(f"{source}: no limits: give e.g. bias_max = 0.5 in [limits.accel]")
    return ProductLimits(product, tuple(limits), units, nominal, source)


def _product_name(table: Any, source: str) -> str | None:
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: [product] must be a table (name = \"...\")")
    unknown = sorted(set(table) - {"name"})
    if unknown:
        raise ConfigError(f"{source}: [product]: unknown key `{unknown[0]}` (known: name)")
    name = table.get("name")
    if name is not None and (not isinstance(name, str) or not name.strip()):
        raise ConfigError(f"{source}: [product] name must be text")
    return None if name is None else name.strip()


def _positive(value: Any, key: str, where: str) -> float:
    number = as_number(value)
    if number is None or number <= 0:
        raise ConfigError(f"{where}: `{key}` must be a positive number, not {value!r}")
    return number


def _nominal(value: Any, where: str) -> tuple[float, ...]:
    values = value if isinstance(value, list) else [value]
    numbers = [as_number(v) for v in values]
    if len(numbers) not in (1, 3) or any(n is None or n <= 0 for n in numbers):
        raise ConfigError(f"{where}: `nominal_sensitivity` must be one positive number or one "
                          f"per axis (3), not {value!r}")  # fmt: skip
    return tuple(float(n) for n in numbers)  # type: ignore[arg-type]


# --------------------------------------------------------------------------------------------
# The figures of a calibration


def section_figures(sec: SensorCalibration) -> list[dict[str, Any]]:
    """The acceptance figures of one section that no limit changes: ``name``, ``unit``,
    ``value``, ``std``.

    - ``bias x|y|z``: the bias in output units, ``matrix @ bias`` (the reading of a sensor at
      rest in zero input, as the calibration corrects it); std propagated from the raw bias std
      through the matrix (its own uncertainty, second order, left out);
    - ``noise x|y|z``: the pooled white noise per sample, output units: ``sqrt(diag(M diag(
      sigma^2) M^T))`` of the raw per-channel noise (accel ``noise.per_sample_std``, gyro
      ``gyro_noise_raw``);
    - ``residual rms``: the section's ``residual_rms``;
    - ``held-out rms``: accel ``rms_loo``, mag ``rms_held_out``.
    """
    matrix = np.asarray(sec.matrix, dtype=float)
    bias = np.asarray(sec.bias, dtype=float).ravel()
    rows: list[dict[str, Any]] = []
    if matrix.shape == (3, bias.size):
        out = matrix @ bias
        raw_std = _raw_bias_std(sec, bias.size)
        std = None if raw_std is None else np.sqrt((matrix**2) @ raw_std**2)
        rows += [_row(f"bias {a}", sec.units, out[i], None if std is None else std[i])
                 for i, a in enumerate(AXES)]  # fmt: skip
        sigma = _raw_noise(sec, bias.size)
        if sigma is not None:
            noise = np.sqrt((matrix**2) @ sigma**2)
            rows += [_row(f"noise {a}", sec.units, noise[i], None) for i, a in enumerate(AXES)]
    rows.append(_row("residual rms", sec.units, sec.residual_rms, None))
    held_out = as_number(getattr(sec, "rms_loo", None))
    if held_out is None:
        held_out = as_number(getattr(sec, "rms_held_out", None))
    if held_out is not None:
        rows.append(_row("held-out rms", sec.units, held_out, None))
    return [r for r in rows if r["value"] is not None]


def _row(name: str, unit: str | None, value: Any, std: Any) -> dict[str, Any]:
    return {"name": name, "unit": unit, "value": as_number(value), "std": as_number(std)}


def _raw_bias_std(sec: SensorCalibration, n: int) -> np.ndarray | None:
    """The raw bias std per channel from the parameter rows ``b_*`` (in channel order)."""
    stds = [as_number(p.std) for p in sec.parameters or [] if p.name.startswith("b_")]
    if len(stds) != n or any(s is None for s in stds):
        return None
    return np.asarray(stds, dtype=float)


def _raw_noise(sec: SensorCalibration, n: int) -> np.ndarray | None:
    """Raw white noise per channel: accel ``noise.per_sample_std``, gyro ``gyro_noise_raw``."""
    noise = getattr(sec, "noise", None)
    values = as_list(getattr(noise, "per_sample_std", None))
    gyro_noise = as_number(getattr(sec, "gyro_noise_raw", None))
    if not values and gyro_noise is not None:
        values = [gyro_noise] * n
    numbers = [as_number(v) for v in values]
    if len(numbers) == 1:
        numbers *= n
    if len(numbers) != n or any(v is None for v in numbers):
        return None
    return np.asarray(numbers, dtype=float)


def unit_figures(cal: Calibration) -> dict[str, dict[str, Any]]:
    """Every figure of a calibration, per sensor: ``{sensor: {"units", "units_in", "solver",
    "basis", "rows": [{name, unit, value, std, tracked}]}}``; ``tracked`` marks the history's
    parameters (:func:`~imucal_cli.use.report.history.tracked_rows`), the others are
    :func:`section_figures`."""
    out = {}
    for sensor, sec in cal.sections().items():
        tracked = [{**r, "tracked": True} for r in tracked_rows(sec)]
        figures = [{**r, "tracked": False} for r in section_figures(sec)]
        out[sensor] = {
            "units": sec.units,
            "units_in": as_text(sec.units_in),
            "solver": sec.solver,
            "basis": section_basis(sensor, sec),
            "rows": tracked + figures,
        }
    return out


# --------------------------------------------------------------------------------------------
# The verdict


@dataclass(frozen=True)
class Check:
    """One figure against one limit; ``value`` None when not stated (then not ``passed``)."""

    sensor: str
    figure: str
    key: str
    value: float | None
    std: float | None
    maximum: float
    unit: str | None
    passed: bool
    note: str = ""

    def line(self) -> str:
        """``accel bias x: 0.62 m/s^2 > 0.5`` (or why it could not be checked)."""
        unit = f" {self.unit}" if self.unit else ""
        if self.value is None:
            return f"{self.sensor} {self.figure}: {self.note} (limit {self.maximum:g}{unit})"
        op = "<=" if self.passed else ">"
        shown = abs(self.value) if LIMIT_KEYS[self.key].two_sided else self.value
        sign = "|" if LIMIT_KEYS[self.key].two_sided else ""
        return f"{self.sensor} {sign}{self.figure}{sign}: {shown:.4g}{unit} {op} {self.maximum:g}"


@dataclass(frozen=True)
class Acceptance:
    """A unit's verdict against a product's limits: every check, the failed ones named."""

    product: str | None
    checks: tuple[Check, ...]
    source: str

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)

    @property
    def verdict(self) -> str:
        return "pass" if self.passed else "fail"

    @property
    def failed(self) -> list[str]:
        """One line per failed check (:meth:`Check.line`)."""
        return [c.line() for c in self.checks if not c.passed]

    def to_dict(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict, "product": self.product, "limits_source": self.source,
            "failed": self.failed,
            "checks": [{"sensor": c.sensor, "figure": c.figure, "limit": c.key,
                        "value": c.value, "std": c.std, "maximum": c.maximum, "unit": c.unit,
                        "passed": c.passed, "note": c.note or None} for c in self.checks],
        }  # fmt: skip


def gain_error_rows(rows: list[dict[str, Any]], nominal: tuple[float, ...]) -> list[dict]:
    """``gain error <axis>`` (%) of the ``sensitivity <axis>`` rows against ``nominal``:
    ``100 (s / s_nominal - 1)``, std ``100 std(s) / s_nominal``."""
    sens = [r for r in rows if r["name"].startswith("sensitivity ")]
    out = []
    for i, r in enumerate(sens):
        s0 = nominal[0] if len(nominal) == 1 else nominal[min(i, len(nominal) - 1)]
        value = None if r["value"] is None else 100.0 * (r["value"] / s0 - 1.0)
        std = None if r.get("std") is None else 100.0 * r["std"] / s0
        out.append({"name": "gain error " + r["name"][len("sensitivity ") :], "unit": "%",
                    "value": value, "std": std, "tracked": False})  # fmt: skip
    return out


def judge(figures: dict[str, dict[str, Any]], limits: ProductLimits) -> Acceptance:
    """Every limit of ``limits`` against the figures of one unit (:func:`unit_figures`, or the
    same rows as the registry keeps them).

    Returns
    -------
    Acceptance
        One :class:`Check` per figure a limit bounds (a limit with no such figure: one failed
        check saying why).
    """
    checks: list[Check] = []
    for lim in limits.limits:
        section = figures.get(lim.sensor)
        if section is None:
            checks.append(_missing(lim, "not calibrated"))
            continue
        declared = limits.units.get(lim.sensor)
        if declared and declared != section["units"] and lim.kind.unit is None:
            checks.append(_missing(lim, f"calibrated in {section['units']}, limits in "
                                        f"{declared}: not comparable"))  # fmt: skip
            continue
        rows = section["rows"]
        if lim.key == "gain_error_max_pct":
            rows = gain_error_rows(rows, limits.nominal[lim.sensor])
        bounded = [r for r in rows if lim.bounds(r["name"])]
        if not bounded:
            checks.append(_missing(lim, "not stated in the calibration"))
            continue
        unit = lim.kind.unit or section["units"]
        for r in bounded:
            value = r["value"]
            ok = value is not None and math.isfinite(value) and (
                abs(value) <= lim.maximum if lim.kind.two_sided else value <= lim.maximum)
            checks.append(Check(lim.sensor, r["name"], lim.key, value, r.get("std"),
                                lim.maximum, unit, ok,
                                "" if value is not None else "not determined"))  # fmt: skip
    return Acceptance(limits.product, tuple(checks), limits.source)


def _missing(lim: Limit, note: str) -> Check:
    return Check(lim.sensor, lim.kind.figure, lim.key, None, None, lim.maximum, lim.kind.unit,
                 False, note)  # fmt: skip


def judge_calibration(cal: Calibration, limits: ProductLimits) -> Acceptance:
    """:func:`judge` of a calibration as read: the reference IMU's sensors, then, in a set of
    several IMUs (``imus``), each other IMU's against the same limits (their checks named
    ``"imu1 accel"``, ...): a unit passes when every IMU on it does."""
    checks = list(judge(unit_figures(cal), limits).checks)
    for key, entry in (cal.imus or {}).items():
        checks += [replace(c, sensor=f"{key} {c.sensor}")
                   for c in judge(unit_figures(entry), limits).checks]  # fmt: skip
    return Acceptance(limits.product, tuple(checks), limits.source)
