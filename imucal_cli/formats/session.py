"""HDF5 session files: validating reader, appending writer, calibration storage.

Implements the session format of ``shared/spec/session-format.md``, version 1:

- :func:`read_session` opens any file that follows the format (written by this package or by
  another tool), validates it and returns a :class:`Session`.  Every problem a user can fix
  raises :class:`~imucal_cli.errors.SessionError` with a one-line message that names the file.
- :class:`SessionWriter` records a session while it is captured: chunked, resizable ``/raw``
  datasets written at least once per ``flush_interval_s`` in HDF5 SWMR mode, so that a reader
  can open the file while it is written and a writer killed with ``kill -9`` leaves a readable
  file that misses at most the last ``flush_interval_s`` of samples.
- :func:`write_session` writes a complete :class:`Session` in one go (through the writer).
- :func:`store_calibration` appends a calibration JSON under ``/calibrations``.

SWMR and segments
-----------------
HDF5 does not support creating groups or attributes while a file is in SWMR write mode, so the
writer keeps segments in memory and writes the ``/segments/NNNN`` groups when it is closed.
Until then each segment is also logged, SWMR-safely, as one JSON object per row of the
fixed-length string dataset ``/capture_log/segments`` (an extra dataset the format allows).
A clean :meth:`SessionWriter.close` removes the log.  When a writer was killed, the file has
no segment groups but still holds the log, and :func:`read_session` reads the segments from it.

A file whose SWMR writer was killed keeps the HDF5 "open for writing" flag.  Plain HDF5 readers
(``h5py.File(path)``, ``h5dump``) refuse such a file until ``h5clear -s FILE`` clears the flag;
:func:`read_session` opens it in SWMR read mode instead and reads every ``/raw`` dataset up to
the shortest one (the datasets of an interrupted flush may differ in length).
"""

from __future__ import annotations

import json
import math
import operator
import os
import time as _time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from imucal_cli.errors import InputError, SessionError

FORMAT = "imucal-session"
FORMAT_VERSION = 1
GRAVITY_DEFAULT = 9.80665
SEGMENT_KINDS = ("static", "rotation")

_CHUNK_ROWS = 1024  # samples per HDF5 chunk of the /raw datasets
_MAX_PENDING_ROWS = 65536  # the writer writes out earlier than its flush interval past this
_LOG_GROUP = "capture_log"
_LOG_DATASET = "capture_log/segments"
_LOG_ITEM_BYTES = 2048  # one segment as JSON, fixed-length bytes (SWMR cannot grow VL strings)


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
    path : Path or None
        The file the session was read from.
    calibrations : dict of str to str
        ``/calibrations/<name>`` -> its calibration JSON text.
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


def _as_float(value: Any) -> float | None:
    """Return a finite real number as float, else None."""
    value = _scalar(value)
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | float | np.number):
        return None
    if isinstance(value, np.complexfloating):
        return None
    number = float(value)
    return number if math.isfinite(number) else None


def as_int(value: Any) -> int | None:
    """Return an integer (also an integral float, as MATLAB writes them) as int, else None."""
    number = _as_float(value)
    if number is None or number != int(number):
        return None
    return int(number)


def _as_unit_vector(value: Any) -> np.ndarray | None:
    """Return 3 finite, not all zero numbers scaled to unit length, else None."""
    try:
        vector = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if vector.size != 3 or vector.ndim > 1 and vector.shape != (3, 1):
        return None
    vector = vector.reshape(3)
    norm = float(np.linalg.norm(vector))
    if not np.isfinite(vector).all() or norm == 0.0:
        return None
    return vector / norm


