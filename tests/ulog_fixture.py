"""A minimal PX4 ULog writer, written from the ULog file format specification (PX4 user guide,
"ULog File Format"): the 16-byte header, the flag-bits message, format ('F'), info ('I'),
subscription ('A') and data ('D') messages.  Only for test fixtures."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

MAGIC = b"ULog\x01\x12\x35"
_TYPES = {"uint64_t": "Q", "uint32_t": "I", "int32_t": "i", "float": "f", "uint8_t": "B"}


def _msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def write_ulog(path: Path, topics: list[tuple[str, int, list[tuple[str, str]], dict]]) -> None:
    """``topics``: (name, multi_id, [(type, field)...] with ``uint64_t timestamp`` first,
    columns {field: array}).  Messages are written interleaved in timestamp order."""
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
        packer = struct.Struct("<" + "".join(_TYPES[t] for t, _ in fields))
        n = len(cols["timestamp"])
        for i in range(n):
            values = [cols[f][i].item() if isinstance(cols[f][i], np.generic) else cols[f][i]
                      for _, f in fields]  # fmt: skip
            rows.append((cols["timestamp"][i], msg_id, packer.pack(*values)))
    for _, msg_id, data in sorted(rows, key=lambda r: (r[0], r[1])):
        out += _msg(b"D", struct.pack("<H", msg_id) + data)
    path.write_bytes(bytes(out))


SENSOR_FIELDS = [("uint64_t", "timestamp"), ("uint64_t", "timestamp_sample"),
                 ("uint32_t", "device_id"), ("float", "x"), ("float", "y"), ("float", "z"),
                 ("float", "temperature")]  # fmt: skip
