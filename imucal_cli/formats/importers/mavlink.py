"""MAVLink telemetry logs (``.tlog``) and ArduPilot DataFlash logs (``.bin``), read with
``pymavlink`` (``pip install 'imucal-cli[mavlink]'``).

What is read, in the units each message states (never rescaled but for the factor that turns
a unit the session format does not name into one it does):

=================  =======================================  =====================================
log: message       accel, gyro, mag                         time; temperature
=================  =======================================  =====================================
tlog: RAW_IMU      counts, counts, counts                   ``time_usec``; ``temperature`` cdegC
tlog: SCALED_IMU,  mG, mrad/s, mgauss: stored as g, rad/s,  ``time_boot_ms``; ``temperature``
SCALED_IMU2, 3     gauss (/ 1000)                           cdegC
tlog: HIGHRES_IMU  m/s^2, rad/s, gauss                      ``time_usec``; ``temperature`` degC
DataFlash: IMU     ``AccX..`` m/s^2, ``GyrX..`` rad/s        ``TimeUS``; ``T`` (``Temp``) degC
DataFlash: ACC +   ``AccX..`` m/s^2, ``GyrX..`` rad/s,       ``SampleUS``; the IMU's ``T``
GYR                paired by ``SampleUS``
DataFlash: MAG     ``MagX..`` mGauss, stored as gauss        ``TimeUS``, latest per sample
DataFlash: ISBH +  the batch sampler's raw samples: int16     ``SampleUS`` of the batch + k /
ISBD               ``x y z[32]`` / ``mul`` (m/s^2, rad/s),    ``smp_rate``
                   ``type`` 0 accel, 1 gyro
=================  =======================================  =====================================

The batch sampler (``INS_LOG_BAT_MASK``, ArduPilot's ``AP_InertialSensor_Logging``: ISBH
``TimeUS,N,type,instance,mul,smp_cnt,SampleUS,smp_rate``, ISBD ``TimeUS,N,seqno,x,y,z``)
logs a batch of ``smp_cnt`` samples of one sensor at a time, 32 per ISBD, sample ``32 seqno +
k`` at ``SampleUS + (32 seqno + k) / smp_rate``; the values are the sensor's raw samples
(before ArduPilot's filters, and before its calibration unless ``INS_LOG_BAT_OPT`` says
post-filter) times ``mul``.  Accelerometer and gyroscope batches are paired by time where they
overlap; where they do not (the sampler takes one sensor at a time) the accelerometer is read
alone and the note says so (``--topic ISB.N``).

A DataFlash log converted to text (``.log``: ``FMT, 128, 89, FMT, BBnNZ, ...`` then one
message per line, as Mission Planner writes it) is read with pymavlink's text reader, the same
messages; arrays (ISBD) are not in text logs.

A temperature of 0 in RAW_IMU/SCALED_IMU means "not sent" (MAVLink's definition) and is NaN;
a magnetometer reading of exactly (0, 0, 0) is no reading (NaN).  Telemetry logs: time from the
message's own time field when it is set and strictly increasing, else from the log's receive
stamps; beside the message's own time the receive stamps (when the ground station, the host,
received each packet) are the session's ``/raw/host_time``, the reference of the sample clock
(issue 17.2).  Several streams (message, instance ``id``/``I``, sending system when there are
several) are listed and one is chosen with ``topic`` (``--topic RAW_IMU``, ``IMU.1``), as for
ROS topics.  ArduPilot logs IMU/ACC/GYR/MAG after applying its own calibration (INS_ACCOFFS,
INS_ACCSCAL, INS_GYROFFS, COMPASS_OFS ..., the board rotation), and fills RAW_IMU with its
calibrated values in mG and mrad/s: the notes say so.

pymavlink's DataFlash reader loops forever on a format of length 0 with no fields (a damaged
or hostile file); :class:`_Guarded` stops it at the first message that does not move on.
"""

from __future__ import annotations

import os
import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.inputs import read_head

from .library import one_line_reason, quiet
from .recording import STAMPS_KEPT, SeveralStreams, choose_time, increasing
from .ros import Channels, hold_latest, one_file, to_recording
from .text_scan import cut_line_number, cut_line_start, cut_line_warning
from .ulog import pair_by_time

