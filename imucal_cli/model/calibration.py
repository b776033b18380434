"""The calibration model (``shared/spec/session-format.md``, version 1): a :class:`Calibration`
holds one section per calibrated sensor (:mod:`.section` and the sensors' subclasses), and,
for a session with several IMUs, an :class:`ImuEntry` per other IMU; built from the JSON
document's dict (validated: the spec's fields strictly, the solvers' fields as
:mod:`.codec` reads them) and turned back into it.

Files are read and written by :mod:`imucal_cli.formats.calibration` (imucal's JSON, and other
tools' calibrations through :mod:`imucal_cli.formats.foreign_calibration`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np

from imucal_cli.errors import CalibrationFileError

from .accel import AccelCalibration
from .codec import Mismatch, Record, decode, encode, item
from .gyro import GyroCalibration
from .mag import MagCalibration
from .parts import JSON, ImportedFrom, SampleClock
from .section import MODEL_EQUATION, MODEL_EQUATION_G, SensorCalibration
from .truth import AccelTruth, GyroTruth, MagTruth

__all__ = ["FORMAT", "FORMAT_VERSION", "LOCAL_FIELD", "MODEL_EQUATION", "MODEL_EQUATION_G",
           "SENSORS", "SENSOR_UNITS", "Calibration", "ImuEntry", "SensorCalibration",
           "SetDiagnostics", "section_class"]  # fmt: skip

FORMAT = "imucal-calibration"
FORMAT_VERSION = 1
SENSOR_UNITS = {"accel": "m/s^2", "gyro": "rad/s", "mag": "uT"}
SENSORS = ("accel", "gyro", "mag")
#: Units of a ``mag`` section calibrated without a known field magnitude: the calibrated
#: vector's magnitude is 1 at the local field.
LOCAL_FIELD = "local field"
_ALLOWED_UNITS = {"accel": ("m/s^2",), "gyro": ("rad/s",), "mag": ("uT", LOCAL_FIELD)}
#: Each sensor's section class: a solver's, or the simulator's truth.
_CLASSES = {"accel": (AccelCalibration, AccelTruth), "gyro": (GyroCalibration, GyroTruth),
            "mag": (MagCalibration, MagTruth)}  # fmt: skip


def section_class(sensor: str, solver: str) -> type[SensorCalibration]:
    """The class of a ``sensor`` section that ``solver`` wrote."""
    fitted, truth = _CLASSES[sensor]
    return truth if solver == "truth" else fitted


def _utc_now_iso() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


@dataclass
class SetDiagnostics(Record):
    """How an IMU's place in the set was found (the ``set`` member of an ``imus`` entry)."""

    rotation_method: str | None = None
    coarse_offset_s: float | None = None
    rotation_pairs: dict[str, int] | None = None
    rotation_residual_deg: dict[str, float] | None = None
    rotation_cov_rad2: list[list[float]] | None = None
    offset_samples: int | None = None
    offset_rms: float | None = None
    offset_rms_expected: float | None = None
    offset_iterations: int | None = None
    offset_method: str | None = None
    offset_rms_units: str | None = None


@dataclass
class ImuEntry(Record):
    """One more IMU of a session with several (spec: "Several IMUs"): its own sections and
    its place in the set.

    Attributes
    ----------
    accel, gyro, mag : SensorCalibration or None
    rotation_to_reference : list of list of float
        3 x 3: this IMU's calibrated frame into the reference IMU's.
    rotation_std_deg : list of float
    time_offset_s, time_offset_std_s : float
        Added to this IMU's time stamps, it puts them on the reference's time.
    set : SetDiagnostics or None
        How the rotation and the time offset were found.
    rotation_deg : float or None
        The rotation's angle (null when it was not determined).
    left_out : dict or None
        ``{sensor: why}`` of this IMU's sensors left out.
    warnings : list of str or None
        Its place in the set's warnings (a rotation or offset not determined, gyros that
        disagree).
    """

    accel: AccelCalibration | AccelTruth | None = item(own=True)
    gyro: GyroCalibration | GyroTruth | None = item(own=True)
    mag: MagCalibration | MagTruth | None = item(own=True)
    rotation_to_reference: list[list[float]] | None = None
    rotation_std_deg: list[float] | None = None
    time_offset_s: float | None = None
    time_offset_std_s: float | None = None
    set: SetDiagnostics | None = None
    rotation_deg: float | None = None
    left_out: dict[str, str] | None = None
    warnings: list[str] | None = None

    def sections(self) -> dict[str, SensorCalibration]:
        return {n: getattr(self, n) for n in SENSORS if getattr(self, n) is not None}

    def to_dict(self) -> dict:
        d = {name: encode(sec) for name, sec in self.sections().items()}
        d.update(encode(self))
        return d


