"""``imucal import`` of a log holding several IMUs (issue 28): which streams make the set and
how their recordings become one session (``/raw`` the reference, ``/imus/<name>`` the others,
each with its own time stamps, never resampled).

The set, one stream per IMU, the reference first (where a reader refuses "several IMU
streams" and no ``--topic`` chose one):

- PX4 ULog: every instance of the IMU topic read (``sensor_accel.0``, ``sensor_accel.1``, ...);
- ROS: every ``sensor_msgs/Imu`` topic;
- DataFlash: the ``IMU`` instances (``IMU.0``, ``IMU.1``, ``IMU.2``), else the ``ACC``/``GYR``
  ones, else the batch sampler's;
- MAVLink telemetry: per IMU number, ``RAW_IMU`` (``id`` 0, 1, 2: IMU 1, 2, 3), else
  ``SCALED_IMU``/``SCALED_IMU2``/``SCALED_IMU3``, else ``HIGHRES_IMU``; a log of several
  senders is not taken as one set;
- CSV: fields suffixed ``.N`` (:mod:`imucal_cli.formats.set_columns`).
"""

from __future__ import annotations

import re

import numpy as np

from imucal_cli.formats.session import ImuStream

from .recording import Recording

__all__ = ["imu_name", "imu_stream", "set_streams"]

_TLOG = re.compile(r"^(RAW_IMU|SCALED_IMU(\d?)|HIGHRES_IMU)(?:\.(\d+))?$")
_TLOG_PREFERENCE = ("RAW_IMU", "SCALED_IMU", "HIGHRES_IMU")


def imu_name(label: str) -> str:
    """A stream's label as an IMU (HDF5 group) name: ``/imu0/data`` -> ``imu0_data``."""
    name = label.strip("/").replace("/", "_").strip()
    return name or "imu"


def _tlog_number(label: str) -> tuple[int, int] | None:
    """``(IMU number, preference)`` of a telemetry stream label, None if not one."""
    m = _TLOG.match(label)
    if m is None:
        return None
    name, digit, ident = m.group(1), m.group(2), m.group(3)
    if name.startswith("SCALED_IMU"):
        return (int(digit) if digit else 1), 1
    number = int(ident) + 1 if ident is not None else 1
    return number, 0 if name == "RAW_IMU" else 2


def set_streams(labels: list[str]) -> list[str]:
    """The streams of ``labels`` that make a set of IMUs, one per IMU (module notes); fewer
    than 2: no set (the reader's refusal stands)."""
    if any("@" in label for label in labels):
        return []
    for kind in ("IMU", "ACC", "ISB"):
        found = [x for x in labels if x.startswith(f"{kind}.")]
        if found:
            return found if len(found) > 1 else []
    tlog = {x: _tlog_number(x) for x in labels}
    if all(v is not None for v in tlog.values()) and tlog:
        best: dict[int, tuple[int, str]] = {}
        for label, (number, pref) in tlog.items():
            if number not in best or pref < best[number][0]:
                best[number] = (pref, label)
        return [best[n][1] for n in sorted(best)] if len(best) > 1 else []
    return list(labels)


def imu_stream(rec: Recording, units: tuple[str | None, str | None, str | None],
               sensor: str | None = None) -> ImuStream:  # fmt: skip
    """One other IMU of the set: its recording as read (its own times), with the units it
    fixes or those given (``--accel-units`` ..., as for the reference)."""
    accel_units, gyro_units, mag_units = units
    return ImuStream(
        time=np.asarray(rec.time, float), accel=rec.accel, gyro=rec.gyro, mag=rec.mag,
        temperature=rec.temperature, sensor=sensor,
        accel_units=(accel_units or rec.accel_units) if rec.accel is not None else None,
        gyro_units=(gyro_units or rec.gyro_units) if rec.gyro is not None else None,
        mag_units=(mag_units or rec.mag_units) if rec.mag is not None else None,
        sample_rate_hz=float(rec.rate_hz) if np.isfinite(rec.rate_hz) else None,
    )  # fmt: skip