__all__ = ["choose_stream", "looks_like_dataflash", "looks_like_tlog", "read_mavlink"]

NAME = "mavlink"
FILES = "one MAVLink telemetry log (.tlog) or ArduPilot DataFlash log (.bin, or text .log)"
DATAFLASH_HEAD = b"\xa3\x95\x80"  # the first message of a DataFlash log: FMT (type 128)


@dataclass(frozen=True)
class _Message:
    """How a telemetry message carries a sample: its time field and its units."""

    time_field: str
    time_scale: float  # s per unit
    units: tuple[str, str, str]  # accel, gyro, mag as stored
    scale: float  # stored = sent * scale
    temp_scale: float  # deg C per unit
    zero_temp_missing: bool
    sent: str  # the units as sent, for the notes


_CENTI = dict(temp_scale=0.01, zero_temp_missing=True)
TLOG_MESSAGES = {
    "RAW_IMU": _Message("time_usec", 1e-6, ("counts", "counts", "counts"), 1.0, **_CENTI,
                        sent="raw counts"),
    "SCALED_IMU": _Message("time_boot_ms", 1e-3, ("g", "rad/s", "gauss"), 1e-3, **_CENTI,
                           sent="mG, mrad/s, mgauss"),
    "HIGHRES_IMU": _Message("time_usec", 1e-6, ("m/s^2", "rad/s", "gauss"), 1.0, 1.0, False,
                            sent="m/s^2, rad/s, gauss"),
}  # fmt: skip
TLOG_MESSAGES["SCALED_IMU2"] = TLOG_MESSAGES["SCALED_IMU3"] = TLOG_MESSAGES["SCALED_IMU"]
_WITH_ID = ("RAW_IMU", "HIGHRES_IMU")  # messages with an instance field `id`
_DF_NAME = re.compile(r"(IMU|ACC|GYR|MAG|ISBH|ISBD)([1-3]?)")
DATAFLASH_TEXT_HEAD = (b"FMT, ", b"FMT,")


# --------------------------------------------------------------------------------------------
# Recognising the files
# --------------------------------------------------------------------------------------------


def looks_like_dataflash(head: bytes) -> bool:
    """True when ``head`` starts as a DataFlash log does: an FMT message (0xA3 0x95 0x80)."""
    return head.startswith(DATAFLASH_HEAD)


def looks_like_dataflash_text(head: bytes) -> bool:
    """True when ``head`` starts as a DataFlash log converted to text does: an FMT line."""
    return head.lstrip(b"\xef\xbb\xbf \r\n").startswith(DATAFLASH_TEXT_HEAD)


def looks_like_tlog(head: bytes, need: int = 3) -> bool:
    """True when ``head`` starts with ``need`` telemetry-log records: an 8-byte big-endian
    time (microseconds since 1970, 2001-2100) then a MAVLink 1 (0xFE) or 2 (0xFD) packet."""
    pos = found = 0
    while found < need and pos + 12 <= len(head):
        (stamp_us,) = struct.unpack(">Q", head[pos : pos + 8])
        magic, length = head[pos + 8], head[pos + 9]
        if not 1e15 <= stamp_us <= 4.1e15 or magic not in (0xFD, 0xFE):
            return False
        signed = magic == 0xFD and head[pos + 10] & 0x01
        pos += 8 + length + (12 + 13 * signed if magic == 0xFD else 8)
        found += 1
    return found >= need or (found > 0 and pos == len(head))


# --------------------------------------------------------------------------------------------
# Choosing a stream
# --------------------------------------------------------------------------------------------


def choose_stream(labels: list[str], wanted: str | None, src: str, what: str) -> str:
    """The stream to read: ``wanted`` (its label, or the message name alone when one stream
    has it), or the only stream.

    Raises
    ------
    InputError
        No stream, several and none chosen, or ``wanted`` names none or several; the message
        lists the streams.
    """
    listed = ", ".join(labels)
    if not labels:
        raise InputError(f"{src}: no {what} messages in the log")
    if wanted is None:
        if len(labels) == 1:
            return labels[0]
        raise SeveralStreams(f"{src}: several IMU streams: {listed}; choose one with --topic",
                             labels)
    matches = [
        label for label in labels
        if wanted in (label, label.partition("@")[0], label.partition("@")[0].partition(".")[0])
    ]  # fmt: skip
    if len(matches) == 1:
        return matches[0]
    if wanted in labels:
        return wanted
    said = "matches several streams" if matches else "is not in the log"
    raise InputError(f"{src}: --topic {wanted} {said}; IMU streams: {listed}")