def _show(value: Any) -> str:
    """Return ``repr`` of an attribute value without numpy types: ``2``, not ``np.int64(2)``."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    elif isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bytes):
        value = value.decode("utf-8", errors="replace")
    return repr(value)


def one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


# --------------------------------------------------------------------------------------------
# Reader
# --------------------------------------------------------------------------------------------


def _check_session_file(path: Path, src: str) -> None:
    """Raise SessionError unless ``path`` is a readable HDF5 file."""
    if not path.exists():
        raise SessionError(f"{src}: no such file")
    if path.is_dir():
        raise SessionError(f"{src}: is a directory, not a session file")
    if not os.access(path, os.R_OK):
        raise SessionError(f"{src}: permission denied")
    if not h5py.is_hdf5(path):
        raise SessionError(f"{src}: not an HDF5 file")


def open_for_reading(path: Path, src: str) -> tuple[h5py.File, bool]:
    """Open a session read-only; return the file and whether its writer has not closed it.

    A file still being written (or whose SWMR writer was killed) carries the HDF5 "open for
    writing" flag and only opens in SWMR read mode.
    """
    _check_session_file(path, src)
    try:
        return h5py.File(path, "r"), False
    except OSError:
        pass
    try:
        return h5py.File(path, "r", swmr=True), True
    except OSError as exc:
        raise SessionError(
            f"{src}: cannot open the HDF5 file ({one_line(exc)}); if the program that wrote "
            f"it was killed, `h5clear -s {src}` clears the flag"
        ) from None


def read_session(path: str | os.PathLike) -> Session:
    """Read and validate a session file.

    Parameters
    ----------
    path : str or path-like
        The HDF5 session file.

    Returns
    -------
    Session
        Arrays as float64; segments sorted by start, ``up``/``axis`` scaled to unit length.

    Raises
    ------
    SessionError
        The file is missing, not HDF5, or does not follow the session format.  The message is
        one line naming the file and the problem.
    """
    path = Path(path)
    src = str(path)
    file, unclosed = open_for_reading(path, src)
    try:
        session = _read_open_file(file, src, unclosed)
    except (OSError, KeyError, RuntimeError) as exc:
        raise SessionError(f"{src}: damaged HDF5 file ({one_line(exc)})") from None
    finally:
        file.close()
    session.path = path
    return session


def _get_attr(attrs: h5py.AttributeManager, name: str, src: str, where: str) -> Any:
    """Return attribute ``name`` or None when absent; an unreadable value is an error."""
    if name not in attrs:
        return None
    try:
        return attrs[name]
    except (OSError, TypeError, ValueError) as exc:
        raise SessionError(
            f"{src}: {where}attribute {name!r} cannot be read ({one_line(exc)})"
        ) from None


def _read_open_file(file: h5py.File, src: str, unclosed: bool) -> Session:
    root = {
        name: _get_attr(file.attrs, name, src, "root ")
        for name in (
            "format", "format_version", "created", "sensor", "source", "sample_rate_hz",
            "gravity", "accel_units", "gyro_units",
        )
    }  # fmt: skip
    fmt = root["format"]
    if fmt is None:
        raise SessionError(f"{src}: not an imucal session (no root attribute 'format')")
    if as_str(fmt) != FORMAT:
        raise SessionError(
            f"{src}: not an imucal session (format is {_show(fmt)}, expected {FORMAT!r})"
        )
    version = root["format_version"]
    if version is None:
        raise SessionError(f"{src}: root attribute 'format_version' is missing")
    if as_int(version) != FORMAT_VERSION:
        raise SessionError(
            f"{src}: unsupported format_version {_show(version)} (this reader reads "
            f"version {FORMAT_VERSION})"
        )
    created = as_str(root["created"])
    if created is None:
        problem = "is missing" if root["created"] is None else "is not a string"
        raise SessionError(f"{src}: root attribute 'created' {problem}")
    text = {}
    for name in ("sensor", "source", "accel_units", "gyro_units"):
        text[name] = None if root[name] is None else as_str(root[name])
        if root[name] is not None and text[name] is None:
            raise SessionError(f"{src}: root attribute {name!r} is not a string")
    numbers = {}
    for name in ("sample_rate_hz", "gravity"):
        numbers[name] = None if root[name] is None else _as_float(root[name])
        if root[name] is not None and (numbers[name] is None or numbers[name] <= 0):
            raise SessionError(
                f"{src}: root attribute {name!r} must be a positive number, got {_show(root[name])}"
            )

    time, accel, gyro, temperature = _read_raw(file, src, unclosed)
    segments = _read_segments(file, src, len(time), accel, gyro, unclosed)
    return Session(
        time=time,
        accel=accel,
        gyro=gyro,
        temperature=temperature,
        segments=segments,
        created=created,
        sensor=text["sensor"],
        source=text["source"],
        sample_rate_hz=numbers["sample_rate_hz"],
        gravity=GRAVITY_DEFAULT if numbers["gravity"] is None else numbers["gravity"],
        accel_units=text["accel_units"],
        gyro_units=text["gyro_units"],
        calibrations=_read_calibrations(file),
    )


def _read_raw(
    file: h5py.File, src: str, unclosed: bool
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    raw = file.get("raw")
    datasets: dict[str, h5py.Dataset] = {}
    for name in ("time", "accel", "gyro", "temperature"):
        obj = raw.get(name) if isinstance(raw, h5py.Group) else None
        if obj is None:
            continue
        if not isinstance(obj, h5py.Dataset):
            raise SessionError(f"{src}: /raw/{name} is not a dataset")
        if obj.dtype.kind not in "iuf":
            raise SessionError(f"{src}: /raw/{name} is not numeric (dtype {obj.dtype})")
        datasets[name] = obj
    if "time" not in datasets:
        raise SessionError(f"{src}: /raw/time is missing")
    if datasets["time"].ndim != 1:
        raise SessionError(f"{src}: /raw/time must be 1-D, has shape {datasets['time'].shape}")
    n = datasets["time"].shape[0]
    if unclosed:
        # An interrupted flush may have grown some datasets and not others.
        n = min(ds.shape[0] for ds in datasets.values() if ds.ndim >= 1)
    for name in ("accel", "gyro"):
        ds = datasets.get(name)
        if ds is not None and (ds.ndim != 2 or ds.shape[0] < n or ds.shape[1] < 3):
            raise SessionError(
                f"{src}: /raw/{name} must have shape (N, >=3) with N = {n} samples, "
                f"has shape {ds.shape}"
            )
        if ds is not None and not unclosed and ds.shape[0] != n:
            raise SessionError(f"{src}: /raw/{name} has {ds.shape[0]} rows, /raw/time has {n}")
    ds = datasets.get("temperature")
    if ds is not None and (ds.shape != (n,) and (not unclosed or ds.ndim != 1)):
        raise SessionError(f"{src}: /raw/temperature must have shape ({n},), has shape {ds.shape}")

    def load(name: str) -> np.ndarray | None:
        if name not in datasets:
            return None
        return np.asarray(datasets[name][:n], dtype=np.float64)

    time = load("time")
    bad = np.flatnonzero(~np.isfinite(time))
    if bad.size:
        raise SessionError(f"{src}: /raw/time is {time[bad[0]]} at sample {bad[0]}")
    bad = np.flatnonzero(np.diff(time) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise SessionError(
            f"{src}: /raw/time is not strictly increasing "
            f"(sample {i}: {float(time[i])!r} s after {float(time[i - 1])!r} s)"
        )
    return time, load("accel"), load("gyro"), load("temperature")


def _read_segments(
    file: h5py.File,
    src: str,
    n: int,
    accel: np.ndarray | None,
    gyro: np.ndarray | None,
    unclosed: bool,
) -> list[Segment]:
    segments = []
    group = file.get("segments")
    if isinstance(group, h5py.Group):
        for name in group:
            obj = group.get(name)
            if isinstance(obj, h5py.Group):
                where = f"/segments/{name}"
                get = _attr_getter(obj.attrs, src, where)
                segment = _parse_segment(name, get, src, where, n, accel, gyro)
                segment.extra.update(_extra_attrs(obj.attrs.items()))
                segments.append(segment)
    log = file.get(_LOG_DATASET)
    if not segments and isinstance(log, h5py.Dataset):
        # The writer was killed before it wrote the segment groups: use its SWMR-safe log.
        for row, item in enumerate(log[()]):
            where = f"/{_LOG_DATASET}[{row}]"
            try:
                entry = json.loads(bytes(item).decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError):
                raise SessionError(f"{src}: {where} is not a JSON object") from None
            if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
                raise SessionError(f"{src}: {where} is not a segment")
            if unclosed and isinstance(entry.get("stop"), int) and entry["stop"] > n:
                continue  # describes samples the writer did not get to save
            segment = _parse_segment(entry["name"], entry.get, src, where, n, accel, gyro)
            segment.extra.update(_extra_attrs((k, v) for k, v in entry.items() if k != "name"))
            segments.append(segment)
    segments.sort(key=lambda s: s.start)
    return segments


#: Segment attributes the format names; everything else lands in ``Segment.extra``.
_SEGMENT_ATTRS = {"kind", "start", "stop", "label", "up", "axis", "angle_deg"}


def _extra_attrs(items) -> dict[str, Any]:
    """Plain Python values of the attributes the format does not name."""
    extra = {}
    for key, value in items:
        if key in _SEGMENT_ATTRS:
            continue
        if isinstance(value, bytes):
            value = value.decode("utf-8", "replace")
        elif isinstance(value, np.ndarray):
            value = value.tolist()
        elif isinstance(value, np.generic):
            value = value.item()
        extra[key] = value
    return extra


def _attr_getter(attrs: h5py.AttributeManager, src: str, where: str) -> Callable[[str], Any]:
    return lambda name: _get_attr(attrs, name, src, f"{where}: ")


def _parse_segment(
    name: str,
    get: Callable[[str], Any],
    src: str,
    where: str,
    n: int,
    accel: np.ndarray | None,
    gyro: np.ndarray | None,
) -> Segment:
    def fail(problem: str) -> SessionError:
        return SessionError(f"{src}: {where}: {problem}")

    values = {}
    for key in ("kind", "start", "stop"):
        values[key] = get(key)
        if values[key] is None:
            raise fail(f"attribute {key!r} is missing")
    kind = as_str(values["kind"])
    if kind not in SEGMENT_KINDS:
        raise fail(f"unknown kind {_show(values['kind'])} (expected 'static' or 'rotation')")
    start, stop = as_int(values["start"]), as_int(values["stop"])
    for key, number in (("start", start), ("stop", stop)):
        if number is None:
            raise fail(f"{key!r} must be an integer sample index, got {_show(values[key])}")
    if start >= stop:
        raise fail(f"start {start} is not before stop {stop}")
    if start < 0 or stop > n:
        raise fail(f"samples [{start}, {stop}) are outside the recorded range [0, {n}]")
    label = get("label")
    if label is not None and as_str(label) is None:
        raise fail("attribute 'label' is not a string")
    label = None if label is None else as_str(label)

    up = axis = angle_deg = None
    if kind == "static":
        raw_up = get("up")
        if raw_up is not None:
            up = _as_unit_vector(raw_up)
            if up is None:
                raise fail(f"'up' must be 3 finite numbers, not all zero, got {_show(raw_up)}")
        data, dataset = accel, "/raw/accel"
    else:
        raw_axis = get("axis")
        if raw_axis is not None:
            axis = _as_unit_vector(raw_axis)
            if axis is None:
                raise fail(f"'axis' must be 3 finite numbers, not all zero, got {_show(raw_axis)}")
        raw_angle = get("angle_deg")
        if raw_angle is not None:
            angle_deg = _as_float(raw_angle)
            if angle_deg is None:
                raise fail(f"'angle_deg' must be a finite number, got {_show(raw_angle)}")
        data, dataset = gyro, "/raw/gyro"
    if data is None:
        raise fail(f"{kind} segment but the file has no {dataset}")
    bad = np.flatnonzero(~np.isfinite(data[start:stop]).all(axis=1))
    if bad.size:
        raise fail(f"{dataset} has NaN or inf at sample {start + int(bad[0])}, inside the segment")
    return Segment(name, kind, start, stop, label, up, axis, angle_deg)


def _read_calibrations(file: h5py.File) -> dict[str, str]:
    calibrations = {}
    group = file.get("calibrations")
    if isinstance(group, h5py.Group):
        for name in group:
            obj = group.get(name)
            if isinstance(obj, h5py.Group) and "json" in obj.attrs:
                text = as_str(obj.attrs["json"])
                if text is not None:
                    calibrations[name] = text
    return calibrations


# --------------------------------------------------------------------------------------------
# Writer
# --------------------------------------------------------------------------------------------


class SessionWriter:
    """Write a session while it is recorded; a context manager.

    Samples are buffered and written to chunked, resizable ``/raw`` datasets, followed by an
    HDF5 flush, at least every ``flush_interval_s`` while :meth:`append` is called.  The file
    is in SWMR mode, so :func:`read_session` can read it while it is written, and a writer
    killed with ``kill -9`` leaves a readable file (see the module notes).  Segments are
    written as ``/segments/NNNN`` groups on :meth:`close`.

    Parameters
    ----------
    path : str or path-like
        The file to create.
    created : str, optional
        ISO 8601 UTC start time; default now.
    sensor, source, accel_units, gyro_units : str, optional
        Root attributes, written only when given.
    sample_rate_hz : float, optional
        Nominal rate in Hz, written only when given.
    gravity : float, optional
        Local gravity in m/s^2, written only when given.
    accel_channels, gyro_channels : int or None
        Raw channels per sample (>= 3); None records no such sensor.
    temperature : bool
        Whether samples carry a temperature in degrees C.
    flush_interval_s : float
        Longest time in seconds appended samples stay in memory.
    overwrite : bool
        Replace an existing file instead of refusing.

    Raises
    ------
    InputError
        The file exists (and ``overwrite`` is false) or cannot be created, or an option is bad.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        created: str | None = None,
        sensor: str | None = None,
        source: str | None = None,
        sample_rate_hz: float | None = None,
        gravity: float | None = None,
        accel_units: str | None = None,
        gyro_units: str | None = None,
        accel_channels: int | None = 3,
        gyro_channels: int | None = 3,
        temperature: bool = False,
        flush_interval_s: float = 1.0,
        overwrite: bool = False,
    ) -> None:
        self.path = Path(path)
        self._src = src = str(path)
        channel_counts = {"accel_channels": accel_channels, "gyro_channels": gyro_channels}
        for name, channels in channel_counts.items():
            valid = isinstance(channels, int | np.integer) and channels >= 3
            if channels is not None and not valid:
                raise InputError(f"{src}: {name} must be an integer >= 3 or None, got {channels!r}")
        for name, number in (("sample_rate_hz", sample_rate_hz), ("gravity", gravity)):
            value = None if number is None else _as_float(number)
            if number is not None and (value is None or value <= 0):
                raise InputError(f"{src}: {name} must be a positive number, got {number!r}")
        if self.path.is_dir():
            raise InputError(f"{src}: is a directory")
        if self.path.exists() and not overwrite:
            raise InputError(f"{src}: file exists (refusing to overwrite it)")
        attrs: dict[str, Any] = {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "created": created if created is not None else utc_now_iso(),
        }
        optional = {
            "sensor": sensor,
            "source": source,
            "sample_rate_hz": None if sample_rate_hz is None else float(sample_rate_hz),
            "gravity": None if gravity is None else float(gravity),
            "accel_units": accel_units,
            "gyro_units": gyro_units,
        }
        attrs.update({k: v for k, v in optional.items() if v is not None})

        self._widths: dict[str, int | None] = {
            "accel": None if accel_channels is None else int(accel_channels),
            "gyro": None if gyro_channels is None else int(gyro_channels),
        }
        self._flush_interval_s = float(flush_interval_s)
        self._n_written = 0
        self._pending: list[dict[str, np.ndarray]] = []
        self._n_pending = 0
        self._last_time: float | None = None
        self._nonfinite: dict[str, list[np.ndarray]] = {"accel": [], "gyro": []}
        self._segments: list[dict[str, Any]] = []
        self._pending_log: list[bytes] = []
        try:
            self._file: h5py.File | None = h5py.File(self.path, "w", libver="latest")
        except OSError as exc:
            raise InputError(f"{src}: cannot create the file ({one_line(exc)})") from None
        try:
            self._file.attrs.update(attrs)
            raw = self._file.create_group("raw")
            # Written in this order at each flush; time last, so it is never longer than data.
            self._datasets: dict[str, h5py.Dataset] = {}
            for name in ("accel", "gyro"):
                width = self._widths[name]
                if width is not None:
                    self._datasets[name] = raw.create_dataset(
                        name, shape=(0, width), maxshape=(None, width),
                        chunks=(_CHUNK_ROWS, width), dtype="f8",
                    )  # fmt: skip
            shapes = {"temperature": temperature, "time": True}
            for name, wanted in shapes.items():
                if wanted:
                    self._datasets[name] = raw.create_dataset(
                        name, shape=(0,), maxshape=(None,), chunks=(_CHUNK_ROWS,), dtype="f8"
                    )
            self._file.create_group("segments")
            self._log = self._file.create_dataset(
                _LOG_DATASET, shape=(0,), maxshape=(None,), chunks=(16,),
                dtype=f"S{_LOG_ITEM_BYTES}",
            )  # fmt: skip
            self._file.swmr_mode = True
        except OSError as exc:
            self._file.close()
            raise InputError(f"{src}: cannot write ({one_line(exc)})") from None
        self._last_flush = _time.monotonic()

    # context manager ---------------------------------------------------------------------
    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @property
    def n_samples(self) -> int:
        """Samples appended so far (written to the file or still buffered)."""
        return self._n_written + self._n_pending

    def _fail(self, problem: str) -> SessionError:
        return SessionError(f"{self._src}: {problem}")

    def _check_open(self) -> h5py.File:
        if self._file is None:
            raise self._fail("the session writer is closed")
        return self._file

    # samples -------------------------------------------------------------------------------
    def append(
        self,
        time: float | np.ndarray,
        accel: np.ndarray | None = None,
        gyro: np.ndarray | None = None,
        temperature: float | np.ndarray | None = None,
    ) -> None:
        """Append samples: a block of k, or a single one.

        Parameters
        ----------
        time : float or ndarray, shape (k,)
            Sample times in seconds, strictly increasing and after every earlier sample.
        accel : ndarray, shape (k, na) or (na,) for a single sample
            Raw accelerometer channels; required exactly when the writer records accel.
        gyro : ndarray, shape (k, ng) or (ng,)
            Raw gyroscope channels; required exactly when the writer records gyro.
        temperature : ndarray, shape (k,), or float
            Degrees C; required exactly when the writer records temperature.

        Raises
        ------
        SessionError
            Wrong shapes, a missing or unexpected sensor, or times that are not finite and
            strictly increasing.  Nothing of the block is kept then.
        """
        self._check_open()
        t = np.asarray(time, dtype=np.float64)
        single = t.ndim == 0
        t = t.reshape(-1) if single else t
        if t.ndim != 1:
            raise self._fail(f"append: time must be a number or 1-D, has shape {t.shape}")
        k = t.size
        block = {"time": t}
        given = {"accel": accel, "gyro": gyro, "temperature": temperature}
        for name, value in given.items():
            expected = (k,) if name == "temperature" else (k, self._widths[name])
            recorded = name in self._datasets
            if value is None and recorded:
                raise self._fail(f"append: {name} is missing (this writer records {name})")
            if value is not None and not recorded:
                raise self._fail(f"append: got {name}, but this writer does not record {name}")
            if value is None:
                continue
            array = np.asarray(value, dtype=np.float64)
            if single:
                array = array.reshape((1, -1) if name != "temperature" else (1,))
            if array.shape != expected:
                raise self._fail(f"append: {name} has shape {array.shape}, expected {expected}")
            block[name] = array
        if k == 0:
            return
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            raise self._fail(f"append: time is {t[bad[0]]} at sample {self.n_samples + bad[0]}")
        previous = t if self._last_time is None else np.concatenate(([self._last_time], t))
        bad = np.flatnonzero(np.diff(previous) <= 0)
        if bad.size:
            i = int(bad[0])
            index = self.n_samples + i + (0 if self._last_time is None else -1) + 1
            raise self._fail(
                f"append: time is not strictly increasing "
                f"(sample {index}: {float(previous[i + 1])!r} s after {float(previous[i])!r} s)"
            )
        for name in ("accel", "gyro"):
            if name in block:
                rows = np.flatnonzero(~np.isfinite(block[name]).all(axis=1))
                if rows.size:
                    self._nonfinite[name].append(rows + self.n_samples)
        self._pending.append(block)
        self._n_pending += k
        self._last_time = float(t[-1])
        self._flush_if_due()

    def _flush_if_due(self) -> None:
        due = _time.monotonic() - self._last_flush >= self._flush_interval_s
        if due or self._n_pending >= _MAX_PENDING_ROWS:
            self.flush()

    def flush(self) -> None:
        """Write buffered samples and segments to the file and flush it to disk (HDF5 flush)."""
        file = self._check_open()
        try:
            if self._pending:
                start, stop = self._n_written, self._n_written + self._n_pending
                for name, dataset in self._datasets.items():
                    dataset.resize(stop, axis=0)
                    dataset[start:stop] = np.concatenate([block[name] for block in self._pending])
                self._pending = []
                self._n_written, self._n_pending = stop, 0
            if self._pending_log:
                start = self._log.shape[0]
                self._log.resize(start + len(self._pending_log), axis=0)
                self._log[start:] = np.array(self._pending_log, dtype=f"S{_LOG_ITEM_BYTES}")
                self._pending_log = []
            file.flush()
        except OSError as exc:
            raise self._fail(f"cannot write ({one_line(exc)})") from None
        self._last_flush = _time.monotonic()

    # segments ------------------------------------------------------------------------------
    def add_segment(
        self,
        kind: str,
        start: int,
        stop: int,
        *,
        label: str | None = None,
        up: np.ndarray | None = None,
        axis: np.ndarray | None = None,
        angle_deg: float | None = None,
        extra: dict[str, Any] | None = None,
    ) -> str:
        """Mark samples ``[start, stop)`` as a segment; return its name (``"0000"``, ...).

        Parameters
        ----------
        kind : str
            ``"static"`` or ``"rotation"``.
        start, stop : int
            Half-open sample range, within the samples appended so far.  Segments are added in
            time order (non-decreasing ``start``) so that their names follow time.
        label : str, optional
            What the person was told.
        up : array_like, shape (3,), optional
            Static only: nominal up direction in the fixture frame; stored scaled to unit length.
        axis : array_like, shape (3,), optional
            Rotation only: nominal rotation axis; stored scaled to unit length.
        angle_deg : float, optional
            Rotation only: known signed rotation angle in degrees.
        extra : dict, optional
            Further attributes (numbers, strings, lists of numbers), e.g. ``{"mounting": 2}``.

        Raises
        ------
        SessionError
            Unknown kind, bad range, options that do not fit the kind, a sensor the writer does
            not record, or NaN/inf samples inside the segment.
        """
        self._check_open()
        name = f"{len(self._segments):04d}"

        def fail(problem: str) -> SessionError:
            return self._fail(f"segment {name}: {problem}")

        if kind not in SEGMENT_KINDS:
            raise fail(f"unknown kind {kind!r} (expected 'static' or 'rotation')")
        try:
            start, stop = operator.index(start), operator.index(stop)
        except TypeError:
            raise fail(f"start and stop must be integers, got {start!r}, {stop!r}") from None
        if not 0 <= start < stop <= self.n_samples:
            raise fail(
                f"samples [{start}, {stop}) are not a non-empty range within the "
                f"{self.n_samples} samples appended so far"
            )
        if self._segments and start < self._segments[-1]["start"]:
            raise fail(
                f"segments must be added in time order (start {start} is before the previous "
                f"segment's start {self._segments[-1]['start']})"
            )
        if label is not None and not isinstance(label, str):
            raise fail(f"label must be a string, got {label!r}")
        entry: dict[str, Any] = {"name": name, "kind": kind, "start": start, "stop": stop}
        if label is not None:
            entry["label"] = label
        for key, value in (extra or {}).items():
            if key in _SEGMENT_ATTRS or key == "name":
                raise fail(f"extra attribute {key!r} is one the format defines")
            if not isinstance(value, int | float | str | list):
                raise fail(f"extra attribute {key!r} must be a number, string or list")
            entry[key] = value
        sensor = "accel" if kind == "static" else "gyro"
        wrong = {"up": up} if kind == "rotation" else {"axis": axis, "angle_deg": angle_deg}
        for option, value in wrong.items():
            if value is not None:
                raise fail(f"{option!r} does not apply to a {kind} segment")
        for option, value in (("up", up), ("axis", axis)):
            if value is not None:
                vector = _as_unit_vector(value)
                if vector is None:
                    raise fail(f"{option!r} must be 3 finite numbers, not all zero, got {value!r}")
                entry[option] = vector.tolist()
        if angle_deg is not None:
            if _as_float(angle_deg) is None:
                raise fail(f"'angle_deg' must be a finite number, got {angle_deg!r}")
            entry["angle_deg"] = float(angle_deg)
        if self._widths[sensor] is None:
            raise fail(f"a {kind} segment needs {sensor}, which this writer does not record")
        if self._nonfinite[sensor]:
            rows = np.concatenate(self._nonfinite[sensor])
            inside = rows[(rows >= start) & (rows < stop)]
            if inside.size:
                raise fail(f"/raw/{sensor} has NaN or inf at sample {inside.min()}")
        logged = json.dumps(entry).encode("utf-8")
        if len(logged) > _LOG_ITEM_BYTES:
            raise fail(f"label too long ({len(label or '')} characters)")
        self._segments.append(entry)
        self._pending_log.append(logged)
        self._flush_if_due()
        return name

    # closing -------------------------------------------------------------------------------
    def close(self) -> None:
        """Flush, end SWMR mode and write the segment groups.  Closing twice does nothing."""
        if self._file is None:
            return
        try:
            self.flush()
        finally:
            self._file.close()
            self._file = None
        try:
            with h5py.File(self.path, "r+", libver="latest") as file:
                group = file["segments"]
                for entry in self._segments:
                    attrs = group.create_group(entry["name"]).attrs
                    for key, value in entry.items():
                        if key in ("up", "axis"):
                            attrs[key] = np.asarray(value, dtype=np.float64)
                        elif key != "name":
                            attrs[key] = value
                del file[_LOG_GROUP]
        except OSError as exc:
            raise self._fail(f"cannot write the segments ({one_line(exc)})") from None


