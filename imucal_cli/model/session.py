"""The session data model: :class:`Segment`, :class:`Session`, format constants, and the
conversions of HDF5 attribute values (str or bytes, numpy scalars or 1-element arrays)."""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from imucal_cli.errors import SessionError

from .imu_stream import REFERENCE_NAME, ImuStream

FORMAT = "imucal-session"
FORMAT_VERSION = 1
GRAVITY_DEFAULT = 9.80665
SEGMENT_KINDS = ("static", "rotation")
#: Units of ``/raw/accel`` and ``/raw/gyro`` the format names (``accel_units``, ``gyro_units``).
ACCEL_UNITS = ("counts", "V", "g", "m/s^2")
GYRO_UNITS = ("counts", "V", "rad/s", "deg/s")
#: Units of ``/raw/mag`` the format names (root attribute ``mag_units``).
MAG_UNITS = ("counts", "uT", "nT", "gauss")
#: Each sensor's raw units (a calibration section's ``units_in``).
RAW_UNITS = {"accel": ACCEL_UNITS, "gyro": GYRO_UNITS, "mag": MAG_UNITS}
#: Microtesla per raw unit of each physical ``mag_units``.
UT_PER_MAG_UNIT = {"uT": 1.0, "nT": 1e-3, "gauss": 100.0}
#: The largest local field a session may state (``magnetic_field_uT``, ``--field-uT``), uT: the
#: Earth's is 25-65 uT; a field beyond this is no magnitude a magnetometer is calibrated in.
MAX_FIELD_UT = 1e4

LOG_GROUP = "capture_log"
LOG_DATASET = "capture_log/segments"
LOG_ITEM_BYTES = 2048  # one segment as JSON, fixed-length bytes (SWMR cannot grow VL strings)

#: Segment attributes the format names; everything else lands in ``Segment.extra``.
SEGMENT_ATTRS = frozenset({"kind", "start", "stop", "label", "up", "axis", "angle_deg"})


def utc_now_iso() -> str:
    """Return the current UTC time as ISO 8601, second resolution: ``2026-11-21T10:00:00Z``."""
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


# --------------------------------------------------------------------------------------------
# Data model
# --------------------------------------------------------------------------------------------


def _frozen_vector(value: Any) -> np.ndarray | None:
    if value is None:
        return None
    vector = np.array(value, dtype=np.float64).reshape(3)
    vector.flags.writeable = False
    return vector


def _optional_equal(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return bool(np.array_equal(a, b))


@dataclass(frozen=True)
class Segment:
    """One labelled stretch of a session: the half-open sample range ``[start, stop)`` of /raw.

    Attributes
    ----------
    name : str
        Subgroup name under ``/segments``, e.g. ``"0000"``.
    kind : str
        ``"static"`` (held still) or ``"rotation"`` (turned).
    start, stop : int
        Half-open sample indices into the ``/raw`` datasets.
    label : str or None
        What the person was told, e.g. ``"face +Z up"``.
    up : ndarray, shape (3,), or None
        Static only: nominal unit vector pointing away from the earth, fixture frame.
    axis : ndarray, shape (3,), or None
        Rotation only: nominal unit rotation axis, fixture frame.
    angle_deg : float or None
        Rotation only: known signed rotation angle about ``axis`` in degrees (right hand).
    extra : dict
        Attributes the format does not name (allowed by the spec), e.g. ``mounting`` (int): the
        unit's mounting in the fixture, for constraints that hold within one mounting only.
        Values are numbers, strings or lists of numbers.
    """

    name: str
    kind: str
    start: int
    stop: int
    label: str | None = None
    up: np.ndarray | None = None
    axis: np.ndarray | None = None
    angle_deg: float | None = None
    extra: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "up", _frozen_vector(self.up))
        object.__setattr__(self, "axis", _frozen_vector(self.axis))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Segment):
            return NotImplemented
        return (
            (self.name, self.kind, self.start, self.stop, self.label, self.angle_deg)
            == (other.name, other.kind, other.start, other.stop, other.label, other.angle_deg)
            and _optional_equal(self.up, other.up)
            and _optional_equal(self.axis, other.axis)
        )

    def __hash__(self) -> int:
        return hash((self.name, self.kind, self.start, self.stop, self.label, self.angle_deg))

    @property
    def n_samples(self) -> int:
        """Number of samples in the segment, ``stop - start``."""
        return self.stop - self.start