def _zero_is_none(values: np.ndarray) -> np.ndarray | None:
    """Rows of exactly 0 become NaN (not sent); None when no row holds a value."""
    values = np.asarray(values, np.float64)
    none = np.all(values == 0, axis=-1) if values.ndim > 1 else values == 0
    if none.all():
        return None
    return np.where(none[..., None] if values.ndim > 1 else none, np.nan, values)


# --------------------------------------------------------------------------------------------
# pymavlink
# --------------------------------------------------------------------------------------------


def _pymavlink():
    """``(mavutil, DFReader)``, or the one-line error naming the extra."""
    try:
        from pymavlink import DFReader, mavutil
    except ImportError:
        raise InputError("reading a MAVLink log needs pymavlink: pip install "
                         "'imucal-cli[mavlink]'") from None  # fmt: skip
    return mavutil, DFReader


class _Stuck(Exception):
    """pymavlink's DataFlash reader did not move on (a format of length 0)."""


def _guarded(DFReader):  # noqa: N803 - the module's own name
    """pymavlink's ``DFReader_binary`` that raises :class:`_Stuck` instead of reading the same
    message for ever."""

    class _Guarded(DFReader.DFReader_binary):
        def _parse_next(self):
            before = self.offset
            message = super()._parse_next()
            if message is not None and self.offset <= before:
                raise _Stuck(f"a message format of length 0 at byte {before}")
            return message

    return _Guarded


# --------------------------------------------------------------------------------------------
# Telemetry logs
# --------------------------------------------------------------------------------------------


def _tlog_rows(path: Path, mavutil) -> tuple[dict[tuple, list], int]:
    """Rows ``(receive s, device time, ax..az, gx..gz, mx..mz, temp)`` per stream key
    ``(message, id, system, component)``, and the count of bad data."""
    log = mavutil.mavlogfile(str(path), robust_parsing=True)
    rows: dict[tuple, list] = {}
    bad = 0
    try:
        while (m := log.recv_msg()) is not None:
            name = m.get_type()
            if name == "BAD_DATA":
                bad += 1
                continue
            spec = TLOG_MESSAGES.get(name)
            if spec is None:
                continue
            key = (name, int(getattr(m, "id", 0) or 0) if name in _WITH_ID else None,
                   m.get_srcSystem(), m.get_srcComponent())  # fmt: skip
            rows.setdefault(key, []).append((
                m._timestamp, getattr(m, spec.time_field), m.xacc, m.yacc, m.zacc, m.xgyro,
                m.ygyro, m.zgyro, m.xmag, m.ymag, m.zmag, getattr(m, "temperature", 0),
            ))  # fmt: skip
    finally:
        log.close()
    return rows, bad


def _tlog_labels(keys: list[tuple]) -> dict[str, tuple]:
    """Stream labels: ``RAW_IMU.0``, ``SCALED_IMU2``; ``@system/component`` when the log holds
    IMU messages of several senders."""
    several = len({k[2:] for k in keys}) > 1
    out = {}
    for name, ident, system, component in sorted(keys, key=lambda k: (k[0], k[1] or 0, k[2:])):
        label = name if ident is None else f"{name}.{ident}"
        out[label + (f"@{system}/{component}" if several else "")] = (name, ident, system,
                                                                      component)  # fmt: skip
    return out