@dataclass
class Calibration(Record):
    """A calibration file: one section per calibrated sensor plus root metadata.

    Attributes
    ----------
    accel, gyro, mag : SensorCalibration or None
        At least one is present in a valid file.
    session : str or None
        The session file the calibration was computed from.
    created : str
        ISO 8601 UTC time of the calibration; default now.
    sensor, source : str or None
        The session's sensor name and source (``"simulator"``, ``"serial:..."``).
    toolkit_version : str or None
    config : dict or None
        The config that shaped it (the TOML's document).
    sample_clock : SampleClock or None
        The sample clock's estimate (issue 17.2).
    temperature_note : str or None
        Why there is no temperature model where one was possible.
    accel_note, gyro_note, mag_note : str or None
        Why a sensor was left out (or calibrated without another).
    complete : bool or None
        No sensor of the session left out (issue 24.2); ``left_out`` says why each was.
    left_out : dict or None
        ``{sensor: why}``.
    sessions : list of str or None
        The sessions merged (``--with``).
    imported_from, created_basis, comment
        A calibration read from another tool's file: which, and what ``created`` is.
    seed, plan, jitter_deg, simulator
        The simulator's truth: its options.
    reference_name : str or None
        The reference IMU's name in a session with several (default ``reference``).
    imus : dict of ImuEntry or None
        The other IMUs of a session with several.
    """

    accel: AccelCalibration | AccelTruth | None = item(own=True)
    gyro: GyroCalibration | GyroTruth | None = item(own=True)
    session: str | None = None
    created: str = item(factory=_utc_now_iso)
    mag: MagCalibration | MagTruth | None = item(own=True)
    sensor: str | None = None
    source: str | None = None
    seed: int | None = None
    plan: str | None = None
    jitter_deg: float | None = None
    simulator: JSON | None = None
    toolkit_version: str | None = None
    config: JSON | None = None
    sample_clock: SampleClock | None = None
    temperature_note: str | None = None
    accel_note: str | None = None
    gyro_note: str | None = None
    mag_note: str | None = None
    complete: bool | None = None
    left_out: dict[str, str] | None = None
    sessions: list[str] | None = None
    imported_from: ImportedFrom | None = None
    created_basis: str | None = None
    comment: str | None = None
    reference_name: str | None = None
    imus: dict[str, ImuEntry] | None = item(own=True)

    def sections(self) -> dict[str, SensorCalibration]:
        """The sensors present, in file order: ``{"accel": ..., "gyro": ..., "mag": ...}``."""
        return {n: getattr(self, n) for n in SENSORS if getattr(self, n) is not None}

    def note(self, sensor: str) -> str | None:
        """Why ``sensor`` was left out (or calibrated without another), or None."""
        return getattr(self, f"{sensor}_note")

    def to_dict(self) -> dict:
        """Return the JSON document as a dict (arrays as lists, sections only when present)."""
        d: dict[str, Any] = {"format": FORMAT, "format_version": FORMAT_VERSION}
        d.update(encode(self))
        for name, section in self.sections().items():
            d[name] = encode(section)
        if self.imus is not None:
            d["imus"] = {name: entry.to_dict() for name, entry in self.imus.items()}
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
        sections = _sections(d, "", fail)
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
        rest = {k: v for k, v in d.items() if k not in ("format", "format_version")}
        cal = decode(cls, rest)
        for name, sec in sections.items():
            setattr(cal, name, sec)
        cal.imus = _imus(d.get("imus"), fail)
        return cal


def _sections(d: dict, where: str, fail) -> dict[str, SensorCalibration]:
    """The sections of a document (or of one IMU of ``imus``: ``where`` its name)."""
    return {name: _parse_section(d[name], f"{where}{name}", name, fail)
            for name in SENSORS if d.get(name) is not None}  # fmt: skip


def _imus(raw: Any, fail) -> dict[str, ImuEntry] | None:
    """The ``imus`` of a document: each IMU's sections validated as the reference's."""
    if raw is None:
        return None
    if not isinstance(raw, dict):
        raise fail(f"'imus' must be an object of IMUs by name, got {type(raw).__name__}")
    out = {}
    for name, entry in raw.items():
        if not isinstance(entry, dict):
            raise fail(f"imus.{name} must be an object, got {type(entry).__name__}")
        imu = decode(ImuEntry, entry)
        for sensor, sec in _sections(entry, f"imus.{name}.", fail).items():
            setattr(imu, sensor, sec)
        out[str(name)] = imu
    return out


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _is_finite_list(value: Any) -> bool:
    return isinstance(value, list) and all(_is_number(v) and math.isfinite(v) for v in value)


