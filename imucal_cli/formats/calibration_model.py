"""The calibration model (``shared/spec/session-format.md``, version 1): one
:class:`SensorCalibration` per calibrated sensor and the :class:`Calibration` that holds them,
built from the JSON document's dict (validated) and turned back into it.

For each sensor present, the calibrated 3-vector in SI units is::

    calibrated = matrix @ (raw - bias)

with ``bias`` (length n) in raw units and ``matrix`` of shape (3, n).  Fields a solver adds
beyond the standard ones are kept in ``extra`` dictionaries and written back unchanged.

Files are read and written by :mod:`imucal_cli.formats.calibration` (imucal's JSON, and other
tools' calibrations through :mod:`imucal_cli.formats.foreign_calibration`), which also gives
these names.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

import numpy as np

from imucal_cli.errors import CalibrationFileError

FORMAT = "imucal-calibration"
FORMAT_VERSION = 1
MODEL_EQUATION = "calibrated = matrix @ (raw - bias)"
SENSOR_UNITS = {"accel": "m/s^2", "gyro": "rad/s", "mag": "uT"}
SENSORS = ("accel", "gyro", "mag")
#: Units of a ``mag`` section calibrated without a known field magnitude: the calibrated
#: vector's magnitude is 1 at the local field.
LOCAL_FIELD = "local field"
_ALLOWED_UNITS = {"accel": ("m/s^2",), "gyro": ("rad/s",), "mag": ("uT", LOCAL_FIELD)}

_ROOT_FIELDS = ("format", "format_version", "session", "created", "accel", "gyro", "mag")
_SECTION_FIELDS = ("solver", "units", "bias", "matrix", "residual_rms")


def _utc_now_iso() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


@dataclass
class SensorCalibration:
    """Calibration of one sensor: ``calibrated = matrix @ (raw - bias)``.

    Attributes
    ----------
    solver : str
        Name of the solver that produced it, e.g. ``"gravity"``.
    units : str
        Units of the calibrated output: ``"m/s^2"`` (accel), ``"rad/s"`` (gyro), ``"uT"`` or
        ``"local field"`` (mag: hard iron ``bias``, soft iron ``matrix``).
    bias : ndarray, shape (n,)
        Bias in raw units, n >= 3 raw channels.
    matrix : ndarray, shape (3, n)
        Maps bias-free raw channels to the calibrated 3-vector.
    residual_rms : float or None
        RMS of what the solver minimised, in ``units``.
    extra : dict
        Every other field of the section, preserved on a round trip.
    """

    solver: str
    units: str
    bias: np.ndarray
    matrix: np.ndarray
    residual_rms: float | None = None
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.bias = np.asarray(self.bias, dtype=np.float64)
        self.matrix = np.asarray(self.matrix, dtype=np.float64)

    @property
    def g_sensitivity(self) -> np.ndarray | None:
        """The optional ``g_sensitivity`` term (n x 3, raw units per m/s^2), None when absent
        or all zero.

        Raises
        ------
        CalibrationFileError
            Present but not n x 3 finite numbers.
        """
        value = self.extra.get("g_sensitivity")
        if value is None:
            return None
        try:
            g = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            g = np.empty(0)
        n = self.bias.shape[0]
        if g.shape != (n, 3) or not np.isfinite(g).all():
            raise CalibrationFileError(f"g_sensitivity must be {n} x 3 finite numbers")
        return g if g.any() else None

    @property
    def temperature_terms(self) -> tuple[float, np.ndarray] | None:
        """The optional ``temperature_ref`` (degrees C) and ``bias_tempco`` (K x n, raw units
        per C^k) terms, None when absent (or K = 0).

        Raises
        ------
        CalibrationFileError
            One without the other, or not finite numbers of the right shape.
        """
        return _temperature_terms(self.extra, self.bias.shape[0])

    @property
    def sample_clock_scale(self) -> float | None:
        """The optional ``sample_clock_scale`` (device seconds per true second), or None.

        Raises
        ------
        CalibrationFileError
            Present but not a finite number between 0.5 and 2.
        """
        value = self.extra.get("sample_clock_scale")
        if value is None:
            return None
        if not (_is_number(value) and math.isfinite(value) and 0.5 < value < 2.0):
            raise CalibrationFileError(
                f"sample_clock_scale must be a number of device seconds per true second "
                f"(near 1), got {value!r}"
            )
        return float(value)

    def bias_at(self, temperature: np.ndarray | float | None = None) -> np.ndarray:
        """The bias at each temperature, (N, n) raw units (``bias`` alone, shape (n,), when the
        section has no temperature terms):
        ``bias + sum_k bias_tempco[k-1] (T - temperature_ref)^k``.

        Raises
        ------
        CalibrationFileError
            The section has temperature terms and ``temperature`` is None.
        """
        terms = self.temperature_terms
        if terms is None:
            return self.bias
        if temperature is None:
            raise CalibrationFileError(
                "the calibration holds bias_tempco (a temperature-dependent bias): it needs "
                "the temperature of each sample"
            )
        t_ref, tempco = terms
        dt = np.atleast_1d(np.asarray(temperature, dtype=np.float64)) - t_ref
        return self.bias + (dt[:, None] ** np.arange(1, len(tempco) + 1)) @ tempco

    def apply(
        self, raw: np.ndarray, accel: np.ndarray | None = None,
        temperature: np.ndarray | None = None,
    ) -> np.ndarray:  # fmt: skip
        """Calibrate raw samples.

        Parameters
        ----------
        raw : ndarray, shape (N, n) or (n,)
            Raw channels in raw units.
        accel : ndarray, shape (N, 3) or (3,), optional
            The calibrated accelerometer of the same samples, m/s^2: needed when the section
            holds ``g_sensitivity``, subtracted as ``raw - bias - g_sensitivity @ accel``.
        temperature : ndarray, shape (N,) or float, optional
            Degrees C of each sample: needed when the section holds ``bias_tempco``
            (:meth:`bias_at`); a NaN temperature gives a NaN output.

        Returns
        -------
        ndarray, shape (N, 3) or (3,)
            ``matrix @ (raw - bias [- g_sensitivity @ accel])`` per sample, in ``units``.

        Raises
        ------
        CalibrationFileError
            ``raw`` does not have n channels in its last axis, or the section holds
            ``g_sensitivity`` and ``accel`` is not given, or ``bias_tempco`` and
            ``temperature`` is not given.
        """
        raw = np.asarray(raw, dtype=np.float64)
        n = self.bias.shape[0]
        if raw.ndim not in (1, 2) or raw.shape[-1] != n:
            raise CalibrationFileError(
                f"cannot apply a calibration for {n} raw channels to data of shape {raw.shape}"
            )
        gs = self.g_sensitivity
        bias = self.bias
        if self.temperature_terms is not None:
            bias = self.bias_at(temperature)
            if raw.ndim == 1 and len(bias) == 1:
                bias = bias[0]
            elif len(bias) not in (1, raw.shape[0]) or raw.ndim == 1:
                raise CalibrationFileError(f"{len(bias)} temperatures for {len(raw)} samples")
        if gs is None:
            return (raw - bias) @ self.matrix.T
        if accel is None:
            raise CalibrationFileError(
                "the gyro calibration holds g_sensitivity: it needs the calibrated "
                "accelerometer of the same samples"
            )
        return (raw - bias - np.asarray(accel, dtype=np.float64) @ gs.T) @ self.matrix.T

    def to_dict(self) -> dict:
        """Return the JSON section: standard fields first, then ``extra``."""
        section = {
            "solver": self.solver,
            "units": self.units,
            "bias": self.bias.tolist(),
            "matrix": self.matrix.tolist(),
            "residual_rms": self.residual_rms,
        }
        section.update({k: v for k, v in self.extra.items() if k not in section})
        return section


@dataclass
class Calibration:
    """A calibration file: one section per calibrated sensor plus root metadata.

    Attributes
    ----------
    accel, gyro, mag : SensorCalibration or None
        At least one is present in a valid file.
    session : str or None
        The session file the calibration was computed from.
    created : str
        ISO 8601 UTC time of the calibration; default now.
    extra : dict
        Other root fields (``sensor``, ``toolkit_version``, ``config``, ...), preserved.
    """

    accel: SensorCalibration | None = None
    gyro: SensorCalibration | None = None
    session: str | None = None
    created: str = field(default_factory=_utc_now_iso)
    extra: dict = field(default_factory=dict)
    mag: SensorCalibration | None = None

    def sections(self) -> dict[str, SensorCalibration]:
        """The sensors present, in file order: ``{"accel": ..., "gyro": ..., "mag": ...}``."""
        return {n: getattr(self, n) for n in SENSORS if getattr(self, n) is not None}

    def to_dict(self) -> dict:
        """Return the JSON document as a dict (arrays as lists, sections only when present)."""
        d: dict[str, Any] = {"format": FORMAT, "format_version": FORMAT_VERSION}
        if self.session is not None:
            d["session"] = self.session
        d["created"] = self.created
        d.update({k: v for k, v in self.extra.items() if k not in _ROOT_FIELDS})
        for name, section in self.sections().items():
            d[name] = section.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "<dict>") -> Calibration:
        """Validate a parsed calibration document and build a Calibration.

        Parameters
        ----------
        d : dict
            The parsed JSON.
        source : str
            Name of the file (or string) it came from, used in error messages.

        Raises
        ------
        CalibrationFileError
            The document does not follow the calibration format; one line naming ``source``.
        """

        def fail(problem: str) -> CalibrationFileError:
            return CalibrationFileError(f"{source}: {problem}")

        if not isinstance(d, dict):
            raise fail(f"expected a JSON object, got {type(d).__name__}")
        if d.get("format") != FORMAT:
            raise fail(
                f"not an imucal calibration (format is {d.get('format')!r}, expected {FORMAT!r})"
            )
        version = d.get("format_version")
        if isinstance(version, bool) or version != FORMAT_VERSION:
            raise fail(
                f"unsupported format_version {version!r} "
                f"(this reader reads version {FORMAT_VERSION})"
            )
        for key in ("session", "created"):
            if key in d and d[key] is not None and not isinstance(d[key], str):
                raise fail(f"{key!r} must be a string, got {d[key]!r}")
        if not isinstance(d.get("created"), str):
            raise fail("'created' is missing")
        sections = {
            name: _parse_section(d[name], name, fail)
            for name in SENSORS
            if d.get(name) is not None
        }
        if not sections:
            raise fail("holds no 'accel', 'gyro' or 'mag' calibration")
        misplaced = ["the root" if "sample_clock_scale" in d else None] + [
            f"the {name} section" for name in ("accel", "mag")
            if isinstance(d.get(name), dict) and "sample_clock_scale" in d[name]
        ]  # fmt: skip
        if any(misplaced):  # the spec: it lives in the gyro section, refused anywhere else
            where = " and ".join(w for w in misplaced if w)
            raise fail(f"sample_clock_scale in {where}: it belongs in the gyro section (the "
                       "one whose values depend on time); move it there")  # fmt: skip
        return cls(
            accel=sections.get("accel"),
            mag=sections.get("mag"),
            gyro=sections.get("gyro"),
            session=d.get("session"),
            created=d["created"],
            extra={k: v for k, v in d.items() if k not in _ROOT_FIELDS},
        )


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _is_finite_list(value: Any) -> bool:
    return isinstance(value, list) and all(_is_number(v) and math.isfinite(v) for v in value)


def _temperature_terms(extra: dict, n: int) -> tuple[float, np.ndarray] | None:
    """``(temperature_ref, bias_tempco (K, n))`` of a section's fields, None when absent."""
    ref, tempco = extra.get("temperature_ref"), extra.get("bias_tempco")
    if ref is None and tempco is None:
        return None
    if ref is None or tempco is None:
        have, miss = ("temperature_ref", "bias_tempco") if tempco is None else (
            "bias_tempco", "temperature_ref")  # fmt: skip
        raise CalibrationFileError(f"{have} without {miss}: the temperature model is incomplete")
    if not (_is_number(ref) and math.isfinite(ref)):
        raise CalibrationFileError(f"temperature_ref must be a finite number (C), got {ref!r}")
    if not (isinstance(tempco, list) and all(_is_finite_list(v) and len(v) == n
                                              for v in tempco)):  # fmt: skip
        raise CalibrationFileError(
            f"bias_tempco must be a list of vectors of {n} finite numbers (one per bias entry)"
        )
    if not tempco:
        return None
    return float(ref), np.array(tempco, dtype=np.float64).reshape(len(tempco), n)


