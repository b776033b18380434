"""Writing sessions: :class:`SessionWriter` records one while it is captured; :func:`write_session`
(in :mod:`.complete`) writes a complete :class:`~.model.Session` in one go (through the writer).
Continuing a capture's session is :mod:`.resume`'s; the disk's room and a write that failed are
:mod:`.disk`'s.

Safety (issue 11): the file is created through :class:`~imucal_cli.formats.output.OutputFile`
(a fresh temporary file in the target's folder, renamed into place: at once for a capture,
``publish_early``, so that ``kill -9`` loses at most the last flush; when complete otherwise).
The ``/raw`` datasets carry Fletcher32 checksums (corruption is detected on read) and NaN as
fill value (rows grown but never written read as NaN, never as made-up zeros).  A write that
fails (disk full: h5py raises ``OSError`` or ``RuntimeError``) raises :class:`WriteFailed`
and keeps the samples in memory, so that :meth:`SessionWriter.flush` can be tried again once
space is freed, or :meth:`SessionWriter.drop_pending` gives them up and shrinks the datasets
back to what was written.
"""

from __future__ import annotations

import os
import time as _time
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from imucal_cli.errors import InputError, SessionError, WriteFailed
from imucal_cli.model.imu_stream import REFERENCE_NAME
from imucal_cli.model.session import (
    FORMAT,
    FORMAT_VERSION,
    MAG_UNITS,
    as_float,
    io_reason,
    utc_now_iso,
)

from ..output import OutputFile
from .disk import CHUNK_ROWS, WRITE_ERRORS, FailedWrites, Reserve, chunk_rows, free_bytes
from .imu_writer import ImuDatasets, ImuLayout
from .resume import Resumable
from .rewrite import Rewritable
from .segments import SegmentLog, segment_entry

_MAX_PENDING_ROWS = 65536  # the writer writes out earlier than its flush interval past this

def _check_options(
    src: str, channels: dict[str, Any], numbers: dict[str, Any], mag_units: str | None
) -> None:
    if mag_units is not None and mag_units not in MAG_UNITS:
        raise InputError(
            f"{src}: mag_units must be one of {', '.join(MAG_UNITS)}, got {mag_units!r}"
        )
    for name, value in channels.items():
        valid = isinstance(value, int | np.integer) and not isinstance(value, bool) and value >= 3
        if value is not None and not valid:
            raise InputError(f"{src}: {name} must be an integer >= 3 or None, got {value!r}")
    for name, number in numbers.items():
        value = None if number is None else as_float(number)
        if number is not None and (value is None or value <= 0):
            raise InputError(f"{src}: {name} must be a positive number, got {number!r}")


def _root_attrs(created: str | None, **optional: Any) -> dict[str, Any]:
    """The root attributes of a new session: format, version, creation time, then the
    optional ones that were given (numbers as floats)."""
    attrs: dict[str, Any] = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "created": created if created is not None else utc_now_iso(),
    }
    for key, value in optional.items():
        if value is not None:
            attrs[key] = float(value) if isinstance(value, int | float) else value
    return attrs