def _check_terms(section: dict, n: int) -> None:
    """Refuse a section whose optional terms (spec) are malformed: ``temperature_ref`` and
    ``bias_tempco`` (one without the other, not finite numbers of the right shape),
    ``sample_clock_scale`` (not a number near 1), ``g_sensitivity`` (not n x 3 finite
    numbers)."""
    _temperature_terms(section, n)
    value = section.get("sample_clock_scale")
    if value is not None and not (_is_number(value) and math.isfinite(value)
                                  and 0.5 < value < 2.0):  # fmt: skip
        raise CalibrationFileError(
            f"sample_clock_scale must be a number of device seconds per true second "
            f"(near 1), got {value!r}"
        )
    g = section.get("g_sensitivity")
    if g is not None:
        try:
            g = np.asarray(g, dtype=np.float64)
        except (TypeError, ValueError):
            g = np.empty(0)
        if g.shape != (n, 3) or not np.isfinite(g).all():
            raise CalibrationFileError(f"g_sensitivity must be {n} x 3 finite numbers")


def _temperature_terms(section: dict, n: int) -> tuple[float, np.ndarray] | None:
    """``(temperature_ref, bias_tempco (K, n))`` of a section's fields, None when absent."""
    ref, tempco = section.get("temperature_ref"), section.get("bias_tempco")
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


#: The smallest gain a matrix may have, output units per raw unit, and the largest spread of
#: its gains (condition number): a 32-bit reading of a +-0.1 rad/s gyro is 5e-11 rad/s per
#: count; a matrix of zeros (or a singular one) made ``apply`` write zeros (or one axis's
#: reading on two) for every sample with exit 0.
MIN_GAIN, MAX_CONDITION = 1e-15, 1e12


def _check_matrix(name: str, units: str, matrix: list, fail) -> None:
    """Refuse a matrix no sensor has: one raw unit read as more than the sensor's
    :data:`OFFSET_LIMIT` (a gain of 1e30), or less than :data:`MIN_GAIN`, or a singular one
    (readings that differ calibrated alike)."""
    with np.errstate(all="ignore"):
        gains = np.linalg.svd(np.asarray(matrix, np.float64), compute_uv=False)
    largest, smallest = float(gains[0]), float(gains[-1])
    limit = OFFSET_LIMIT[units]
    if not MIN_GAIN <= largest <= limit:
        raise fail(f"{name}.matrix gives at most {largest:.3g} {units} per raw unit, outside "
                   f"any sensor's {MIN_GAIN:g} to {limit:g}: not a calibration")
    if not smallest * MAX_CONDITION >= largest:
        raise fail(f"{name}.matrix is singular (its gains span {largest:.3g} to {smallest:.3g} "
                   f"{units} per raw unit): different readings would calibrate alike; not a "
                   "calibration")  # fmt: skip


def _parse_section(section: Any, where: str, name: str, fail) -> SensorCalibration:
    """A section of the document, the spec's fields checked strictly (``where``: its path in
    the document, for the message; ``name``: the sensor)."""
    if not isinstance(section, dict):
        raise fail(f"{where!r} must be an object, got {type(section).__name__}")
    for key in ("solver", "units"):
        if not isinstance(section.get(key), str):
            problem = "is missing" if key not in section else "must be a string"
            raise fail(f"{where}.{key} {problem}")
    if section["units"] not in _ALLOWED_UNITS[name]:
        expected = " or ".join(repr(u) for u in _ALLOWED_UNITS[name])
        raise fail(f"{where}.units is {section['units']!r}, expected {expected}")
    bias = section.get("bias")
    if not _is_finite_list(bias) or len(bias) < 3:
        raise fail(f"{where}.bias must be a list of at least 3 finite numbers, got {bias!r}")
    n = len(bias)
    matrix = section.get("matrix")
    if (
        not isinstance(matrix, list)
        or len(matrix) != 3
        or not all(_is_finite_list(row) and len(row) == n for row in matrix)
    ):
        raise fail(f"{where}.matrix must be 3 rows of {n} finite numbers (one per bias entry)")
    _check_offset(where, section["units"], bias, matrix, fail)
    _check_matrix(where, section["units"], matrix, fail)
    rms = section.get("residual_rms")
    if rms is not None and not (_is_number(rms) and math.isfinite(rms)):
        raise fail(f"{where}.residual_rms must be a finite number or null, got {rms!r}")
    if name != "gyro" and "g_sensitivity" in section:  # nothing would apply it
        raise fail(f"g_sensitivity in the {name} section: the term is the gyro's (its response "
                   f"to specific force); no reader applies it to the {name}")  # fmt: skip
    try:  # the optional terms of the spec: refused here when malformed
        _check_terms(section, n)
    except CalibrationFileError as exc:
        raise fail(f"{where}.{exc}") from None
    try:
        return decode(section_class(name, section["solver"]), section)
    except Mismatch as exc:  # the standard fields were checked: not expected
        raise fail(f"{where}: {exc}") from None