@dataclass
class Session:
    """A recording: the raw stream, what happened when, and the file's metadata.

    Attributes
    ----------
    time : ndarray, shape (N,)
        Sample times in seconds, strictly increasing.
    accel : ndarray, shape (N, na), or None
        Raw accelerometer channels (na >= 3) in ``accel_units``.
    gyro : ndarray, shape (N, ng), or None
        Raw gyroscope channels (ng >= 3) in ``gyro_units``.
    mag : ndarray, shape (N, nm), or None
        Raw magnetometer channels (nm >= 3) in ``mag_units``; rows may hold NaN where the
        magnetometer gave no reading.
    temperature : ndarray, shape (N,), or None
        Degrees C.
    segments : list of Segment
        Sorted by ``start``.
    created : str
        ISO 8601 UTC time the recording started.
    sensor, source : str or None
        Free text (part and serial number; where the samples came from).
    sample_rate_hz : float or None
        Nominal sample rate in Hz.
    gravity : float
        Local gravity magnitude in m/s^2 (9.80665 when the file does not say).
    accel_units, gyro_units : str or None
        Units of the raw channels as recorded (``counts``, ``V``, ``g``, ``m/s^2``, ...).
    mag_units : str or None
        Units of ``/raw/mag``: one of :data:`MAG_UNITS`.
    magnetic_field_uT : float or None
        Local geomagnetic field magnitude, microtesla, where known.
    path : Path or None
        The file the session was read from.
    host_time : ndarray, shape (N,), or None
        The host's arrival time of each sample, s (``/raw/host_time``, an extra dataset):
        beside the device's ``time``, it measures the device's sample clock (issue 17.2).
    calibrations : dict of str to str
        ``/calibrations/<name>`` -> its calibration JSON text.
    imus : dict of str to ImuStream
        The other IMUs of a set (``/imus/<name>``, issue 28), in the order of the root
        attribute ``imus``; empty for one IMU.
    reference_name : str
        The name of the IMU in ``/raw`` (the first of the root attribute ``imus``).
    """

    time: np.ndarray
    accel: np.ndarray | None
    gyro: np.ndarray | None
    temperature: np.ndarray | None
    segments: list[Segment]
    created: str
    sensor: str | None = None
    source: str | None = None
    sample_rate_hz: float | None = None
    gravity: float = GRAVITY_DEFAULT
    accel_units: str | None = None
    gyro_units: str | None = None
    path: Path | None = None
    calibrations: dict[str, str] = field(default_factory=dict)
    mag: np.ndarray | None = None
    mag_units: str | None = None
    magnetic_field_uT: float | None = None
    host_time: np.ndarray | None = None
    imus: dict[str, ImuStream] = field(default_factory=dict)
    reference_name: str = REFERENCE_NAME

    def static_segments(self) -> list[Segment]:
        """Return the static segments, in time order."""
        return [s for s in self.segments if s.kind == "static"]

    def rotation_segments(self) -> list[Segment]:
        """Return the rotation segments, in time order."""
        return [s for s in self.segments if s.kind == "rotation"]


# --------------------------------------------------------------------------------------------
# Attribute values: h5py gives str or bytes, numpy scalars or 1-element arrays
# --------------------------------------------------------------------------------------------


def _scalar(value: Any) -> Any:
    if isinstance(value, np.ndarray | list | tuple):
        array = np.asarray(value)
        if array.size != 1:
            return None
        return array.reshape(-1)[0]
    return value


def as_str(value: Any) -> str | None:
    """Return a string attribute as str (from str, bytes or a 1-element array), else None."""
    value = _scalar(value)
    if isinstance(value, bytes | np.bytes_):
        try:
            return bytes(value).decode("utf-8")
        except UnicodeDecodeError:
            return None
    if isinstance(value, str):
        return str(value)
    return None


def as_float(value: Any) -> float | None:
    """Return a finite real number as float, else None."""
    value = _scalar(value)
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | float | np.number):
        return None
    if isinstance(value, np.complexfloating):
        return None
    number = float(value)
    return number if math.isfinite(number) else None


RATE_RANGE_HZ = (1.0, 10_000.0)
"""Sample rates plausible for an IMU, Hz: outside them, the time unit or ``--rate`` is wrong."""

RAW_LIMIT = 1e12
"""The largest raw reading (accelerometer, gyroscope, magnetometer, temperature) a sensor can
give, in any unit: 32-bit counts reach 4.3e9; values of 1e300 overflowed the solvers (a
traceback) and the noise figures."""


