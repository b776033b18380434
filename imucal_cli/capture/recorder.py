"""Record a stream into a session while it arrives, and end cleanly whatever happens.

:class:`Recorder` reads a source through a protocol, appends every block of samples to a
:class:`~imucal_cli.formats.session.SessionWriter` (opened on the first samples, with the channel
counts the data show) and hands the blocks to the user interface through :meth:`Recorder.blocks`.
The capture ends, always with a valid session holding every sample received, on:

- Ctrl-C (SIGINT), SIGTERM or SIGHUP (the terminal closed): handlers installed from the start
  of the recording until :meth:`Recorder.close` set a flag (the previous handlers are restored
  then), so a signal while the segments are being added ends nothing half-way; ``end_kind``
  ``"interrupted"`` / ``"terminated"`` / ``"hangup"``;
- the disk nearly full: the free space is checked with every block against what the rest of
  the capture needs (:func:`~imucal_cli.capture.checks.headroom`: the next seconds of samples,
  the segments still to come, closing the file); below it the capture stops, and the file is
  closed cleanly with every sample received and every segment (``"disk-full"``).  A write that
  fails all the same (another program filled the disk) frees the space set aside at the start
  (:data:`RESERVE_BYTES`) and tries again; :attr:`Recorder.samples_lost` says how many received
  samples could still not be written, and segments over them are left out
  (:attr:`Recorder.segments_left_out`);
- time stamps in the wrong unit (:func:`~imucal_cli.capture.checks.clock_problem`, checked once
  after :data:`CLOCK_CHECK_S`): ``"clock"``; the caller discards what this capture wrote
  (:meth:`Recorder.discard`);
- the device disappearing (unplugged, pseudo-terminal closed): ``"device-gone"``;
- no valid line for ``wait_timeout_s`` at the start, or for ``read_timeout_s`` once data
  flowed, judged after a read that found nothing (a host away longer reads what waited):
  ``"timeout"``;
- :meth:`Recorder.stop` (the UI is done): ``"done"``.

Samples reach the file at least every :data:`FLUSH_INTERVAL_S` (the writer flushes on append;
the recorder also flushes when the stream stalls), so after ``kill -9`` the file opens with at
most the last second missing.

The writes themselves (a block appended, a flush, a write that failed) are :mod:`.writing`'s;
:class:`CaptureEnded` is :mod:`.checks`' (importable from here).
"""

from __future__ import annotations

import os
import signal
import threading
import time as _time
from collections.abc import Callable, Iterator
from pathlib import Path

from imucal_cli.capture.checks import (
    CLOCK_CHECK_S,
    CaptureEnded,
    DiskRoom,
    clock_problem,
    fell_behind,
    no_data_reason,
)
from imucal_cli.capture.stream import DeviceGone
from imucal_cli.capture.writing import SessionWrites
from imucal_cli.errors import InputError, SessionError, WriteFailed
from imucal_cli.formats.columns import SampleBlock
from imucal_cli.formats.output import check_output
from imucal_cli.formats.session import SessionWriter

__all__ = ["CLOCK_CHECK_S", "END_KINDS", "FLUSH_INTERVAL_S", "CaptureEnded", "Recorder"]

FLUSH_INTERVAL_S = 0.5
"""Longest time a received sample stays in memory before it is written and flushed."""

END_KINDS = (
    "interrupted", "terminated", "hangup", "device-gone", "disk-full", "timeout", "done", "clock",
)  # fmt: skip

RESERVE_BYTES = 4 << 20
"""Disk space set aside next to the session while recording (at most a sixteenth of the free
space), freed when the disk is nearly full or a write fails."""

_SIGNALS = {
    signal.SIGINT: ("interrupted", "Ctrl-C"),
    signal.SIGTERM: ("terminated", "SIGTERM"),
    **(
        {signal.SIGHUP: ("hangup", "SIGHUP (terminal closed)")} if hasattr(signal, "SIGHUP") else {}
    ),
}

