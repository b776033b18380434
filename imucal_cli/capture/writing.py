"""The recorder's writes to its session (:mod:`.recorder`): a block appended (a continued
session's time stamps shifted after its own; the disk's room checked first, against
:func:`~imucal_cli.capture.checks.headroom`), a flush, and a write that failed (the reserve
freed, the samples that cannot be written given up and counted): each returns why the capture
ends, or None.
"""

from __future__ import annotations

import numpy as np

from imucal_cli.capture.checks import CaptureEnded
from imucal_cli.capture.host_clock import first_read_times, steady_times
from imucal_cli.errors import SessionError, WriteFailed
from imucal_cli.formats.columns import SampleBlock


class SessionWrites:
    """:class:`~.recorder.Recorder`'s part that writes: its ``_writer``, ``samples_lost``,
    the resume offsets and the disk's room are the recorder's."""

    def _append(self, block: SampleBlock) -> CaptureEnded | None:
        """Append a block; returns why the capture ends (the disk full, or nearly) or None.
        The free space is checked before each block: a block that still fits is appended
        and written when the capture ends."""
        if self._writer is None:
            self._open_writer(block)
        nearly_full, short = None, self._room_problem(len(block))
        if short is not None:
            nearly_full, fits = short
            if fits < len(block):  # no room for all of them: the first are kept
                self.samples_lost += len(block) - fits
                nearly_full.reason = nearly_full.reason.replace(
                    "stopped in time, every sample received is written",
                    f"stopped, {self.samples_lost} received samples could not be written "
                    "(no room for them)")  # fmt: skip
                block = block.take(np.arange(len(block)) < fits)
                if not fits:
                    return nearly_full
        time, host = block.time, block.host_time
        others = getattr(block, "others", {})  # several IMUs (issue 28)
        if not self._writer.records_host_time:
            host = None  # a resumed session recorded without host arrival times
        shift = 0.0
        if self.resumed_from:
            gap = max(self._resume_gap_s, 1e-3)
            if self._time_offset is None:
                self._time_offset = self._resume_offset(time, others, gap)
            shift = self._time_offset
            time = time + shift
            if host is not None and self._writer.resumed_host_time is not None:
                if self._host_offset is None:  # the host clock too: after the same gap
                    self._host_offset = self._writer.resumed_host_time + gap - float(host[0])
                host = host + self._host_offset
        try:
            self._writer.append(time, block.accel, block.gyro, block.temperature, block.mag,
                                host_time=host)  # fmt: skip
            for name, other in others.items():
                if len(other):
                    self._writer.append_imu(name, other.time + shift, accel=other.accel,
                                            gyro=other.gyro, mag=other.mag,
                                            temperature=other.temperature)  # fmt: skip
        except WriteFailed as exc:
            return self._write_failed(exc)
        if self._device_first is None:
            self._device_first = float(block.time[0])
            self._device_at_segment = self._device_first
        self._device_last = float(block.time[-1])
        return nearly_full

    def _resume_offset(self, time: np.ndarray, others: dict, gap: float) -> float:
        """What a continued session's new samples are given, s: the device's clock restarts,
        so they follow the old ones after the time the capture was stopped (``gap``, since
        the file's last flush), on the old time axis.  One offset for every IMU of a set
        (their times on the reference's clock keep their places among each other), after
        the latest sample of any IMU and from the earliest new one of any."""
        last = [self._writer.last_time, *self._writer.imu_last_times().values()]
        first = [float(time[0]), *(float(o.time[0]) for o in others.values() if len(o))]
        return max(t for t in last if t is not None) + gap - min(first)

    def _retime_host_stamps(self) -> None:
        """Host-stamped samples, once the capture ended: the first read's times again at the
        rate the rest of the stream showed, then every run between pauses on the device's
        steady clock (:func:`_on_steady_clock`).  Only this capture's samples (a continued
        session's earlier ones keep theirs, and this capture's never move before them), and
        only with every one of them written; a write that fails leaves the stamps as they
        were.  Other IMUs on the same lines move with them; those on ports of their own
        (``other_clocks``) are re-timed on their own clocks."""
        clock = getattr(self.protocol, "host_clock", None)
        writer, base = self._writer, int(self.resumed_from)
        k = 0 if clock is None else clock.first_read
        if (k < 1 or writer is None or self.samples_lost or clock.period is None
                or writer.n_written != writer.n_samples
                or writer.n_written <= base + k):  # fmt: skip
            return
        try:  # the first k are the first read's (in any blocks)
            stamps = writer.written_times()
        except OSError:  # the file cannot be read back (a failing disk): the stamps stay
            return
        origin, shift = clock.origin, (self._time_offset or 0.0) if base else 0.0
        if base:  # on the continued session's axis (:meth:`_append`), after its samples
            origin = max(float(stamps[base - 1]), -np.inf if origin is None else origin + shift)
        stamps = stamps[base:]
        others = getattr(self.protocol, "other_clocks", dict)()
        times = _on_steady_clock(stamps, k, origin, clock.period)
        if not np.array_equal(times, stamps):
            try:
                writer.retime(base, times, others=not others)
            except SessionError:  # the write failed (or the times would not stay in order)
                return
            self._device_first, self._device_last = (float(times[0]) - shift,
                                                     float(times[-1]) - shift)  # fmt: skip
        self._retime_other_ports(others, shift)

    def _retime_other_ports(self, others: dict[str, tuple], resumed: float) -> None:
        """Each other port's samples of this capture on its own steady clock (``others``:
        name to its HostClock, the shift onto the reference's clock, whether its first read
        is kept; ``resumed``: the continued session's offset, s, 0 for a first capture): a
        continued session's earlier samples (each IMU's count at the resume) stay, and the
        new ones never move before them."""
        for name, (clock, shift, first_kept) in others.items():
            if clock.period is None:
                continue
            start = self._imu_starts.get(name, 0)
            try:
                stamps = self._writer.imu_written_times(name)
            except OSError:
                return
            k = clock.first_read if first_kept else 0
            origin = None if clock.origin is None else clock.origin + shift + resumed
            if start:
                origin = max(float(stamps[start - 1]), -np.inf if origin is None else origin)
            new = stamps[start:]
            times = _on_steady_clock(new, k, origin, clock.period)
            if new.size > k and not np.array_equal(times, new):
                try:
                    self._writer.retime_imu(name, times, start)
                except SessionError:
                    continue

    def _flush(self) -> CaptureEnded | None:
        try:
            self._writer.flush()
        except WriteFailed as exc:
            return self._write_failed(exc)
        return None

    def _room_problem(self, arriving: int) -> tuple[CaptureEnded, int] | None:
        """Whether to end the capture now, while the disk still holds the ``arriving``
        samples, those not written yet, and what closing needs (the module notes): why, and
        how many of the ``arriving`` still fit."""
        writer = self._writer
        since = 0.0
        if self._device_last is not None and self._device_at_segment is not None:
            since = self._device_last - self._device_at_segment
        short = self._room.short(writer.room(), written=writer.n_written,
                                 pending=writer.n_samples - writer.n_written, arriving=arriving,
                                 device_rate_hz=self.rate_hz, chunk_rows=writer.chunk_rows,
                                 chunk_bytes=writer.chunk_bytes,
                                 since_segment_s=since)  # fmt: skip
        if short is None:
            return None
        room, fits = short
        writer.release_reserve()
        ended = CaptureEnded(
            "disk-full",
            f"the disk is nearly full ({room // 1024} KiB left where {self.path.name} is): "
            "stopped in time, every sample received is written",
        )
        return ended, fits

    def _write_failed(self, exc: WriteFailed) -> CaptureEnded:
        """Free the reserve and try once more; else give up the samples not written."""
        writer = self._writer
        writer.release_reserve()
        try:
            writer.flush()
        except WriteFailed:
            self.samples_lost += writer.drop_pending()
        lost = (
            f"{self.samples_lost} received samples could not be written"
            if self.samples_lost
            else "every sample received was written"
        )
        return CaptureEnded(
            "disk-full",
            f"cannot write ({exc.reason}): stopped; {lost}, the session holds {writer.n_written}",
        )

    def _close_failed(self, exc: WriteFailed) -> None:
        was_full = self.end_kind == "disk-full"
        self.samples_lost += exc.pending
        self.end_kind = "disk-full"
        more = f", {exc.pending} more samples not written" if exc.pending else ""
        if was_full:
            self.end_reason += f"; closing: cannot write ({exc.reason}){more}"
        else:
            self.end_reason = (
                f"cannot write ({exc.reason}) when closing: {exc.pending} samples could not be "
                f"written, the session holds {self._writer.n_written}"
            )


def _on_steady_clock(stamps: np.ndarray, first_read: int, origin: float | None,
                     period: float) -> np.ndarray:  # fmt: skip
    """Host stamps (n,), s, with the first read's ``first_read`` again at ``period`` (s)
    apart (:func:`~imucal_cli.capture.host_clock.first_read_times`) and every run between
    pauses on its steady line (:func:`~imucal_cli.capture.host_clock.steady_times`), never
    before ``origin``."""
    times = np.asarray(stamps, np.float64).copy()
    if first_read >= 1:
        times[:first_read] = first_read_times(times[:first_read], origin, period)
    return steady_times(times, first_read, origin)
