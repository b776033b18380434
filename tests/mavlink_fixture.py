"""MAVLink logs written with pymavlink itself, for the importer's tests.

- A telemetry log (``.tlog``) is what a ground station records: per packet an 8-byte
  big-endian receive time (microseconds since 1970), then the packet as sent; the packets are
  packed by pymavlink's generated MAVLink 2 (or 1) ``common`` dialect (``*_encode`` then
  ``pack``).
- A DataFlash log (``.bin``) is a stream of messages ``0xA3 0x95 TYPE`` + body, each type
  declared first by an FMT message (type 128: ``Type, Length, Name, Format, Columns``); the
  FMT and data messages are packed by pymavlink's ``DFReader.DFMessage.get_msgbuf`` (its
  writer of a message from its ``DFFormat``).  The formats are ArduPilot's own (4.x
  ``LogStructure.h``; ``IMU2`` without an instance field as older firmware wrote it).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

EPOCH_US = 1_700_000_000_000_000
"""Receive time of the first packet of a telemetry log, microseconds since 1970."""

DF_FORMATS = {
    "IMU": ("QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"),
    "IMU2": ("QffffffIIfBB", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,ErrG,ErrA,Temp,GyHlt,AcHlt"),
    "ACC": ("QBQfff", "TimeUS,I,SampleUS,AccX,AccY,AccZ"),
    "GYR": ("QBQfff", "TimeUS,I,SampleUS,GyrX,GyrY,GyrZ"),
    "MAG": ("QBhhhhhhhhhBI", "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S"),
    "MSG": ("QZ", "TimeUS,Message"),
    "ISBH": ("QHBBHHQf", "TimeUS,N,type,instance,mul,smp_cnt,SampleUS,smp_rate"),
    "ISBD": ("QHHaaa", "TimeUS,N,seqno,x,y,z"),
}


# --------------------------------------------------------------------------------------------
# Telemetry logs
# --------------------------------------------------------------------------------------------


class TlogWriter:
    """Packets into a telemetry log: ``add(receive_us, "raw_imu", *fields)`` encodes
    ``raw_imu_encode(*fields)`` with pymavlink and writes it after its receive time."""

    def __init__(self, version: int = 2, system: int = 1, component: int = 1) -> None:
        if version == 2:
            from pymavlink.dialects.v20 import common as dialect
        else:
            from pymavlink.dialects.v10 import common as dialect
        self.mav = dialect.MAVLink(None, srcSystem=system, srcComponent=component)
        self.data = bytearray()

    def add(self, receive_us: int, message: str, *fields) -> None:
        msg = getattr(self.mav, f"{message}_encode")(*fields)
        self.data += struct.pack(">Q", int(receive_us)) + msg.pack(self.mav)

    def write(self, path: Path) -> Path:
        path.write_bytes(bytes(self.data))
        return path


# --------------------------------------------------------------------------------------------
# DataFlash logs
# --------------------------------------------------------------------------------------------


class DataFlashWriter:
    """Messages into a DataFlash log, packed by pymavlink: ``add("IMU", [values])`` declares
    the type with an FMT message on first use (as ArduPilot does), then writes the message."""

    def __init__(self) -> None:
        from pymavlink import DFReader

        self.DFReader = DFReader
        self.fmt = DFReader.DFFormat(0x80, "FMT", 89, "BBnNZ", "Type,Length,Name,Format,Columns")
        self.types: dict[str, object] = {}
        self.data = bytearray(self._pack(self.fmt, [0x80, 89, "FMT", "BBnNZ",
                                                    "Type,Length,Name,Format,Columns"]))
        self.lines = ["FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns"]

    def _pack(self, fmt, values) -> bytes:
        buf = self.DFReader.DFMessage(fmt, list(values), False, None).get_msgbuf()
        assert buf is not None, (fmt.name, values)
        return buf

    def declare(self, name: str, form: str, columns: str, length: int | None = None) -> None:
        """An FMT message for ``name`` (``length`` overrides the true length: a damaged log)."""
        kind = 0x81 + len(self.types)
        probe = self.DFReader.DFFormat(kind, name, 0, form, columns)
        true_length = 3 + struct.calcsize(probe.msg_struct)
        fmt = self.DFReader.DFFormat(kind, name, true_length, form, columns)
        self.types[name] = fmt
        self.data += self._pack(self.fmt, [kind, true_length if length is None else length,
                                           name, form, columns])  # fmt: skip
        self.lines.append(f"FMT, {kind}, {true_length}, {name}, {form}, {columns}")

    def add(self, name: str, values) -> None:
        if name not in self.types:
            self.declare(name, *DF_FORMATS[name])
        self.data += self._pack(self.types[name], values)
        self.lines.append(", ".join([name, *(_text(v) for v in values)]))

    def text(self) -> str:
        """The same log as text (``.log``): FMT lines then one message per line, fields
        separated by ``", "``, as Mission Planner converts a ``.bin`` (and pymavlink's
        ``DFReader_text`` reads it)."""
        return "\n".join(self.lines) + "\n"

    def write(self, path: Path) -> Path:
        path.write_bytes(bytes(self.data))
        return path


def _text(value) -> str:
    return repr(float(value)) if isinstance(value, float) else str(value)


def imu_row(time_us: int, instance: int | None, accel, gyro, temp: float) -> list:
    """The values of an ArduPilot IMU message (``instance`` None: the old IMU2 layout)."""
    gx, gy, gz = (float(v) for v in gyro)
    ax, ay, az = (float(v) for v in accel)
    if instance is None:
        return [time_us, gx, gy, gz, ax, ay, az, 0, 0, temp, 1, 1]
    return [time_us, instance, gx, gy, gz, ax, ay, az, 0, 0, temp, 1, 1, 1000, 1000]


def write_dataflash_six(path: Path, six, *, acc_gyr: bool = False) -> Path:
    """The six faces of ``six`` (time s, accel, gyro counts) as IMU instance 0 (m/s^2,
    rad/s), or (``acc_gyr``) as ACC and GYR instance 0."""
    t, a, g = six
    writer = DataFlashWriter()
    t_us = np.round((t - t[0]) * 1e6 + 1e6).astype(np.int64)
    acc, gyr = (a / 835.0).astype(np.float32), (g / 939.7).astype(np.float32)
    writer.add("MSG", [0, "ArduCopter V4.5.0"])
    for k in range(len(t)):
        if acc_gyr:
            writer.add("ACC", [int(t_us[k]) + 300, 0, int(t_us[k]), *map(float, acc[k])])
            writer.add("GYR", [int(t_us[k]) + 300, 0, int(t_us[k]), *map(float, gyr[k])])
        else:
            writer.add("IMU", imu_row(int(t_us[k]), 0, acc[k], gyr[k], 31.5))
    return writer.write(path)


def write_tlog_six(path: Path, six) -> Path:
    """The six faces of ``six`` as HIGHRES_IMU (m/s^2, rad/s) in a telemetry log."""
    t, a, g = six
    writer = TlogWriter()
    t_us = np.round((t - t[0]) * 1e6 + 1e6).astype(np.int64)
    acc, gyr = a / 835.0, g / 939.7
    for k in range(len(t)):
        writer.add(EPOCH_US + int(t_us[k]) + 2000, "highres_imu", int(t_us[k]), *acc[k],
                   *gyr[k], 0.2, 0.0, 0.4, 1013.0, 0.0, 0.0, 30.0, 0x1FFF, 0)  # fmt: skip
    return writer.write(path)
