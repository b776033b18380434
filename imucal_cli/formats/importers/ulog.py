"""PX4 ULog (``.ulg``) read with ``pyulog`` (``pip install 'imucal-cli[px4]'``).

The raw topics, as the drivers publish them before PX4's calibration is applied:
``sensor_accel`` (``x y z`` m/s^2, ``temperature`` deg C, ``device_id``) and ``sensor_gyro``
(``x y z`` rad/s), timed by ``timestamp_sample`` (else ``timestamp``), microseconds; and
``sensor_mag`` (gauss) where present.  A vehicle with several IMUs logs several instances
(``multi_id``): ``topic`` chooses one (``"1"`` or ``"sensor_accel.1"``); with several and none
chosen the reader refuses and lists them with their device ids.

Accelerometer and gyroscope samples are paired, never resampled: when both run on one sample
clock their times coincide; otherwise each sample of the slower sensor takes the nearest
sample of the faster one within half of the faster one's period, and unmatched samples are
dropped (counted).  The magnetometer, slower still, is held (latest at or before each sample).
The ``device_id`` is reported, for ``imucal export --format px4 --device-id``.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.importers.ros import Channels, hold_latest

__all__ = ["pair_by_time", "read_ulog"]

TOPICS = ("sensor_accel", "sensor_gyro", "sensor_mag")


def _instance(wanted: str | None) -> int | None:
    if wanted is None:
        return None
    text = wanted.rpartition(".")[2] if "." in wanted else wanted
    try:
        return int(text)
    except ValueError:
        raise InputError(f"--topic {wanted!r}: a ULog instance is a number (0, 1, ...) or "
                         "sensor_accel.N") from None  # fmt: skip


def _times(d: Any) -> np.ndarray:
    t = d.data.get("timestamp_sample")
    if t is None or not np.all(t > 0):
        t = d.data["timestamp"]
    return np.asarray(t, np.float64) * 1e-6


def pair_by_time(t_a: np.ndarray, t_g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(ia, ig)`` pairing accel and gyro samples by time (see the module notes; the
    DataFlash reader pairs ACC and GYR the same way)."""
    common, ia, ig = np.intersect1d(t_a, t_g, return_indices=True)
    if len(common) >= 0.9 * min(len(t_a), len(t_g)):
        return ia, ig
    slow_is_a = np.median(np.diff(t_a)) >= np.median(np.diff(t_g))
    slow, fast = (t_a, t_g) if slow_is_a else (t_g, t_a)
    half = 0.5 * float(np.median(np.diff(fast)))
    j = np.clip(np.searchsorted(fast, slow), 1, len(fast) - 1)
    j = np.where(np.abs(fast[j - 1] - slow) <= np.abs(fast[j] - slow), j - 1, j)
    ok = np.abs(fast[j] - slow) <= half
    i_slow, i_fast = np.flatnonzero(ok), j[ok]
    _, first = np.unique(i_fast, return_index=True)  # a fast sample pairs once
    i_slow, i_fast = i_slow[first], i_fast[first]
    return (i_slow, i_fast) if slow_is_a else (i_fast, i_slow)


def read_ulog(path: str | os.PathLike, topic: str | None = None) -> Channels:
    """Accelerometer, gyroscope (and magnetometer) samples of a PX4 ULog.

    Raises
    ------
    InputError
        pyulog not installed (names the extra), an unreadable log, no ``sensor_accel`` /
        ``sensor_gyro``, or several instances and none chosen.
    """
    try:
        from pyulog import ULog
    except ImportError:
        raise InputError("reading a ULog needs pyulog: pip install 'imucal-cli[px4]'") from None
    src = str(path)
    try:
        log = ULog(str(path), message_name_filter_list=list(TOPICS))
    except Exception as exc:  # noqa: BLE001 - pyulog raises plain exceptions
        raise InputError(f"{src}: not a readable ULog ({' '.join(str(exc).split())})") from None
    found: dict[str, dict[int, Any]] = {name: {} for name in TOPICS}
    for d in log.data_list:
        if d.name in found:
            found[d.name][d.multi_id] = d
    accel, gyro = found["sensor_accel"], found["sensor_gyro"]
    if not accel or not gyro:
        missing = " and ".join(n for n in ("sensor_accel", "sensor_gyro") if not found[n])
        raise InputError(f"{src}: no {missing} topic in the log (log the raw sensor topics: "
                         "SDLOG_PROFILE high rate or sensor comparison)")  # fmt: skip
    wanted = _instance(topic)
    if wanted is None:
        if len(accel) > 1 or len(gyro) > 1:
            listed = ", ".join(
                f"{i} (device_id {int(accel[i].data['device_id'][0]) if i in accel else '?'})"
                for i in sorted(set(accel) | set(gyro))
            )  # fmt: skip
            raise InputError(f"{src}: several IMU instances: {listed}; choose one with --topic N")
        wanted = next(iter(accel))
    if wanted not in accel or wanted not in gyro:
        raise InputError(f"{src}: no sensor_accel and sensor_gyro instance {wanted}; instances: "
                         f"accel {sorted(accel)}, gyro {sorted(gyro)}")  # fmt: skip
    a, g = accel[wanted], gyro[wanted]
    t_a, t_g = _times(a), _times(g)
    ia, ig = pair_by_time(t_a, t_g)
    if len(ia) == 0:
        raise InputError(f"{src}: sensor_accel and sensor_gyro share no time")
    time = t_a[ia] if np.median(np.diff(t_a)) >= np.median(np.diff(t_g)) else t_g[ig]
    acc = np.column_stack([a.data[k][ia] for k in "xyz"]).astype(np.float64)
    gyr = np.column_stack([g.data[k][ig] for k in "xyz"]).astype(np.float64)
    keep = np.concatenate([[True], np.diff(time) > 0]) & np.isfinite(acc).all(1) \
        & np.isfinite(gyr).all(1)  # fmt: skip
    device_id = int(a.data["device_id"][0]) if "device_id" in a.data else None
    notes = [
        f"sensor_accel/sensor_gyro instance {wanted}"
        + (f", accel device_id {device_id} (for export --format px4 --device-id)"
           if device_id else ""),
        f"{len(ia)} of {len(t_a)} accel and {len(t_g)} gyro samples paired by time",
    ]  # fmt: skip
    ch = Channels(time=time[keep], accel=acc[keep], gyro=gyr[keep], accel_units="m/s^2",
                  gyro_units="rad/s", notes=notes,
                  dropped=int(len(t_a) + len(t_g) - 2 * len(ia) + (~keep).sum()))  # fmt: skip
    temp = a.data.get("temperature")
    if temp is not None and np.isfinite(temp[ia][keep]).any():
        ch.temperature = np.asarray(temp[ia][keep], np.float64)
    mags = found["sensor_mag"]
    if mags:
        m = mags.get(wanted, mags[min(mags)])
        ch.mag = hold_latest(_times(m), np.column_stack([m.data[k] for k in "xyz"]).astype(float),
                       ch.time)  # fmt: skip
        ch.mag_units = "gauss"
        notes.append(f"sensor_mag instance {m.multi_id} (gauss), latest per sample")
    return ch


NAME = "ulog"
FILES = "one PX4 ULog (.ulg)"


def read(paths, options, stats):
    """``imucal import --format ulog``: :func:`read_ulog` of the one path, ``--topic N``."""
    from .ros import one_file, to_recording

    path = one_file(paths, options, NAME, FILES)
    return to_recording(read_ulog(path, options.topic), paths, stats)