#: The largest calibrated offset ``|matrix @ bias|`` a sensor can have, in its output units:
#: 1000 g for an accelerometer (MEMS parts span 2 to 400 g), 1000 rad/s for a gyroscope (parts
#: span up to 70 rad/s), 1 T for a magnetometer (the earth's field is 25-65 uT, hard iron a few
#: thousand at most), 10,000 local fields.  Past them the numbers are no calibration: a bias of
#: 1e200 made ``apply`` write 1e197 m/s^2 for every sample with exit 0 (issue 26).
OFFSET_LIMIT = {"m/s^2": 1e4, "rad/s": 1e3, "uT": 1e6, LOCAL_FIELD: 1e4}


def _check_offset(name: str, units: str, bias: list, matrix: list, fail) -> None:
    """Refuse a section whose bias, through its matrix, is beyond what the sensor can read."""
    with np.errstate(all="ignore"):
        offset = np.abs(np.asarray(matrix, np.float64) @ np.asarray(bias, np.float64))
    limit = OFFSET_LIMIT[units]
    worst = float(np.max(offset))
    if not worst <= limit:
        raise fail(f"{name}.bias through {name}.matrix is an offset of {worst:.3g} {units}, "
                   f"beyond any sensor (at most {limit:g} {units}): not a calibration")  # fmt: skip