def write_session(path: str | os.PathLike, session: Session, *, overwrite: bool = False) -> None:
    """Write a complete session file, including ``session.calibrations``.

    Parameters
    ----------
    path : str or path-like
        The file to create.
    session : Session
        What to write.  Segments are written in order of ``start`` and renamed
        ``0000``, ``0001``, ...; ``up``/``axis`` are stored scaled to unit length.
    overwrite : bool
        Replace an existing file instead of refusing.

    Raises
    ------
    InputError
        The file exists or cannot be written, or the session breaks the format (SessionError).
    """
    accel, gyro = session.accel, session.gyro
    with SessionWriter(
        path,
        created=session.created,
        sensor=session.sensor,
        source=session.source,
        sample_rate_hz=session.sample_rate_hz,
        gravity=session.gravity,
        accel_units=session.accel_units,
        gyro_units=session.gyro_units,
        accel_channels=None if accel is None else np.shape(accel)[1],
        gyro_channels=None if gyro is None else np.shape(gyro)[1],
        temperature=session.temperature is not None,
        overwrite=overwrite,
    ) as writer:
        writer.append(session.time, accel, gyro, session.temperature)
        for segment in sorted(session.segments, key=lambda s: s.start):
            writer.add_segment(
                segment.kind,
                segment.start,
                segment.stop,
                label=segment.label,
                up=segment.up,
                axis=segment.axis,
                angle_deg=segment.angle_deg,
                extra=segment.extra,
            )
    for name, text in session.calibrations.items():
        store_calibration(path, text, name)


