"""Writing sessions: :class:`SessionWriter` records one while it is captured; :func:`write_session`
writes a complete :class:`~.model.Session` in one go (through the writer)."""

from __future__ import annotations

import json
import operator
import os
import time as _time
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from imucal_cli.errors import InputError, SessionError

from .model import (
    FORMAT,
    FORMAT_VERSION,
    LOG_DATASET,
    LOG_GROUP,
    LOG_ITEM_BYTES,
    MAG_UNITS,
    SEGMENT_ATTRS,
    SEGMENT_KINDS,
    Session,
    as_float,
    as_unit_vector,
    one_line,
    utc_now_iso,
)
from .store import store_calibration

_CHUNK_ROWS = 1024  # samples per HDF5 chunk of the /raw datasets
_MAX_PENDING_ROWS = 65536  # the writer writes out earlier than its flush interval past this


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
    sensor, source, accel_units, gyro_units, mag_units : str, optional
        Root attributes, written only when given (``mag_units`` one of ``MAG_UNITS``).
    sample_rate_hz : float, optional
        Nominal rate in Hz, written only when given.
    gravity : float, optional
        Local gravity in m/s^2, written only when given.
    magnetic_field_uT : float, optional
        Local geomagnetic field magnitude in microtesla, written only when given.
    accel_channels, gyro_channels, mag_channels : int or None
        Raw channels per sample (>= 3); None records no such sensor (default: no magnetometer).
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
        mag_channels: int | None = None,
        mag_units: str | None = None,
        magnetic_field_uT: float | None = None,
        temperature: bool = False,
        flush_interval_s: float = 1.0,
        overwrite: bool = False,
    ) -> None:
        self.path = Path(path)
        self._src = src = str(path)
        channel_counts = {
            "accel_channels": accel_channels, "gyro_channels": gyro_channels,
            "mag_channels": mag_channels,
        }  # fmt: skip
        for name, channels in channel_counts.items():
            valid = isinstance(channels, int | np.integer) and channels >= 3
            if channels is not None and not valid:
                raise InputError(f"{src}: {name} must be an integer >= 3 or None, got {channels!r}")
        if mag_units is not None and mag_units not in MAG_UNITS:
            raise InputError(f"{src}: mag_units must be one of {', '.join(MAG_UNITS)}, "
                             f"got {mag_units!r}")  # fmt: skip
        numbers = (("sample_rate_hz", sample_rate_hz), ("gravity", gravity),
                   ("magnetic_field_uT", magnetic_field_uT))  # fmt: skip
        for name, number in numbers:
            value = None if number is None else as_float(number)
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
            "mag_units": mag_units,
            "magnetic_field_uT": None if magnetic_field_uT is None else float(magnetic_field_uT),
        }
        attrs.update({k: v for k, v in optional.items() if v is not None})

        self._widths: dict[str, int | None] = {
            "accel": None if accel_channels is None else int(accel_channels),
            "gyro": None if gyro_channels is None else int(gyro_channels),
            "mag": None if mag_channels is None else int(mag_channels),
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
            for name in ("accel", "gyro", "mag"):
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
                LOG_DATASET, shape=(0,), maxshape=(None,), chunks=(16,),
                dtype=f"S{LOG_ITEM_BYTES}",
            )  # fmt: skip
            self._file.swmr_mode = True
        except OSError as exc:
            self._file.close()
            raise InputError(f"{src}: cannot write ({one_line(exc)})") from None
        self._last_flush = _time.monotonic()

    # continuing a capture ------------------------------------------------------------------
    @classmethod
    def reopen(cls, path: str | os.PathLike, *, flush_interval_s: float = 1.0) -> SessionWriter:
        """Continue a session a capture wrote (``imucal capture --resume``): samples and
        segments are appended after those already there, as if the capture had not stopped.

        The session is read and checked first (a capture killed before it wrote its segment
        groups has them in its log).  Its segments are kept and written again, with the new ones,
        at :meth:`close`; until then they are in the log, so a crash loses none.

        Raises
        ------
        InputError
            Not a session, or one with fixed-size datasets (not written by a capture).
        """
        from .reader import read_session

        session = read_session(path)
        self = cls.__new__(cls)
        self.path, self._src = Path(path), str(path)
        try:
            self._file = h5py.File(self.path, "r+", libver="latest")
        except OSError as exc:
            raise InputError(f"{path}: cannot open it to continue ({one_line(exc)})") from None
        try:
            self._reopen_datasets(len(session.time))
            self._reopen_segments(session)
            self._file.attrs["resumed"] = int(self._file.attrs.get("resumed", 0)) + 1
            self._file.swmr_mode = True
        except (OSError, InputError) as exc:
            self._file.close()
            if isinstance(exc, InputError):
                raise
            raise InputError(f"{path}: cannot continue it ({one_line(exc)})") from None
        self._flush_interval_s = float(flush_interval_s)
        self._n_written, self._pending, self._n_pending = len(session.time), [], 0
        self._last_time = float(session.time[-1]) if len(session.time) else None
        self._nonfinite = {
            name: [np.flatnonzero(~np.isfinite(data).all(axis=1))] if data is not None else []
            for name, data in (("accel", session.accel), ("gyro", session.gyro))
        }
        self._last_flush = _time.monotonic()
        self.flush()
        return self

    @property
    def last_time(self) -> float | None:
        """Time of the last sample appended (or already in a reopened session), s."""
        return self._last_time

    def _reopen_datasets(self, n: int) -> None:
        """The /raw datasets of a reopened file, cut to the ``n`` samples it holds whole."""
        raw = self._file["raw"]
        self._datasets = {}
        for name in ("accel", "gyro", "mag", "temperature", "time"):  # time last, as written
            ds = raw.get(name)
            if ds is None:
                continue
            if ds.maxshape[0] is not None:
                raise InputError(
                    f"{self._src}: /raw/{name} has a fixed size (the session was not written by "
                    "imucal capture): it cannot be continued"
                )
            if ds.shape[0] != n:  # a killed writer may have written data beyond the last time
                ds.resize(n, axis=0)
            self._datasets[name] = ds
        self._widths = {name: self._datasets[name].shape[1] if name in self._datasets else None
                        for name in ("accel", "gyro", "mag")}  # fmt: skip

    def _reopen_segments(self, session: Session) -> None:
        """Keep the session's segments: in memory and, until :meth:`close`, in the log."""
        group = self._file.require_group("segments")
        for name in list(group):
            del group[name]
        if LOG_GROUP in self._file:
            del self._file[LOG_GROUP]
        self._log = self._file.create_dataset(
            LOG_DATASET, shape=(0,), maxshape=(None,), chunks=(16,), dtype=f"S{LOG_ITEM_BYTES}"
        )
        self._segments, self._pending_log = [], []
        for seg in session.segments:
            entry: dict[str, Any] = {"name": f"{len(self._segments):04d}", "kind": seg.kind,
                                     "start": int(seg.start), "stop": int(seg.stop)}  # fmt: skip
            optional = {
                "label": seg.label,
                "angle_deg": seg.angle_deg,
                "up": None if seg.up is None else np.asarray(seg.up).tolist(),
                "axis": None if seg.axis is None else np.asarray(seg.axis).tolist(),
            }
            entry.update({k: v for k, v in optional.items() if v is not None}, **seg.extra)
            self._segments.append(entry)
            self._pending_log.append(json.dumps(entry).encode("utf-8"))

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
        mag: np.ndarray | None = None,
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
        mag : ndarray, shape (k, nm) or (nm,)
            Raw magnetometer channels; required exactly when the writer records mag (NaN
            where the magnetometer gave no reading).

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
        given = {"accel": accel, "gyro": gyro, "temperature": temperature, "mag": mag}
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
                self._log[start:] = np.array(self._pending_log, dtype=f"S{LOG_ITEM_BYTES}")
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
            if key in SEGMENT_ATTRS or key == "name":
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
                vector = as_unit_vector(value)
                if vector is None:
                    raise fail(f"{option!r} must be 3 finite numbers, not all zero, got {value!r}")
                entry[option] = vector.tolist()
        if angle_deg is not None:
            if as_float(angle_deg) is None:
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
        if len(logged) > LOG_ITEM_BYTES:
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
                del file[LOG_GROUP]
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
    accel, gyro, mag = session.accel, session.gyro, session.mag
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
        mag_channels=None if mag is None else np.shape(mag)[1],
        mag_units=session.mag_units,
        magnetic_field_uT=session.magnetic_field_uT,
        temperature=session.temperature is not None,
        overwrite=overwrite,
    ) as writer:
        writer.append(session.time, accel, gyro, session.temperature, mag)
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