def _tlog_channels(label: str, name: str, rows: list) -> Channels:
    """Channels of one telemetry stream (see the module's table)."""
    spec = TLOG_MESSAGES[name]
    data = np.asarray(rows, np.float64)
    received, device = data[:, 0], data[:, 1] * spec.time_scale
    values = data[:, 2:11] * spec.scale
    finite = np.isfinite(values[:, :6]).all(axis=1)
    time, use_device, out_of_order = choose_time(device, received, finite)
    keep = increasing(time, finite)
    a_units, g_units, m_units = spec.units
    notes = [
        f"{label}: {spec.sent}" + (f", stored as {a_units}, {g_units}, {m_units}"
                                    if spec.scale != 1 else ""),
        (f"time from {spec.time_field}" + (f" ({out_of_order} messages whose {spec.time_field} "
                                           "did not follow the previous one left out)"
                                           if out_of_order else "")) if use_device else
        f"time from the log's receive stamps ({spec.time_field} unset, or not increasing for "
        f"{100 * STAMPS_KEPT:g} % of the messages)",
    ]  # fmt: skip
    ch = Channels(time=time[keep], accel=values[keep, 0:3], gyro=values[keep, 3:6],
                  accel_units=a_units, gyro_units=g_units, notes=notes,
                  dropped=int((~keep).sum()))  # fmt: skip
    if use_device:  # when the ground station received each sample: the host's clock
        ch.host_time = received[keep]
        notes.append("the log's receive stamps kept as /raw/host_time (the host's clock)")
    mag = _zero_is_none(values[keep, 6:9])
    if mag is not None:
        ch.mag, ch.mag_units = mag, m_units
    temp = data[keep, 11] * spec.temp_scale
    temp = _zero_is_none(temp) if spec.zero_temp_missing else temp
    if temp is not None and np.any(temp != 0):
        ch.temperature = temp
    if name == "RAW_IMU":
        notes.append("ArduPilot fills RAW_IMU with its calibrated values (mG, mrad/s, mgauss), "
                     "PX4 with the sensor's counts")  # fmt: skip
    return ch


def read_tlog(path: str | os.PathLike, topic: str | None = None) -> Channels:
    """Accelerometer, gyroscope, magnetometer and temperature of a MAVLink telemetry log.

    Raises
    ------
    InputError
        pymavlink not installed (names the extra), an unreadable log, no IMU message, or
        several streams and none chosen (listed).
    """
    mavutil, _ = _pymavlink()
    src = str(path)
    try:
        with quiet():
            rows, bad = _tlog_rows(Path(path), mavutil)
    except Exception as exc:  # noqa: BLE001 - pymavlink raises plain exceptions
        raise InputError(f"{src}: not a readable MAVLink telemetry log "
                         f"({' '.join(str(exc).split())[:200]})") from None  # fmt: skip
    labels = _tlog_labels(list(rows))
    label = choose_stream(list(labels), topic, src, "RAW_IMU, SCALED_IMU or HIGHRES_IMU")
    key = labels[label]
    ch = _tlog_channels(label, key[0], rows[key])
    if bad:
        ch.notes.append(f"{bad} stretches of bytes that were no MAVLink packet skipped")
    return ch


# --------------------------------------------------------------------------------------------
# DataFlash logs
# --------------------------------------------------------------------------------------------


def _df_instance(message, name: str, digit: str) -> int:
    """The sensor instance: the ``I`` field, else the name's digit (IMU2 -> 1, ACC1 -> 0)."""
    if "I" in message.fmt.colhash:
        return int(message.I)
    return int(digit) - 1 if digit else 0


def _df_time_us(message, *fields: str) -> float:
    for field in fields:
        if field in message.fmt.colhash:
            return float(getattr(message, field)) * (1000.0 if field == "TimeMS" else 1.0)
    return float("nan")


def _df_temperature(message) -> float:
    for field in ("T", "Temp"):
        if field in message.fmt.colhash:
            return float(getattr(message, field))
    return float("nan")


