"""A minimal PX4 ULog writer, written from the ULog file format specification (PX4 user guide,
"ULog File Format"): the 16-byte header, the flag-bits message, format ('F'), info ('I'),
subscription ('A') and data ('D') messages.  Only for test fixtures."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

MAGIC = b"ULog\x01\x12\x35"
_TYPES = {"uint64_t": "Q", "uint32_t": "I", "int32_t": "i", "float": "f", "uint8_t": "B",
          "int16_t": "h", "uint16_t": "H"}


def _packing(type_: str) -> tuple[str, int]:
    """``("h", 32)`` for ``int16_t[32]``, ``("f", 1)`` for ``float``."""
    base, _, count = type_.partition("[")
    return _TYPES[base], int(count.rstrip("]")) if count else 1


def _msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def write_ulog(path: Path, topics: list[tuple[str, int, list[tuple[str, str]], dict]]) -> None:
    """``topics``: (name, multi_id, [(type, field)...] with ``uint64_t timestamp`` first,
    columns {field: array}; an array field, ``int16_t[32] x``, has a column of rows).
    Messages are written interleaved in timestamp order."""
    out = bytearray(MAGIC + b"\x01" + struct.pack("<Q", 0))
    out += _msg(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
    seen = set()
    for name, _, fields, _ in topics:
        if name not in seen:
            seen.add(name)
            fmt = f"{name}:" + "".join(f"{t} {f};" for t, f in fields)
            out += _msg(b"F", fmt.encode())
    key = b"char[5] sys_name"
    out += _msg(b"I", bytes([len(key)]) + key + b"PX4 \x00"[:5])
    rows = []
    for msg_id, (name, multi_id, fields, cols) in enumerate(topics):
        out += _msg(b"A", struct.pack("<BH", multi_id, msg_id) + name.encode())
        packs = [_packing(t) for t, _ in fields]
        packer = struct.Struct("<" + "".join((str(n) if n > 1 else "") + code
                                             for code, n in packs))  # fmt: skip
        n = len(cols["timestamp"])
        for i in range(n):
            values = []
            for (_, f), (_, count) in zip(fields, packs, strict=True):
                v = cols[f][i]
                values += [x.item() if isinstance(x, np.generic) else x
                           for x in (v if count > 1 else [v])]  # fmt: skip
            rows.append((cols["timestamp"][i], msg_id, packer.pack(*values)))
    for _, msg_id, data in sorted(rows, key=lambda r: (r[0], r[1])):
        out += _msg(b"D", struct.pack("<H", msg_id) + data)
    path.write_bytes(bytes(out))


SENSOR_FIELDS = [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"),
                 ("uint32_t", "device_id"), ("float", "x"), ("float", "y"), ("float", "z"),
                 ("float", "temperature")]  # fmt: skip


FIFO_FIELDS = [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"),
               ("uint32_t", "device_id"), ("float", "dt"), ("float", "scale"),
               ("uint8_t", "samples"), ("int16_t[32]", "x"), ("int16_t[32]", "y"),
               ("int16_t[32]", "z")]  # fmt: skip
"""PX4's ``sensor_accel_fifo`` / ``sensor_gyro_fifo`` (msg/SensorAccelFifo.msg)."""
VEHICLE_IMU_FIELDS = [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"),
                      ("uint32_t", "accel_device_id"), ("uint32_t", "gyro_device_id"),
                      ("float[3]", "delta_angle"), ("float[3]", "delta_velocity"),
                      ("uint16_t", "delta_angle_dt"), ("uint16_t", "delta_velocity_dt"),
                      ("uint8_t", "delta_angle_clipping"), ("uint8_t", "delta_velocity_clipping"),
                      ("uint8_t", "accel_calibration_count"),
                      ("uint8_t", "gyro_calibration_count")]  # fmt: skip
"""PX4's ``vehicle_imu`` (msg/VehicleImu.msg)."""
SENSOR_COMBINED_FIELDS = [("uint64_t", "timestamp"), ("float[3]", "gyro_rad"),
                          ("uint32_t", "gyro_integral_dt"),
                          ("int32_t", "accelerometer_timestamp_relative"),
                          ("float[3]", "accelerometer_m_s2"),
                          ("uint32_t", "accelerometer_integral_dt"),
                          ("uint8_t", "accelerometer_clipping"), ("uint8_t", "gyro_clipping"),
                          ("uint8_t", "accel_calibration_count"),
                          ("uint8_t", "gyro_calibration_count")]  # fmt: skip
"""PX4's ``sensor_combined`` (msg/SensorCombined.msg)."""
MAG_FIELDS = [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"),
              ("uint32_t", "device_id"), ("float", "x"), ("float", "y"), ("float", "z"),
              ("float", "temperature")]  # fmt: skip
