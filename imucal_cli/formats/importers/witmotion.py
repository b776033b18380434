"""WitMotion's binary protocol (WT901, JY901, HWT905 ...): 11-byte frames ``0x55 TYPE D0..D7
SUM``, ``SUM`` the low byte of the sum of the first ten bytes, ``D`` four little-endian int16.

=====  ================================  =================================================
TYPE   content                           nominal scale (WitMotion's manual)
=====  ================================  =================================================
0x50   time: YY MM DD hh mm ss ms(u16)   (a sample's time when the device sends it)
0x51   acceleration x y z, temperature   16 g / 32768 per count; temperature / 100 = deg C
0x52   angular velocity x y z            2000 deg/s / 32768 per count
0x54   magnetic field x y z              counts (the part's own scale)
=====  ================================  =================================================

The raw int16 counts are kept (never rescaled: the session's units are ``counts``; the nominal
scales above are what a calibration should find).  Frames of other types (angles,
quaternions, pressure ...) are counted and skipped; a frame whose checksum fails is counted as
malformed and the decoder resynchronises on the next ``0x55``.  A sample is one ``0x51`` frame
with the ``0x52`` (and ``0x54``, ``0x50``) frames that follow it before the next ``0x51``.  A
sample whose ``0x52`` frame was lost (a damaged frame, a log cut mid-frame) is left out, its
accelerometer too, and counted with a warning; the gyro is left out only when most samples lack
it (a device set not to send it).  A sample without its ``0x54`` frame has NaN magnetometer
values.
:class:`WitMotionDecoder` is shared by the importer and by ``capture``'s binary protocol
(:class:`imucal_cli.capture.stream.WitMotionProtocol`).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imucal_cli.errors import InputError

from .ros import Channels, one_file, to_recording

__all__ = ["FRAME", "WitMotionDecoder", "WitSample", "looks_like_witmotion", "read_witmotion"]

FRAME = 11
HEAD = 0x55
TIME, ACCEL, GYRO, MAG = 0x50, 0x51, 0x52, 0x54
NOMINAL = {"accel_g_per_count": 16.0 / 32768.0, "gyro_dps_per_count": 2000.0 / 32768.0}


@dataclass
class WitSample:
    """One sample: int16 counts as sent (gyro and mag None when the device sent none)."""

    accel: tuple[int, int, int]
    temperature: float
    gyro: tuple[int, int, int] | None = None
    mag: tuple[int, int, int] | None = None
    device_time: float | None = None  # s since midnight, from a 0x50 frame


@dataclass
class WitMotionDecoder:
    """Frames out of a byte stream, fed in pieces of any size.

    Attributes
    ----------
    stats : dict
        ``frames`` (good frames), ``samples`` (completed), ``skipped`` (frames of other types),
        ``malformed`` (checksum failures and bytes skipped to resynchronise), ``bytes``.
    """

    stats: dict = field(default_factory=lambda: {"frames": 0, "samples": 0, "skipped": 0,
                                                  "malformed": 0, "bytes": 0})  # fmt: skip
    _buffer: bytearray = field(default_factory=bytearray)
    _current: WitSample | None = None
    _time: float | None = None

    def feed(self, data: bytes) -> list[WitSample]:
        """Decode the complete frames of ``data`` (after what was left over); return the
        samples completed by them (a sample completes when the next ``0x51`` arrives)."""
        self.stats["bytes"] += len(data)
        buf = self._buffer
        buf += data
        out: list[WitSample] = []
        i = 0
        while len(buf) - i >= FRAME:
            if buf[i] != HEAD:
                nxt = buf.find(HEAD, i + 1)
                skipped = (nxt if nxt >= 0 else len(buf)) - i
                self.stats["malformed"] += 1
                i += skipped
                continue
            frame = bytes(buf[i : i + FRAME])
            if sum(frame[:10]) & 0xFF != frame[10]:
                self.stats["malformed"] += 1
                i += 1  # resynchronise on the next 0x55
                continue
            i += FRAME
            self.stats["frames"] += 1
            self._frame(frame[1], frame[2:10], out)
        del buf[:i]
        return out

    def flush(self) -> list[WitSample]:
        """The sample in progress at the end of the stream."""
        done = [self._current] if self._current is not None else []
        self._current = None
        self.stats["samples"] += len(done)
        return done

    def _frame(self, kind: int, payload: bytes, out: list[WitSample]) -> None:
        values = struct.unpack("<hhhh", payload)
        if kind == ACCEL:
            if self._current is not None:
                out.append(self._current)
                self.stats["samples"] += 1
            self._current = WitSample(values[:3], values[3] / 100.0, device_time=self._time)
        elif kind == GYRO and self._current is not None:
            self._current.gyro = values[:3]
        elif kind == MAG and self._current is not None:
            self._current.mag = values[:3]
        elif kind == TIME:
            _, _, _, hh, mm, ss = payload[:6]
            ms = payload[6] | payload[7] << 8
            self._time = hh * 3600 + mm * 60 + ss + ms / 1000.0
        else:
            self.stats["skipped"] += 1


def looks_like_witmotion(head: bytes) -> bool:
    """True when ``head`` (the first bytes of a file) holds at least 3 valid frames."""
    good, i = 0, head.find(bytes([HEAD]))
    while 0 <= i <= len(head) - FRAME:
        frame = head[i : i + FRAME]
        if sum(frame[:10]) & 0xFF == frame[10] and 0x50 <= frame[1] <= 0x5F:
            good += 1
            i += FRAME
        else:
            i = head.find(bytes([HEAD]), i + 1)
    return good >= 3


@dataclass
class WitRecording:
    """Decoded samples of a file: counts, with a time base."""

    time: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray | None
    temperature: np.ndarray
    mag: np.ndarray | None
    notes: list[str]
    stats: dict
    warnings: list[str] = field(default_factory=list)


def read_witmotion(path: str | os.PathLike, rate_hz: float | None = None) -> WitRecording:
    """Decode a file of WitMotion frames (a serial dump).

    Time: the device's ``0x50`` time frames when every sample has one and they increase,
    else ``i / rate_hz``.

    Raises
    ------
    InputError
        Unreadable file, no sample, or neither device time nor ``rate_hz``.
    """
    src = str(path)
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise InputError(f"{src}: cannot read ({exc.strerror or exc})") from None
    dec = WitMotionDecoder()
    samples = dec.feed(data) + dec.flush()
    if not samples:
        raise InputError(f"{src}: no WitMotion acceleration frame (0x55 0x51) found")
    notes = [f"WitMotion frames: {dec.stats['frames']} good, {dec.stats['malformed']} "
             f"malformed, {dec.stats['skipped']} of other types"]  # fmt: skip
    warnings: list[str] = []
    times = [s.device_time for s in samples]
    dev = None
    if all(t is not None for t in times):
        dev = np.array(times, np.float64)
        if not np.all(np.diff(dev) > 0):
            dev = None
    if dev is not None and rate_hz is None:
        time = dev - dev[0]
        notes.append("time from the device's 0x50 time frames")
    elif rate_hz is not None:
        time = np.arange(len(samples)) / float(rate_hz)
        notes.append(f"time = sample / {rate_hz:g} Hz")
    else:
        raise InputError(f"{src}: the frames carry no increasing device time: pass --rate "
                         "(the output rate set on the device)")  # fmt: skip
    accel = np.array([s.accel for s in samples], np.float64)
    temperature = np.array([s.temperature for s in samples])
    has_gyro = np.array([s.gyro is not None for s in samples])
    gyro = mag = None
    if has_gyro.sum() >= 0.5 * len(samples):  # a frame lost here and there: those samples go
        gyro = np.array([s.gyro or (0, 0, 0) for s in samples], np.float64)
        missing = int((~has_gyro).sum())
        if missing:  # their times stay those of their frames: the gap shows, nothing shifts
            time, accel, gyro = time[has_gyro], accel[has_gyro], gyro[has_gyro]
            temperature = temperature[has_gyro]
            samples = [s for s, ok in zip(samples, has_gyro, strict=True) if ok]
            warnings.append(f"{missing} of {len(has_gyro)} samples had no angular-velocity frame "
                            "(0x52; a frame lost or the log cut): left out, accelerometer too")
            dec.stats["malformed"] += missing
    elif has_gyro.any():
        warnings.append(f"only {int(has_gyro.sum())} of {len(has_gyro)} samples have an "
                        "angular-velocity frame (0x52): the gyro is left out")  # fmt: skip
    has_mag = np.array([s.mag is not None for s in samples])
    if has_mag.sum() >= 0.5 * len(samples):  # missing readings are NaN (left out by calibrate)
        mag = np.array([s.mag if s.mag is not None else (np.nan,) * 3 for s in samples],
                       np.float64)  # fmt: skip
        if not has_mag.all():
            notes.append(f"{int((~has_mag).sum())} samples had no magnetic-field frame (0x54): "
                         "their magnetometer values are NaN")  # fmt: skip
    elif has_mag.any():
        notes.append("few samples have a magnetic-field frame (0x54): the magnetometer is left "
                     "out")  # fmt: skip
    return WitRecording(time, accel, gyro, temperature, mag, notes, dec.stats, warnings)


NAME = "witmotion"
FILES = "one file of WitMotion 0x55 frames (a serial dump)"


def read(paths, options, stats):
    """``imucal import --format witmotion``: :func:`read_witmotion`; ``--rate`` when the
    frames carry no time."""
    path = one_file(paths, options, NAME, FILES)
    rec = read_witmotion(path, options.rate_hz)
    stats.lines, stats.malformed = rec.stats["frames"], rec.stats["malformed"]
    stats.comments = rec.stats["skipped"]
    ch = Channels(rec.time, rec.accel, rec.gyro, "counts", "counts", temperature=rec.temperature,
                  mag=rec.mag, mag_units=None if rec.mag is None else "counts",
                  notes=rec.notes, warnings=rec.warnings)  # fmt: skip
    return to_recording(ch, paths, stats)
