"""What the virtual IMU of ``imucal simulate --serve`` prints (:mod:`.device`): a simulated
session's samples as text lines, numbers (``t,ax,...``, their field names) or as MotionCal's and
i2cdevlib's Arduino sketches print them (MotionCal's with a magnetometer seen through the unit's
tilt), and a line damaged on purpose.
"""

from __future__ import annotations

import numpy as np

from imucal_cli.errors import InputError

SERVE_PROTOCOLS = ("lines", "motioncal", "i2cdevlib")
"""What the virtual IMU can print: numbers (``t,ax,...``), MotionCal or i2cdevlib lines."""

HARD_IRON_COUNTS = (150.0, -90.0, 60.0)
"""The offset of the virtual magnetometer of MotionCal lines, counts."""


def line_columns(accel: np.ndarray, gyro: np.ndarray | None, temperature: bool,
             mag: np.ndarray | None = None) -> str:  # fmt: skip
    """The field names of a line: ``t,ax,ay,az[,a4..],gx,gy,gz[,mx,my,mz][,temp]``."""
    names = ["t", "ax", "ay", "az"] + [f"a{k}" for k in range(4, accel.shape[1] + 1)]
    if gyro is not None:
        names += ["gx", "gy", "gz"] + [f"g{k}" for k in range(4, gyro.shape[1] + 1)]
    if mag is not None:
        names += ["mx", "my", "mz"]
    return ",".join(names + (["temp"] if temperature else []))


def format_lines(
    time: np.ndarray, accel: np.ndarray, gyro: np.ndarray | None, temperature,
    counts: bool, mag: np.ndarray | None = None, mag_counts: bool = True,
) -> list[bytes]:  # fmt: skip
    """The data lines; ``temperature``: False (no field), the session's temperatures (N,),
    or True (a part at room temperature, warming a little: 25 C plus 0.01 C/s)."""
    columns = [time, accel] + ([] if gyro is None else [gyro])
    n_values = sum(c.shape[1] for c in columns[1:])
    value = "%.0f" if counts else "%.6f"
    fields = ["%.4f"] + [value] * n_values
    if mag is not None:
        columns.append(mag)
        fields += ["%.0f" if mag_counts else "%.4f"] * mag.shape[1]
    with_temp = temperature is not None and temperature is not False
    fmt = ",".join(fields + (["%.2f"] if with_temp else []))
    if with_temp:
        own = not isinstance(temperature, bool)
        columns.append((np.asarray(temperature, float) if own else 25.0 + 0.01 * time)[:, None])
    rows = np.column_stack(columns).tolist()
    return [(fmt % tuple(r) + "\n").encode() for r in rows]


def tilted_field(accel: np.ndarray, field_uT: float = 48.0,
                  inclination_deg: float = 60.0) -> np.ndarray:  # fmt: skip
    """The earth's field (north along world x, ``inclination_deg`` below the horizontal) read
    by a unit whose accelerometer points along ``accel`` (world up), its heading fixed: the
    smallest rotation taking world up (z) to the measured up, applied to the field, uT."""
    inc = np.radians(inclination_deg)
    h = field_uT * np.array([np.cos(inc), 0.0, -np.sin(inc)])
    up = accel / np.linalg.norm(accel, axis=1, keepdims=True)
    v = np.cross([0.0, 0.0, 1.0], up)  # axis * sin(angle)
    c = up[:, 2]  # cos(angle)
    flipped = c < -1 + 1e-9  # upside down: a half turn about x
    scale = np.where(flipped, 0.0, 1.0 / np.where(flipped, 1.0, 1.0 + c))
    vxh = np.cross(v, h)
    out = h + vxh + np.cross(v, vxh) * scale[:, None]
    out[flipped] = h * [1.0, -1.0, -1.0]
    return out


def format_sketch(protocol: str, accel: np.ndarray, gyro: np.ndarray | None) -> list[bytes]:
    """Lines as MotionCal's or i2cdevlib's sketches print them (integer counts, no time)."""
    if accel.shape[1] != 3 or gyro is None:
        raise InputError(f"--protocol {protocol} prints a 3-axis accelerometer and gyroscope "
                         "(not a redundant unit)")  # fmt: skip
    values = [np.round(accel), np.round(gyro)]
    if protocol == "motioncal":
        values.append(np.round(tilted_field(accel) * 10.0 + HARD_IRON_COUNTS))
        fmt = "Raw:" + ",".join(["%d"] * 9)
    else:
        fmt = "a/g:\t" + "\t".join(["%d"] * 6)
    rows = np.column_stack(values).astype(np.int64).tolist()
    return [(fmt % tuple(r) + "\n").encode() for r in rows]


def protocol_lines(protocol: str, time, accel, gyro, temperature: bool, units: str, mag=None,
           mag_units: str = "counts") -> list[bytes]:  # fmt: skip
    """The data lines of ``protocol`` (:data:`SERVE_PROTOCOLS`)."""
    if protocol == "lines":
        return format_lines(time, accel, gyro, temperature, units == "counts", mag,
                       mag_units == "counts")  # fmt: skip
    if protocol not in SERVE_PROTOCOLS:
        raise InputError(f"--protocol {protocol!r}: use {', '.join(SERVE_PROTOCOLS)}")
    if units != "counts":
        raise InputError(f"--protocol {protocol} prints counts: leave out --units {units}")
    if mag is not None:
        raise InputError(f"--protocol {protocol} prints its own magnetometer (or none): "
                         "leave out --mag")  # fmt: skip
    return format_sketch(protocol, accel, gyro)


def damaged(line: bytes) -> bytes:
    """A malformed version of a data line: its last two fields are lost."""
    sep = b"\t" if b"\t" in line else b","
    return sep.join(line.rstrip(b"\n").split(sep)[:-2]) + b"\n"