def _df_rows(path: Path, DFReader, text: bool = False  # noqa: N803
             ) -> tuple[dict[tuple[str, int], list], str | None]:  # fmt: skip
    """Rows per ``(kind, instance)``: IMU ``(us, ax..az, gx..gz, temp)``, ACC/GYR ``(sample
    us, x, y, z)``, MAG ``(us, x, y, z)``; the batch sampler's under ``("ISBH", N)`` (its
    header) and ``("ISBD", N)`` (its data messages), N the batch number.  A text log's last
    line cut short (:func:`~.text_scan.cut_line_start`) is not read: its ``file:line`` is
    returned with the rows (None: none cut)."""
    log = DFReader.DFReader_text(str(path)) if text else _guarded(DFReader)(str(path))
    cut = cut_line_start(log.data_map) if text else None
    where = None if cut is None else f"{path}:{cut_line_number(log.data_map, cut)}"
    if cut is not None:  # pymavlink's text reader reads no line past data_len
        log.data_len = cut
    names = [n for n in log.name_to_id if _DF_NAME.fullmatch(n)]
    rows: dict[tuple[str, int], list] = {}
    try:
        while names and (m := log.recv_match(type=names)) is not None:
            kind, digit = _DF_NAME.fullmatch(m.get_type()).groups()
            if kind == "ISBH":
                rows.setdefault(("ISBH", int(m.N)), []).append(
                    (int(m.type), int(m.instance), float(m.mul), int(m.smp_cnt),
                     float(m.SampleUS), float(m.smp_rate), float(m.TimeUS)))  # fmt: skip
                continue
            if kind == "ISBD":
                rows.setdefault(("ISBD", int(m.N)), []).append(
                    (int(m.seqno), list(m.x), list(m.y), list(m.z)))  # fmt: skip
                continue
            key = (kind, _df_instance(m, kind, digit))
            if kind == "IMU":
                row = (_df_time_us(m, "TimeUS", "TimeMS"), m.AccX, m.AccY, m.AccZ, m.GyrX,
                       m.GyrY, m.GyrZ, _df_temperature(m))  # fmt: skip
            elif kind == "MAG":
                row = (_df_time_us(m, "TimeUS", "TimeMS"), m.MagX, m.MagY, m.MagZ)
            else:
                axis = "Acc" if kind == "ACC" else "Gyr"
                row = (_df_time_us(m, "SampleUS", "TimeUS"), getattr(m, axis + "X"),
                       getattr(m, axis + "Y"), getattr(m, axis + "Z"))  # fmt: skip
            rows.setdefault(key, []).append(row)
    finally:
        log.close()
    return rows, where


def _df_series(rows: list, n_values: int = 3) -> tuple[np.ndarray, np.ndarray, int]:
    """Time (s) and values of one DataFlash series, strictly increasing, the first
    ``n_values`` values finite (the temperature may be NaN); dropped rows."""
    data = np.asarray(rows, np.float64)
    keep = increasing(data[:, 0] * 1e-6, np.isfinite(data[:, : 1 + n_values]).all(axis=1))
    return data[keep, 0] * 1e-6, data[keep, 1:], int((~keep).sum())


def _df_imu(rows: dict, instance: int) -> Channels:
    time, values, dropped = _df_series(rows[("IMU", instance)], 6)
    ch = Channels(time=time, accel=values[:, 0:3], gyro=values[:, 3:6], accel_units="m/s^2",
                  gyro_units="rad/s", dropped=dropped,
                  notes=[f"DataFlash IMU instance {instance} (m/s^2, rad/s), time from TimeUS"])
    if np.isfinite(values[:, 6]).any():
        ch.temperature = values[:, 6]
    return ch


def _df_acc_gyr(rows: dict, instance: int) -> Channels:
    t_a, acc, drop_a = _df_series(rows[("ACC", instance)])
    t_g, gyr, drop_g = _df_series(rows[("GYR", instance)])
    if min(len(t_a), len(t_g)) < 2:
        raise InputError(f"ACC and GYR instance {instance}: too few samples ({len(t_a)}, "
                         f"{len(t_g)})")  # fmt: skip
    ia, ig = pair_by_time(t_a, t_g)
    if len(ia) == 0:
        raise InputError(f"ACC and GYR instance {instance} share no SampleUS")
    time = t_a[ia] if np.median(np.diff(t_a)) >= np.median(np.diff(t_g)) else t_g[ig]
    ch = Channels(time=time, accel=acc[ia], gyro=gyr[ig], accel_units="m/s^2",
                  gyro_units="rad/s", dropped=drop_a + drop_g,
                  unpaired=len(t_a) + len(t_g) - 2 * len(ia),
                  notes=[f"DataFlash ACC and GYR instance {instance} (m/s^2, rad/s) paired by "
                         f"SampleUS: {len(ia)} of {len(t_a)} and {len(t_g)} samples"])  # fmt: skip
    if ("IMU", instance) in rows:
        t_i, imu, _ = _df_series(rows[("IMU", instance)], 6)
        if np.isfinite(imu[:, 6]).any():
            ch.temperature = hold_latest(t_i, imu[:, 6], time)
            ch.notes.append(f"temperature: IMU instance {instance}'s T, latest per sample")
    return ch