NOTE_MIN_BYTES = 512
"""Bytes without a complete line before a capture that ended says what they were."""

STATUS_REPEAT_S = 5.0
"""While waiting for data, the waiting message is repeated this often."""


class Recorder(SessionWrites):
    """Append a live stream to a session file.

    Parameters
    ----------
    path : str or path-like
        Session file to create.  Checked at once (exists without ``overwrite``, no such
        directory); written from the first samples on.  No file is created when no sample
        ever arrives.
    source : SerialSource or similar
        ``read() -> bytes``, ``close()``, ``describe() -> str``, ``uri``; see
        :mod:`imucal_cli.capture.stream`.
    protocol : LineProtocol or similar
        ``feed(data, host_time) -> SampleBlock`` and ``stats``.
    sensor, accel_units, gyro_units, mag_units : str, optional
        Root attributes of the session.
    magnetic_field_uT : float, optional
        Local field magnitude, microtesla (root attribute), where known.
    overwrite : bool
        Replace an existing file.
    wait_timeout_s : float
        Give up when no valid sample arrived this long after the start.
    read_timeout_s : float
        Give up when no valid sample arrived this long after the last one.
    on_status : callable, optional
        Called with one-line messages while recording (``"waiting for data on /dev/ttyUSB0 at
        115200 baud"``, ``"receiving data: 8 fields per line"``).

    Attributes
    ----------
    end_kind : str or None
        Why :meth:`blocks` ended: one of :data:`END_KINDS` (None while recording).
    end_reason : str
        The same for the user, one line.
    samples_lost : int
        Samples received but not written (a write failed on a disk filled by another
        program; 0 when the recorder stopped in time).
    segments_left_out : int
        Segments not added because their samples could not be written.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        source,
        protocol,
        *,
        sensor: str | None = None,
        accel_units: str | None = None,
        gyro_units: str | None = None,
        mag_units: str | None = None,
        magnetic_field_uT: float | None = None,
        overwrite: bool = False,
        wait_timeout_s: float = 10.0,
        read_timeout_s: float = 5.0,
        on_status: Callable[[str], None] | None = None,
        resume: bool = False,
    ) -> None:
        if resume:
            self.path = Path(path)  # continued in place (SessionWriter.reopen checks it)
        else:
            self.path = check_output(path, force=overwrite)
        self.source = source
        self.protocol = protocol
        self._meta = {"sensor": sensor, "accel_units": accel_units, "gyro_units": gyro_units,
                      "mag_units": mag_units, "magnetic_field_uT": magnetic_field_uT}  # fmt: skip
        self.accel_units = accel_units  #: raw accelerometer units as the user gave them
        self.gyro_units = gyro_units  #: raw gyroscope units as the user gave them
        self._overwrite = overwrite
        self.wait_timeout_s = float(wait_timeout_s)
        self.read_timeout_s = float(read_timeout_s)
        self._on_status = on_status
        self._writer = None
        self._stop = False
        self._signal_kind: str | None = None
        self._old_handlers: dict[int, object] = {}
        self.end_kind: str | None = None
        self.end_reason = ""
        self._t0: float | None = None
        opened = getattr(source, "opened_at", None)  # the port's open: the device's stream
        self._t_open = float(opened) if isinstance(opened, int | float) else _time.monotonic()
        self._t_first: float | None = None
        self._t_last_sample: float | None = None
        self._device_first: float | None = None  # time stamp of the first sample, s
        self._device_last: float | None = None
        self._clock_checked = False
        self._t_end: float | None = None
        self._closed = False
        self.samples_lost = 0  #: samples received but not written (disk full)
        self.segments_left_out = 0  #: segments over samples that could not be written
        self._room = DiskRoom()
        self._device_at_segment: float | None = None  # device time of the last segment added
        self._discarded = False
        self.resumed_from = 0  #: samples the session held before this capture (``resume``)
        self._time_offset: float | None = None  # added to this capture's time stamps (resume)
        self._host_offset: float | None = None  # the same for host arrival times (resume)
        self._resume_gap_s = 0.0
        self._segments_before = 0  # the resumed session's own segments (not this capture's)
        self._imu_starts: dict[str, int] = {}  # the same per other IMU of a set (resume)
        if resume:
            self._reopen()

    def _reopen(self) -> None:
        """``resume``: continue the session; its samples and segments stay, new ones follow."""
        if not self.path.is_file():
            raise InputError(f"{self.path}: no such session to resume")
        gap_s = max(_time.time() - self.path.stat().st_mtime, 0.0)  # since its last flush
        layouts = getattr(self.protocol, "imu_layouts", None)  # several IMUs: the same
        self._writer = SessionWriter.reopen(self.path, flush_interval_s=FLUSH_INTERVAL_S,
                                            imus=None if layouts is None else layouts())
        self.resumed_from = self._writer.n_samples
        self._imu_starts = self._writer.imu_counts()
        self._segments_before = len(self._writer.segments)
        self._resume_gap_s = gap_s

    # status ------------------------------------------------------------------------------------
    def _status(self, message: str) -> None:
        if self._on_status is not None:
            self._on_status(message)

    @property
    def n_samples(self) -> int:
        """Samples appended so far; segment indices refer to these."""
        return 0 if self._writer is None else self._writer.n_samples

    @property
    def recording(self) -> bool:
        """Whether :meth:`blocks` is running and has not ended."""
        return self._t0 is not None and self.end_kind is None

    @property
    def samples_received(self) -> int:
        """Samples this capture received (written, still buffered, or lost)."""
        return self.n_samples - self.resumed_from + self.samples_lost

    @property
    def samples_written(self) -> int:
        """Samples of this capture in the file."""
        return 0 if self._writer is None else self._writer.n_written - self.resumed_from

    @property
    def device_span_s(self) -> float:
        """Device time from this capture's first sample to its last, s (0 before two)."""
        if self._device_first is None or self._device_last is None:
            return 0.0
        return max(self._device_last - self._device_first, 0.0)

    @property
    def rate_hz(self) -> float:
        """Mean sample rate in device time, Hz (0 before two samples)."""
        n, span = self.n_samples - self.resumed_from, self.device_span_s
        return (n - 1) / span if span > 0 and n > 1 else 0.0

    @property
    def behind(self) -> str | None:
        """Why the samples arrived slower than the device's clock ran, or None
        (:func:`~imucal_cli.capture.checks.fell_behind`)."""
        if self._t_first is None or self._t_last_sample is None:
            return None
        return fell_behind(self.device_span_s, self._t_last_sample - self._t_first,
                           self.rate_hz or None)  # fmt: skip

    @property
    def stats(self) -> dict:
        """Protocol counters plus ``samples`` (appended), ``duration_s`` (device time the
        samples span: a backlog read at once or a busy host changes nothing), ``rate_hz``
        (samples per device second), ``wall_s`` (host time since the start), and this
        capture's ``received``, ``written`` and ``lost`` samples."""
        out = dict(self.protocol.stats)
        out["samples"] = self.n_samples
        end = self._t_end if self._t_end is not None else _time.monotonic()
        out["wall_s"] = 0.0 if self._t0 is None else end - self._t0
        out["duration_s"] = self.device_span_s
        out["rate_hz"] = self.rate_hz
        out["received"] = self.samples_received
        out["written"] = self.samples_written
        out["lost"] = self.samples_lost
        return out

    # signals -----------------------------------------------------------------------------------
    def _install_signals(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return

        def handler(signum, frame):  # noqa: ARG001
            if self._signal_kind is None:
                self._signal_kind = signum
            if self.end_kind == "done":  # the recording was ending anyway: say it was cut
                kind, name = _SIGNALS[signum]
                self.end_kind, self.end_reason = kind, f"stopped by {name}"

        for signum in _SIGNALS:
            try:
                self._old_handlers[signum] = signal.signal(signum, handler)
            except (ValueError, OSError):
                pass

    def _restore_signals(self) -> None:
        for signum, old in self._old_handlers.items():
            try:
                signal.signal(signum, old)
            except (ValueError, OSError, TypeError):
                pass
        self._old_handlers = {}

    # the loop ----------------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask :meth:`blocks` to end after the current read (``end_kind`` ``"done"``)."""
        self._stop = True

    def _open_writer(self, block: SampleBlock) -> None:
        """The session, at the first block: its units those given, else those the protocol's
        format fixes (MotionCal and i2cdevlib lines: counts)."""
        meta = dict(self._meta)
        for key, unit in getattr(self.protocol, "units", {}).items():
            if meta.get(key) is None:
                meta[key] = unit
        self._writer = SessionWriter(
            self.path,
            source=getattr(self.source, "uri", None),
            accel_channels=None if block.accel is None else block.accel.shape[1],
            gyro_channels=None if block.gyro is None else block.gyro.shape[1],
            mag_channels=None if block.mag is None else block.mag.shape[1],
            temperature=block.temperature is not None,
            host_time=block.host_time is not None,
            flush_interval_s=FLUSH_INTERVAL_S,
            overwrite=self._overwrite,
            publish_early=True,
            reserve_bytes=RESERVE_BYTES,
            imus=self.protocol.imu_layouts() if hasattr(self.protocol, "imu_layouts") else None,
            **meta,
        )

    def _check_end(self, now: float, idle: bool) -> CaptureEnded | None:
        """Why the recording ends now, or None.  The timeouts are judged only after a read
        that brought no sample (``idle``): a host that did not read for a while (busy,
        suspended) finds the samples waiting, not a stalled device."""
        what = self.source.describe()
        if self._signal_kind is not None:
            kind, name = _SIGNALS[self._signal_kind]
            return CaptureEnded(kind, f"stopped by {name}")
        if self._stop:
            return CaptureEnded("done", "done")
        if not idle:
            return None
        if self._t_last_sample is None:
            if now - self._t0 >= self.wait_timeout_s:
                return CaptureEnded("timeout", self._no_data_reason(what))
        elif now - self._t_last_sample >= self.read_timeout_s:
            return CaptureEnded(
                "timeout",
                f"no data from {what} for {self.read_timeout_s:g} s after "
                f"{self.n_samples} samples: the device stopped sending",
            )
        return None

    def _no_data_reason(self, what: str, within: str | None = None) -> str:
        """Why no sample came from ``what`` (``within``: " in 10 s", the wait by default)."""
        within = f" in {self.wait_timeout_s:g} s" if within is None else within
        columns = getattr(self.protocol, "columns", None)
        return no_data_reason(self.protocol.stats, what + within,
                              None if columns is None else columns.n_fields,
                              getattr(self.protocol, "not_numbers", None))  # fmt: skip

    def received_note(self) -> str:
        """For a capture that ended before its first sample: what did arrive and why none of
        it was a sample ("" when nothing arrived)."""
        stats = self.protocol.stats
        if self.n_samples > self.resumed_from or stats.get("bytes", 0) == 0:
            return ""
        if stats.get("lines", 0) == 0 and stats.get("bytes", 0) < NOTE_MIN_BYTES:
            return ""  # the first bytes of a first line: too early to tell anything
        return self._no_data_reason(self.source.describe(), within="")

    def blocks(self, tick_s: float = 0.1) -> Iterator[SampleBlock]:
        """Record; yield every block of samples after it was appended to the session.

        Yields an empty block at least every ``tick_s`` seconds when nothing arrived, so that a
        user interface stays live.  Ends (no exception) on Ctrl-C, SIGTERM, the device gone, a
        timeout or :meth:`stop`, with :attr:`end_kind` and :attr:`end_reason` set; the source
        is closed then (segments can still be added until :meth:`close`).  SIGINT, SIGTERM
        and SIGHUP are handled (by setting a flag) from the start of this generator until
        :meth:`close`.

        Parameters
        ----------
        tick_s : float
            Longest interval between two yields, s.

        Raises
        ------
        SessionError
            The session file cannot be written (disk full, ...); samples flushed before stay.
        """
        if self._t0 is not None:
            raise RuntimeError("Recorder.blocks() runs once")
        self._t0 = now = _time.monotonic()
        what = self.source.describe()
        set_origin = getattr(self.protocol, "set_origin", None)
        if set_origin is not None:  # host-stamped lines: none was sent before the port opened
            set_origin(min(self._t_open - self._t0, 0.0))
        self._install_signals()
        self._status(f"waiting for data on {what}")
        last_yield = last_status = now
        last_flush = now
        dirty, idle = False, True
        try:
            while True:
                ended = self._check_end(now, idle)
                if ended is not None:
                    self.end_kind, self.end_reason = ended.kind, ended.reason
                    break
                try:
                    data = self.source.read()
                except DeviceGone as exc:
                    self.end_kind = "device-gone"
                    self.end_reason = f"{what}: the device is gone ({exc})"
                    break
                now = _time.monotonic()
                block = self.protocol.feed(data, now - self._t0) if data else SampleBlock.empty()
                # a backlog still being read (its first parts came) is no idle read
                idle = not len(block) and not getattr(self.source, "reading_backlog", False)
                if len(block):
                    ended = self._received(block, now, what)
                    if ended is not None:
                        self.end_kind, self.end_reason = ended.kind, ended.reason
                        break
                    dirty = True
                elif self._t_first is None and now - last_status >= STATUS_REPEAT_S:
                    last_status = now
                    self._status(
                        f"waiting for data on {what} ({now - self._t0:.0f} s, "
                        f"{self.protocol.stats.get('bytes', 0)} bytes received)"
                    )
                if dirty and now - last_flush >= FLUSH_INTERVAL_S:
                    ended = self._flush()
                    if ended is not None:
                        self.end_kind, self.end_reason = ended.kind, ended.reason
                        break
                    last_flush, dirty = now, False
                if len(block) or now - last_yield >= tick_s:
                    last_yield = now
                    yield block
                    now = _time.monotonic()
        finally:
            self._finish()

    def _received(self, block: SampleBlock, now: float, what: str) -> CaptureEnded | None:
        """Append a block that arrived at ``now``; check the device clock once enough time
        has passed.  Returns why the capture ends, or None."""
        if self._t_first is None:
            self._t_first = now
            self._status(f"receiving data from {what}")
        self._t_last_sample = now
        ended = self._append(block)
        if ended is not None:
            return ended
        if not self._clock_checked and now - self._t_first >= CLOCK_CHECK_S:
            self._clock_checked = True
            problem = self._clock_problem(now)
            if problem is not None:
                return CaptureEnded("clock", problem)
        return None

    def _take_held(self) -> None:
        """What the source read but still holds (a backlog being read when the capture
        ended: Ctrl-C, ``q``, the plan done): into the session like any read, so that nothing
        read from the port is lost."""
        take = getattr(self.source, "take_backlog", None)
        data = take() if take is not None else b""
        if not data or self.end_kind in ("disk-full", "clock"):  # no room; or no session kept
            return
        now = _time.monotonic()
        block = self.protocol.feed(data, now - self._t0)
        if len(block):
            if self._t_first is None:
                self._t_first = now
            self._t_last_sample = now
            ended = self._append(block)
            if ended is not None and ended.kind == "disk-full":
                self.end_kind, self.end_reason = ended.kind, ended.reason

    def _finish(self) -> None:
        """After the recording loop, however it ended: restore the signals, close the source
        and flush what is still pending (a full disk keeps its reason)."""
        self._t_end = _time.monotonic()
        if self.end_kind is None:  # the consumer closed the generator
            self.end_kind, self.end_reason = "done", "done"
        self._take_held()
        self.source.close()  # nothing more is read: let the device see it at once
        if self._writer is not None and self._writer.n_samples > self._writer.n_written:
            ended = self._flush()
            if ended is not None and self.end_kind != "disk-full":
                self.end_kind, self.end_reason = ended.kind, ended.reason
        self._retime_host_stamps()  # host-stamped: on the stream's steady clock

    # segments and closing ----------------------------------------------------------------------
    def add_segment(self, kind: str, start: int, stop: int, **attributes) -> str | None:
        """Mark samples ``[start, stop)`` as a segment; return its name.  ``attributes``
        (``label``, ``up``, ``axis``, ``angle_deg``, ``extra``) and the rules are those of
        :meth:`imucal_cli.formats.session.SessionWriter.add_segment`.

        Segments are added in time order.  While recording they are logged in the file at the
        next flush; :meth:`close` writes them as ``/segments`` groups.  A segment over samples
        that could not be written (a disk filled by another program) is left out: None, and
        :attr:`segments_left_out` counts it.

        Raises
        ------
        SessionError
            No samples yet, or a bad segment.
        """
        if self._writer is None:
            raise SessionError(f"{self.path}: no samples recorded, so no segment can be added")
        if self.samples_lost and stop > self._writer.n_samples:
            self.segments_left_out += 1
            return None
        if self._device_last is not None:
            self._device_at_segment = self._device_last
        try:
            return self._writer.add_segment(kind, start, stop, **attributes)
        except WriteFailed as exc:
            ended = self._write_failed(exc)
            if self.end_kind in (None, "done"):
                self.end_kind, self.end_reason = ended.kind, ended.reason
            self.stop()
            return f"{len(self._writer.segments) - 1:04d}"

    @property
    def segments(self) -> list[dict]:
        """The segments this capture added so far (name, kind, start, stop, and the optional
        attributes; with ``resume`` not those the session held already)."""
        return [] if self._writer is None else self._writer.segments[self._segments_before :]

    @property
    def file_written(self) -> bool:
        """Whether a session file was created (some samples arrived)."""
        return self._writer is not None

    def close(self) -> None:
        """Write everything and close the session and the source.  Closing twice does nothing.

        A write that fails while closing (disk full) does not raise: the file is closed with
        what was written, :attr:`end_kind` becomes ``"disk-full"`` and :attr:`samples_lost`
        counts what was not.
        """
        if self._closed:
            return
        self._closed = True
        try:
            if self._writer is not None:
                try:
                    self._writer.close(attrs=self._rate_attrs())
                except WriteFailed as exc:
                    self._close_failed(exc)
        finally:
            self._restore_signals()
            self.source.close()

    def discard(self) -> None:
        """Close, leaving no trace of this capture: a new session is removed, a continued one
        keeps only what it held before (time stamps in the wrong unit are no session)."""
        if self._writer is not None and not self._closed:
            self._writer.truncate(self.resumed_from)
            self.samples_lost = 0
        self._discarded = True  # a continued session keeps its own rate
        self.close()
        if self._writer is not None and not self.resumed_from:
            try:
                self.path.unlink()
            except OSError:
                pass

    def _clock_problem(self, now: float) -> str | None:
        """Why the device's time stamps cannot be right (None: they can); see
        :func:`~imucal_cli.capture.checks.clock_problem`."""
        columns = getattr(self.protocol, "columns", None)
        if getattr(columns, "time", None) is None or self._device_first is None:
            return None  # host-stamped: nothing to compare
        return clock_problem(self.device_span_s, self.n_samples - self.resumed_from,
                             now - self._t_open, now - self._t_first,
                             columns.time_unit)  # fmt: skip

    def _rate_attrs(self) -> dict:
        """``sample_rate_hz`` from the samples' own time stamps (the device clock where the
        protocol has one), not from when the host received them (issue 10.5)."""
        rate = self.rate_hz
        return {"sample_rate_hz": rate} if rate > 0 and not self._discarded else {}

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