def _parse_section(section: Any, name: str, fail) -> SensorCalibration:
    if not isinstance(section, dict):
        raise fail(f"{name!r} must be an object, got {type(section).__name__}")
    for key in ("solver", "units"):
        if not isinstance(section.get(key), str):
            problem = "is missing" if key not in section else "must be a string"
            raise fail(f"{name}.{key} {problem}")
    if section["units"] not in _ALLOWED_UNITS[name]:
        expected = " or ".join(repr(u) for u in _ALLOWED_UNITS[name])
        raise fail(f"{name}.units is {section['units']!r}, expected {expected}")
    bias = section.get("bias")
    if not _is_finite_list(bias) or len(bias) < 3:
        raise fail(f"{name}.bias must be a list of at least 3 finite numbers, got {bias!r}")
    n = len(bias)
    matrix = section.get("matrix")
    if (
        not isinstance(matrix, list)
        or len(matrix) != 3
        or not all(_is_finite_list(row) and len(row) == n for row in matrix)
    ):
        raise fail(f"{name}.matrix must be 3 rows of {n} finite numbers (one per bias entry)")
    _check_offset(name, section["units"], bias, matrix, fail)
    rms = section.get("residual_rms")
    if rms is not None and not (_is_number(rms) and math.isfinite(rms)):
        raise fail(f"{name}.residual_rms must be a finite number or null, got {rms!r}")
    sec = SensorCalibration(
        solver=section["solver"],
        units=section["units"],
        bias=np.array(bias, dtype=np.float64),
        matrix=np.array(matrix, dtype=np.float64),
        residual_rms=None if rms is None else float(rms),
        extra={k: v for k, v in section.items() if k not in _SECTION_FIELDS},
    )
    if name != "gyro" and "g_sensitivity" in section:  # nothing would apply it
        raise fail(f"g_sensitivity in the {name} section: the term is the gyro's (its response "
                   f"to specific force); no reader applies it to the {name}")  # fmt: skip
    try:  # the optional terms of the spec: refused here when malformed
        sec.temperature_terms  # noqa: B018
        sec.sample_clock_scale  # noqa: B018
        sec.g_sensitivity  # noqa: B018 - of the wrong shape: refused, not ignored (issue 26)
    except CalibrationFileError as exc:
        raise fail(f"{name}.{exc}") from None
    return sec