#: The batch sampler's sensor types (AP_InertialSensor: IMU_SENSOR_TYPE_ACCEL, ..._GYRO).
_ISB_TYPES = {0: "accel", 1: "gyro"}


def _plausible_batch(count: int, sample_us: float, rate: float, logged_us: float) -> bool:
    """A batch header whose numbers can be: a sample rate an IMU has, and a batch sampled
    before its header was logged (ArduPilot logs the header when the batch is complete) and
    less than ten minutes before; a damaged header (no checksum) mostly fails this."""
    if not (10.0 <= rate <= 1e5 and 0 < count <= 1 << 16):
        return False
    end_us = sample_us + (count - 1) / rate * 1e6
    return end_us <= logged_us + 1.0 and logged_us - sample_us <= 600e6


def _isb_series(rows: dict) -> dict[tuple[str, int], tuple[np.ndarray, np.ndarray]]:
    """The batch sampler's samples per ``(sensor, instance)``: times (s) and values (SI), from
    every batch whose header is in the log and plausible (:func:`_plausible_batch`); a batch's
    samples past its ``smp_cnt`` or not finite, and data messages of a lost header, are left
    out."""
    parts: dict[tuple[str, int], list] = {}
    for (kind, number), heads in rows.items():
        if kind != "ISBH" or ("ISBD", number) not in rows:
            continue
        sensor_type, instance, mul, count, sample_us, rate, logged_us = heads[0]
        if sensor_type not in _ISB_TYPES or not mul > 0 or \
                not _plausible_batch(count, sample_us, rate, logged_us):  # fmt: skip
            continue
        t_list, v_list = [], []
        for seqno, x, y, z in rows[("ISBD", number)]:
            k = 32 * seqno + np.arange(len(x))
            ok = k < count
            t_list.append((sample_us * 1e-6 + k / rate)[ok])
            v_list.append(np.column_stack([x, y, z]).astype(np.float64)[ok] / mul)
        if t_list:
            parts.setdefault((_ISB_TYPES[sensor_type], instance), []).append(
                (np.concatenate(t_list), np.concatenate(v_list)))  # fmt: skip
    out = {}
    for key, pieces in parts.items():
        t = np.concatenate([p[0] for p in pieces])
        v = np.concatenate([p[1] for p in pieces])
        order = np.argsort(t, kind="stable")
        t, v = t[order], v[order]
        keep = increasing(t, np.isfinite(v).all(axis=1))
        out[key] = (t[keep], v[keep])
    return out


def _df_isb(series: dict, instance: int) -> Channels:
    """The batch sampler's samples of one IMU: paired accelerometer and gyroscope where their
    batches overlap in time, else the accelerometer alone."""
    t_a, acc = series[("accel", instance)]
    if len(t_a) < 2:
        raise InputError(f"ISB.{instance}: too few batch samples ({len(t_a)})")
    notes = [f"DataFlash ISBH/ISBD batch samples of IMU {instance} (int16 / mul: m/s^2, rad/s)"]
    gyro = series.get(("gyro", instance))
    if gyro is not None and len(gyro[0]) >= 2:
        ia, ig = pair_by_time(t_a, gyro[0])
        if len(ia) >= 0.5 * len(t_a):
            time = t_a[ia]
            return Channels(time=time, accel=acc[ia], gyro=gyro[1][ig], accel_units="m/s^2",
                            gyro_units="rad/s", unpaired=len(t_a) + len(gyro[0]) - 2 * len(ia),
                            notes=notes + [f"{len(ia)} accel and gyro batch samples paired by "
                                           "time"])  # fmt: skip
    notes.append("the batches of the accelerometer and the gyroscope do not overlap in time (the "
                 "sampler logs one sensor at a time): the accelerometer alone is read")
    return Channels(time=t_a, accel=acc, gyro=None, accel_units="m/s^2", gyro_units="rad/s",
                    notes=notes)  # fmt: skip