class SessionWriter(Resumable, Rewritable, FailedWrites):
    """Write a session while it is recorded; a context manager.

    Samples are buffered and written to chunked, resizable ``/raw`` datasets, followed by an
    HDF5 flush, at least every ``flush_interval_s`` while :meth:`append` is called.  The file
    is in SWMR mode, so :func:`read_session` can read it while it is written, and a writer
    killed with ``kill -9`` leaves a readable file (see the package notes; the next reader
    repairs its "open for writing" flag).  Segments are written as ``/segments/NNNN`` groups
    on :meth:`close`.

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
    host_time : bool
        Whether samples carry the host's arrival time beside the device's (``/raw/host_time``,
        seconds of the host's clock; an extra dataset the spec allows, issue 17.2).
    flush_interval_s : float
        Longest time in seconds appended samples stay in memory.
    overwrite : bool
        Replace an existing file instead of refusing.
    inputs : iterable of path-like
        Files never to replace (the command's inputs).
    publish_early : bool
        Give the file its name at once (a capture); otherwise only :meth:`close` does, and a
        writer that fails leaves nothing at ``path``.
    reserve_bytes : int
        Disk space set aside next to the file at the start and freed when a write fails, so
        that the file can still be closed cleanly on a full disk.
    imus : dict of str to ImuLayout, optional
        The other IMUs of a set (``/imus/<name>``, issue 28), appended with
        :meth:`append_imu`; ``reference_name`` names the IMU of ``/raw``.

    Raises
    ------
    InputError
        The file exists (and ``overwrite`` is false), is an input, cannot be created, or an
        option is bad.
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
        host_time: bool = False,
        flush_interval_s: float = 1.0,
        overwrite: bool = False,
        inputs=(),
        publish_early: bool = False,
        reserve_bytes: int = 0,
        imus: dict[str, ImuLayout] | None = None,
        reference_name: str = REFERENCE_NAME,
    ) -> None:
        self._imu_layouts = (dict(imus or {}), reference_name)
        self.path = Path(path)
        self._src = str(path)
        _check_options(
            self._src,
            {
                "accel_channels": accel_channels,
                "gyro_channels": gyro_channels,
                "mag_channels": mag_channels,
            },
            {
                "sample_rate_hz": sample_rate_hz,
                "gravity": gravity,
                "magnetic_field_uT": magnetic_field_uT,
            },
            mag_units,
        )
        attrs = _root_attrs(
            created, sensor=sensor, source=source, sample_rate_hz=sample_rate_hz,
            gravity=gravity, accel_units=accel_units, gyro_units=gyro_units,
            mag_units=mag_units, magnetic_field_uT=magnetic_field_uT,
        )  # fmt: skip
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
        self._last_written_time: float | None = None
        self._nonfinite: dict[str, list[np.ndarray]] = {"accel": [], "gyro": []}
        self._file: h5py.File | None = None
        self._out = OutputFile(self.path, force=overwrite, inputs=inputs)
        self._reserve = Reserve(self.path, 0)
        self._open(attrs, (temperature, host_time), publish_early, reserve_bytes)
        self._last_flush = _time.monotonic()

    def _open(self, attrs: dict[str, Any], temperature: tuple[bool, bool], publish_early: bool,
              reserve_bytes: int) -> None:  # fmt: skip
        """Create the file's layout in its temporary file; nothing is left when that fails."""
        try:
            self._file = self._out.h5(libver="latest")
            self._create_layout(attrs, temperature)
            self._file.swmr_mode = True
            if publish_early:
                self._out.publish()
            self._reserve = Reserve(self.path, reserve_bytes)
        except BaseException as exc:
            self._abandon()
            if isinstance(exc, WRITE_ERRORS):
                raise InputError(f"{self._src}: cannot write ({io_reason(exc)})") from None
            raise

    def _create_layout(self, attrs: dict[str, Any], temperature: tuple[bool, bool]) -> None:
        """``temperature``: whether ``/raw/temperature`` and ``/raw/host_time`` are recorded."""
        temperature, host_time = temperature
        file = self._file
        file.attrs.update(attrs)
        raw = file.create_group("raw")
        # Written in this order at each flush; time last, so it is never longer than data.
        self._datasets: dict[str, h5py.Dataset] = {}
        self.chunk_rows = chunk_rows(free_bytes(self.path), self._row_bytes(temperature, host_time))
        shapes = {
            "accel": self._widths["accel"],
            "gyro": self._widths["gyro"],
            "mag": self._widths["mag"],
            "temperature": 0 if temperature else None,
            "host_time": 0 if host_time else None,
            "time": 0,
        }
        for name, width in shapes.items():
            if width is None:
                continue
            tail = (width,) if width else ()
            self._datasets[name] = raw.create_dataset(
                name, shape=(0, *tail), maxshape=(None, *tail), chunks=(self.chunk_rows, *tail),
                dtype="f8", fillvalue=np.nan, fletcher32=True,
            )  # fmt: skip
        file.create_group("segments")
        self._log = SegmentLog(file, small=self.chunk_rows < CHUNK_ROWS)
        layouts, reference = self._imu_layouts
        if layouts:  # several IMUs (issue 28): created before SWMR mode, like /raw
            self._imus = ImuDatasets(file, layouts, reference, self.chunk_rows, self._src)

    def _row_bytes(self, temperature: bool, host_time: bool) -> int:
        """Bytes one sample takes in ``/raw`` (float64 values)."""
        values = sum(w for w in self._widths.values() if w) + 1 + temperature + host_time
        return 8 * values

    @property
    def bytes_per_sample(self) -> int:
        """Bytes one sample takes in the file's ``/raw`` datasets.  Their widths are fixed when
        they are made: read once per set of datasets, not at every block a capture appends
        (h5py's ``shape`` is 10-20 us a call; six of them a block were a tenth of a capture's
        CPU)."""
        datasets = self._datasets
        known = getattr(self, "_sample_bytes", None)
        if known is None or known[0] is not datasets or known[1] != len(datasets):
            size = 8 * sum(int(np.prod(ds.shape[1:])) for ds in datasets.values())
            known = self._sample_bytes = (datasets, len(datasets), size)
        return known[2]

    @property
    def chunk_bytes(self) -> int:
        """Bytes the file grows by when a new chunk of every ``/raw`` dataset is allocated."""
        return self.chunk_rows * self.bytes_per_sample + 4 * len(self._datasets)

    def room(self) -> int | None:
        """Bytes still free on the file's file system for this writer (the space it set aside
        itself not counted as free), or None when the system does not say."""
        return free_bytes(self.path)

    def _abandon(self) -> None:
        """Close and remove a file that never became a session (a failed start)."""
        if self._file is not None:
            try:
                self._file.close()
            except WRITE_ERRORS:
                pass
            self._file = None
        self._out.discard()
        self._reserve.release()

    _imus: ImuDatasets | None = None
    """The other IMUs of a set (``/imus``), None for one IMU."""

    def append_imu(self, name: str, time, **values) -> None:
        """Append a block of the other IMU ``name``'s samples (its own times, on the clock of
        :meth:`append`'s): ``time`` (k,), ``accel=``/``gyro=``/``mag=`` (k, n),
        ``temperature=`` (k,) as its layout records (:class:`ImuDatasets.append`)."""
        self._check_open()
        if self._imus is None:
            raise self._fail(f"append: no IMU {name!r} (this writer records one IMU)")
        self._imus.append(name, time, **values)
        self._flush_if_due()

    @property
    def records_host_time(self) -> bool:
        """Whether samples carry ``host_time`` (``/raw/host_time``)."""
        return "host_time" in self._datasets

    @property
    def last_time(self) -> float | None:
        """Time of the last sample appended (or already in a reopened session), s."""
        return self._last_time

    # context manager ---------------------------------------------------------------------
    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None and not self._out.published:
            self._abandon()  # write_session failed half-way: leave nothing behind
            return
        self.close()

    @property
    def n_samples(self) -> int:
        """Samples appended so far (written to the file or still buffered)."""
        return self._n_written + self._n_pending

    @property
    def n_written(self) -> int:
        """Samples written to the file."""
        return self._n_written

    @property
    def segments(self) -> list[dict[str, Any]]:
        """The segments added so far, as stored (name, kind, start, stop, optional attributes)."""
        return [dict(entry) for entry in self._log.entries]

    def _write_failed(self, exc: BaseException, pending: int, what: str = "write") -> WriteFailed:
        reason = io_reason(exc)
        return WriteFailed(f"{self._src}: cannot {what} ({reason})", pending, reason)

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
        host_time: float | np.ndarray | None = None,
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
        host_time : ndarray, shape (k,), or float
            The host's arrival time of each sample, s (``/raw/host_time``, issue 17.2);
            required exactly when the writer records it.

        Raises
        ------
        SessionError
            Wrong shapes, a missing or unexpected sensor, or times that are not finite and
            strictly increasing.  Nothing of the block is kept then.
        WriteFailed
            The block was kept but writing what is due failed (see :meth:`flush`).
        """
        self._check_open()
        given = {"accel": accel, "gyro": gyro, "temperature": temperature, "mag": mag,
                 "host_time": host_time}  # fmt: skip
        block = self._block(time, given)
        t = block["time"]
        if t.size == 0:
            return
        self._check_times(t)
        for name in ("accel", "gyro"):
            if name in block:
                rows = np.flatnonzero(~np.isfinite(block[name]).all(axis=1))
                if rows.size:
                    self._nonfinite[name].append(rows + self.n_samples)
        self._pending.append(block)
        self._n_pending += t.size
        self._last_time = float(t[-1])
        self._flush_if_due()

    def _block(self, time: Any, given: dict[str, Any]) -> dict[str, np.ndarray]:
        t = np.asarray(time, dtype=np.float64)
        single = t.ndim == 0
        t = t.reshape(-1) if single else t
        if t.ndim != 1:
            raise self._fail(f"append: time must be a number or 1-D, has shape {t.shape}")
        k = t.size
        block = {"time": t}
        for name, value in given.items():
            flat = name in ("temperature", "host_time")
            expected = (k,) if flat else (k, self._widths[name])
            recorded = name in self._datasets
            if value is None and recorded:
                raise self._fail(f"append: {name} is missing (this writer records {name})")
            if value is not None and not recorded:
                raise self._fail(f"append: got {name}, but this writer does not record {name}")
            if value is None:
                continue
            array = np.asarray(value, dtype=np.float64)
            if single:
                array = array.reshape((1, -1) if not flat else (1,))
            if array.shape != expected:
                raise self._fail(f"append: {name} has shape {array.shape}, expected {expected}")
            block[name] = array
        return block

    def _check_times(self, t: np.ndarray) -> None:
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

    def _flush_if_due(self) -> None:
        due = _time.monotonic() - self._last_flush >= self._flush_interval_s
        pending = self._n_pending + (self._imus.n_pending if self._imus is not None else 0)
        if due or pending >= _MAX_PENDING_ROWS:
            self.flush()

    def flush(self) -> None:
        """Write buffered samples and segments to the file and flush it to disk (HDF5 flush).

        Raises
        ------
        WriteFailed
            The write failed (disk full, I/O error).  The samples stay buffered: call
            :meth:`flush` again (after freeing space, e.g. :meth:`release_reserve`) or give
            them up with :meth:`drop_pending`.
        """
        file = self._check_open()
        log_rows = self._log.dataset.shape[0]
        try:
            if self._pending:
                start, stop = self._n_written, self._n_written + self._n_pending
                for name, dataset in self._datasets.items():
                    dataset.resize(stop, axis=0)
                    dataset[start:stop] = np.concatenate([block[name] for block in self._pending])
            if self._imus is not None:
                self._imus.write()
            self._log.flush()
            file.flush()
        except WRITE_ERRORS as exc:
            self._roll_back(log_rows)
            raise self._write_failed(exc, self._n_pending) from None
        if self._pending:
            self._last_written_time = float(self._pending[-1]["time"][-1])
        if self._imus is not None:
            self._imus.written()
        self._pending = []
        self._n_written += self._n_pending
        self._n_pending = 0
        self._log.flushed()
        self._last_flush = _time.monotonic()

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
        segments = self._log.entries
        name = f"{len(segments):04d}"

        def fail(problem: str) -> SessionError:
            return self._fail(f"segment {name}: {problem}")

        options = {"label": label, "up": up, "axis": axis, "angle_deg": angle_deg}
        try:
            entry = segment_entry(name, kind, start, stop, self.n_samples, extra=extra, **options)
        except ValueError as exc:
            raise fail(str(exc)) from None
        if segments and entry["start"] < segments[-1]["start"]:
            raise fail(
                f"segments must be added in time order (start {entry['start']} is before the "
                f"previous segment's start {segments[-1]['start']})"
            )
        sensor = "accel" if kind == "static" else "gyro"
        if self._widths[sensor] is None:
            raise fail(f"a {kind} segment needs {sensor}, which this writer does not record")
        if self._nonfinite[sensor]:
            rows = np.concatenate(self._nonfinite[sensor])
            inside = rows[(rows >= entry["start"]) & (rows < entry["stop"])]
            if inside.size:
                raise fail(f"/raw/{sensor} has NaN or inf at sample {inside.min()}")
        try:
            self._log.add(entry)
        except ValueError:
            raise fail(f"label too long ({len(label or '')} characters)") from None
        self._flush_if_due()
        return name

    # closing -------------------------------------------------------------------------------
    def close(self, attrs: dict[str, Any] | None = None) -> None:
        """Flush, end SWMR mode, write the segment groups and give the file its name.

        Closing twice does nothing.  Samples that cannot be written stay out (a
        :class:`WriteFailed` is raised after the file was closed with what was written); a
        file not yet in place (no ``publish_early``: a session written in one go) is then
        removed, never put in place half written.
        ``attrs``: root attributes known only at the end (``sample_rate_hz``), written with
        the segment groups (no attribute can be created in SWMR mode).
        """
        if self._file is None:
            return
        failed: WriteFailed | None = None
        try:
            self.flush()
        except WriteFailed:
            self.release_reserve()
            try:
                self.flush()
            except WriteFailed as exc:
                failed = WriteFailed(str(exc), self.drop_pending(), exc.reason)
        try:
            self._file.close()
        except WRITE_ERRORS as exc:
            failed = failed or self._write_failed(exc, 0, "close")
        finally:
            self._file = None
        try:
            self._write_segment_groups(attrs or {})
        except WRITE_ERRORS as exc:  # the log stays; readers use it
            failed = failed or self._write_failed(exc, 0, "write the segments")
        self._reserve.release()
        if failed is not None and not self._out.published:
            self._out.discard()  # a session written in one go: all of it, or none
            raise failed
        self._out.commit()
        if failed is not None:
            raise failed

    def _write_segment_groups(self, attrs: dict[str, Any]) -> None:
        self._log.write(self._out.tmp if not self._out.published else self.path, attrs)

    def add_calibration(self, name: str, json_text: str) -> None:
        """Store a calibration JSON as ``/calibrations/<name>`` when the file is closed.

        Raises
        ------
        SessionError
            ``json_text`` is not JSON, or ``name`` is taken or not a valid name.
        """
        self._log.add_calibration(self._src, name, json_text)