def first_beyond_raw_limit(values: np.ndarray) -> int | None:
    """Index of the first sample (row) of ``values`` holding a finite number beyond
    :data:`RAW_LIMIT` (NaN and inf are not: they mark a reading missing), or None."""
    values = np.asarray(values, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        big = np.isfinite(values) & (np.abs(values) > RAW_LIMIT)
    if big.ndim == 2:
        big = big.any(axis=1)
    rows = np.flatnonzero(big)
    return int(rows[0]) if rows.size else None


def check_readings(name: str, values: np.ndarray | None, src: str, first: int = 0,
                   where: str = "/raw") -> None:
    """Raise SessionError where the readings of channel ``where/name`` (samples ``first`` on)
    hold a number no sensor gives (beyond :data:`RAW_LIMIT`); times are not readings."""
    if values is None or name in ("time", "host_time"):
        return
    row = first_beyond_raw_limit(values)
    if row is not None:
        value = float(np.max(np.abs(np.atleast_1d(values[row]))))
        raise SessionError(f"{src}: {where}/{name} reads {value:.3g} at sample {first + row}, "
                           f"beyond any sensor (at most {RAW_LIMIT:g} in any unit): a damaged "
                           "file, or not raw readings")  # fmt: skip


def check_rate(time: np.ndarray, src: str, where: str = "/raw") -> None:
    """Raise SessionError where the median step of ``time`` (increasing, s) gives a rate slower
    than any IMU's (:data:`RATE_RANGE_HZ`): time stamps in a smaller unit written as seconds
    (1e10 s apart gave noise figures of 1e8 ug/sqrt(Hz), exit 0).  Not the fast side: a capture
    stamps a device that sends no time by the host's clock, whose bursts may be faster."""
    if len(time) < 3:
        return
    step = float(np.median(np.diff(time)))
    lo = RATE_RANGE_HZ[0]
    if not 1.0 / step >= lo:
        raise SessionError(f"{src}: {where}/time steps {step:.3g} s, {1.0 / step:.3g} Hz: "
                           f"slower than any IMU ({lo:g} Hz); are the time stamps in "
                           "seconds?")  # fmt: skip


MAX_TURN_DEG = 3600.0
"""The largest known turn a segment or a plan step may state, degrees either way: ten full
turns (a turntable's or a hand's turn is one or two; 1e300 overflowed the known-angle fit)."""

TURN_ANGLE_RULE = f"a finite number of degrees within +-{MAX_TURN_DEG:g} (ten turns)"
"""What a turn angle must be, for messages."""


def as_turn_angle(value: Any) -> float | None:
    """Return a known turn angle (degrees, finite, at most :data:`MAX_TURN_DEG` either way)
    as float, else None."""
    number = as_float(value)
    return number if number is not None and abs(number) <= MAX_TURN_DEG else None


def as_int(value: Any) -> int | None:
    """Return an integer (also an integral float, as MATLAB writes them) as int, else None."""
    number = as_float(value)
    if number is None or number != int(number):
        return None
    return int(number)


def as_unit_vector(value: Any) -> np.ndarray | None:
    """Return 3 finite, not all zero numbers scaled to unit length, else None."""
    try:
        vector = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if vector.size != 3 or vector.ndim > 1 and vector.shape != (3, 1):
        return None
    vector = vector.reshape(3)
    if not np.isfinite(vector).all():
        return None
    peak = float(np.max(np.abs(vector)))
    if peak == 0.0:
        return None
    vector = vector / peak  # its norm neither overflows (1e300) nor underflows (1e-200)
    return vector / float(np.linalg.norm(vector))


def show(value: Any) -> str:
    """Return ``repr`` of an attribute value without numpy types: ``2``, not ``np.int64(2)``."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    elif isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bytes):
        value = value.decode("utf-8", errors="replace")
    return repr(value)


def one_line(exc: BaseException) -> str:
    """The exception's message on one line (its class name when it has none)."""
    return " ".join(str(exc).split()) or type(exc).__name__


def io_reason(exc: BaseException) -> str:
    """A short reason for a failed read or write: ``No space left on device``, not HDF5's
    multi-clause report."""
    number = getattr(exc, "errno", None)
    if isinstance(number, int) and number > 0:
        return os.strerror(number)
    found = re.search(r"error message = '([^']+)'", str(exc))
    if found:
        return found.group(1)
    text = one_line(exc)
    return text if len(text) <= 160 else text[:157] + "..."