def store_calibration(path: str | os.PathLike, json_text: str, name: str | None = None) -> str:
    """Store a calibration JSON in a session as ``/calibrations/<name>``, attribute ``json``.

    Never touches ``/raw`` or ``/segments``.

    Parameters
    ----------
    path : str or path-like
        An existing session file.
    json_text : str
        The calibration JSON.
    name : str, optional
        Subgroup name; default the next zero-padded number (``"0000"``, ``"0001"``, ...).

    Returns
    -------
    str
        The name used.

    Raises
    ------
    SessionError
        The file is not a session or cannot be written, ``json_text`` is not JSON, or ``name``
        is taken or not a valid name.
    """
    path = Path(path)
    src = str(path)
    try:
        json.loads(json_text)
    except (TypeError, json.JSONDecodeError) as exc:
        raise SessionError(f"{src}: calibration to store is not valid JSON ({exc})") from None
    if name is not None and (not isinstance(name, str) or not name or "/" in name or name == "."):
        raise SessionError(f"{src}: {name!r} is not a valid calibration name")
    _check_session_file(path, src)
    try:
        file = h5py.File(path, "r+")
    except OSError as exc:
        raise SessionError(f"{src}: cannot open for writing ({one_line(exc)})") from None
    with file:
        if as_str(file.attrs.get("format")) != FORMAT:
            raise SessionError(f"{src}: not an imucal session (format is not {FORMAT!r})")
        group = file.get("calibrations")
        if group is None:
            group = file.create_group("calibrations")
        elif not isinstance(group, h5py.Group):
            raise SessionError(f"{src}: /calibrations is not a group")
        if name is None:
            numbers = [int(key) for key in group if key.isdigit()]
            name = f"{max(numbers, default=-1) + 1:04d}"
        if name in group:
            raise SessionError(f"{src}: /calibrations/{name} already exists")
        group.create_group(name).attrs["json"] = json_text
    return name