def read_dataflash(path: str | os.PathLike, topic: str | None = None,
                   mag_topic: str | None = None, text: bool = False) -> Channels:  # fmt: skip
    """Accelerometer, gyroscope, magnetometer and temperature of an ArduPilot DataFlash log.

    Raises
    ------
    InputError
        pymavlink not installed (names the extra), an unreadable log, no IMU or ACC/GYR
        messages, or several streams and none chosen (listed).
    """
    _, DFReader = _pymavlink()  # noqa: N806
    src = str(path)
    what = "DataFlash text log" if text else "DataFlash log"
    try:
        with quiet():
            rows, cut = _df_rows(Path(path), DFReader, text)
            isb = _isb_series(rows)
    except MemoryError:
        raise InputError(f"{src}: damaged {what} (a message asks for more memory than there "
                         "is)") from None  # fmt: skip
    except Exception as exc:  # noqa: BLE001 - pymavlink raises plain exceptions
        why = str(exc) if isinstance(exc, _Stuck) else one_line_reason(exc, 200)
        raise InputError(f"{src}: not a readable {what} ({why})") from None
    imu = sorted(i for kind, i in rows if kind == "IMU")
    acc = sorted(i for kind, i in rows if kind == "ACC" and ("GYR", i) in rows)
    batches = sorted(i for sensor, i in isb if sensor == "accel")
    labels = [f"IMU.{i}" for i in imu] + [f"ACC.{i}" for i in acc] + [f"ISB.{i}" for i in batches]
    label = choose_stream(labels, topic, src, "IMU, ACC/GYR or ISBH/ISBD")
    kind, instance = label.split(".")[0], int(label.split(".")[1])
    try:
        ch = _df_imu(rows, instance) if kind == "IMU" else _df_acc_gyr(rows, instance) \
            if kind == "ACC" else _df_isb(isb, instance)  # fmt: skip
    except InputError as exc:
        raise InputError(f"{src}: {exc}") from None
    ch.warnings += [] if cut is None else [cut_line_warning(cut)]
    if kind != "ISB":
        ch.notes.append("ArduPilot logs IMU, ACC and GYR after its own offsets and scales "
                        "(INS_ACCOFFS, INS_ACCSCAL, INS_GYROFFS) and board rotation")  # fmt: skip
    mags = sorted(i for k, i in rows if k == "MAG")
    if mag_topic is not None:
        number = mag_topic.rpartition(".")[2]
        if not number.isdigit() or int(number) not in mags:
            raise InputError(f"{src}: --mag-topic {mag_topic}: MAG instances in the log: "
                             f"{', '.join(f'MAG.{i}' for i in mags) or 'none'}")  # fmt: skip
        mags = [int(number)]
    if mags:
        m = instance if instance in mags else mags[0]
        t_m, values, _ = _df_series(rows[("MAG", m)])
        mag = _zero_is_none(values)
        if mag is not None and len(t_m):
            ch.mag, ch.mag_units = hold_latest(t_m, mag * 1e-3, ch.time), "gauss"
            ch.notes.append(f"MAG instance {m} (mGauss, stored as gauss; after ArduPilot's "
                            "COMPASS_OFS, DIA, ODI), latest per sample")  # fmt: skip
    return ch


# --------------------------------------------------------------------------------------------
# The importer interface (``imucal import --format mavlink``)
# --------------------------------------------------------------------------------------------


def read_mavlink(path: str | os.PathLike, topic: str | None = None,
                 mag_topic: str | None = None) -> Channels:  # fmt: skip
    """A DataFlash log (by its first bytes) with :func:`read_dataflash`, anything else with
    :func:`read_tlog`.

    Raises
    ------
    InputError
        Not a regular file, empty, or what the reader refuses.
    """
    head = read_head(path, 64, what="MAVLink log")
    if not head:
        raise InputError(f"{path}: empty file, not a MAVLink log")
    if looks_like_dataflash(head):
        return read_dataflash(path, topic, mag_topic)
    if looks_like_dataflash_text(head):
        return read_dataflash(path, topic, mag_topic, text=True)
    if mag_topic is not None:
        raise InputError(f"{path}: --mag-topic applies to DataFlash logs (MAG.N); a telemetry "
                         "log's magnetometer is that of the IMU message")  # fmt: skip
    return read_tlog(path, topic)


def read(paths, options, stats):
    """``imucal import --format mavlink``: :func:`read_mavlink` of the one path, ``--topic``."""
    path = one_file(paths, options, NAME, FILES)
    return to_recording(read_mavlink(path, options.topic, options.mag_topic), paths, stats)
