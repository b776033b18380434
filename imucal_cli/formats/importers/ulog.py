"""PX4 ULog (``.ulg``) read with ``pyulog`` (``pip install 'imucal-cli[px4]'``).

The IMU topics PX4 logs (uORB message definitions, ``msg/*.msg`` of PX4-Autopilot), from the
rawest to the most processed; the first present at a usable rate is read unless ``--topic``
names one (``sensor_accel_fifo``, ``sensor_accel``, ``vehicle_imu``, ``sensor_combined``, with
``.N`` for an instance, or ``N`` alone):

=====================  ===============================================  ==========================
topic                  what it holds                                    samples, time
=====================  ===============================================  ==========================
sensor_accel_fifo +    every sample of the driver's FIFO, int16 ``x y   ``samples`` per message,
sensor_gyro_fifo       z[32]`` times ``scale`` (m/s^2, rad/s: stored     ``dt`` us apart, the last
                       as the SI values), board frame, before PX4's     at ``timestamp_sample``
                       calibration                                      (full rate)
sensor_accel +         one value per message (``x y z``, m/s^2, rad/s),  ``timestamp_sample``; PX4's
sensor_gyro            board frame, before PX4's calibration;           default profile logs them
                       ``temperature`` deg C, ``device_id``             at about 1 Hz
vehicle_imu            ``delta_velocity / delta_velocity_dt`` and       ``timestamp_sample``
                       ``delta_angle / delta_angle_dt`` (m/s^2,         (the estimator's rate)
                       rad/s): integrated, **after** PX4's calibration
sensor_combined        ``accelerometer_m_s2``, ``gyro_rad``: **after**  ``timestamp`` (the gyro's;
                       PX4's calibration, body frame                    the accelerometer's is
                                                                        ``timestamp`` + its
                                                                        ``..._relative``)
=====================  ===============================================  ==========================

A calibration from the calibrated topics (``vehicle_imu``, ``sensor_combined``) is what is left
after PX4's own: the notes say so.  A recording under 50 Hz is read with a warning (PX4's
default profile logs ``sensor_accel`` at 1 Hz: nothing to calibrate from).

Accelerometer and gyroscope samples are paired, never resampled: when both run on one sample
clock their times coincide; otherwise each sample of the slower sensor takes the nearest
sample of the faster one within half of the faster one's period, and unmatched samples are
left out (counted as unpaired).  A vehicle with several IMUs logs several instances
(``multi_id``): ``--topic`` chooses one; with several and none chosen the reader refuses and
lists them with their device ids.  The magnetometer (``sensor_mag``, gauss), slower still, is
held (latest at or before each sample): the instance of the IMU's number, else the first, or
the one ``--mag-topic`` names (``sensor_mag.N`` or ``N``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.importers.library import one_line_reason, quiet
from imucal_cli.formats.importers.recording import SeveralStreams
from imucal_cli.formats.importers.ros import Channels, hold_latest, one_file, to_recording

__all__ = ["KINDS", "pair_by_time", "read_ulog"]

MIN_RATE_HZ = 50.0
"""Below this an IMU recording has too few samples to find still poses and integrate turns."""


@dataclass(frozen=True)
class Kind:
    """One way PX4 logs an IMU: the topics of its accelerometer and gyroscope (the same for
    the combined topics), and whether PX4's calibration is applied already."""

    name: str
    accel: str
    gyro: str
    calibrated: bool
    what: str


KINDS = {
    "sensor_accel_fifo": Kind("sensor_accel_fifo", "sensor_accel_fifo", "sensor_gyro_fifo", False,
                              "FIFO samples, full rate, before PX4's calibration"),
    "sensor_accel": Kind("sensor_accel", "sensor_accel", "sensor_gyro", False,
                         "before PX4's calibration"),
    "vehicle_imu": Kind("vehicle_imu", "vehicle_imu", "vehicle_imu", True,
                        "delta velocity and angle over their dt, after PX4's calibration"),
    "sensor_combined": Kind("sensor_combined", "sensor_combined", "sensor_combined", True,
                            "after PX4's calibration, body frame"),
}  # fmt: skip
_ALIASES = {"sensor_gyro_fifo": "sensor_accel_fifo", "sensor_gyro": "sensor_accel"}
TOPICS = ("sensor_accel_fifo", "sensor_gyro_fifo", "sensor_accel", "sensor_gyro", "vehicle_imu",
          "sensor_combined", "sensor_mag")  # fmt: skip


def _topic_choice(wanted: str | None) -> tuple[str | None, int | None]:
    """``(kind, instance)`` that ``--topic`` names (either may be None)."""
    if wanted is None:
        return None, None
    name, dot, number = wanted.rpartition(".")
    if not dot:
        name, number = (wanted, "") if not wanted.isdigit() else ("", wanted)
    name = _ALIASES.get(name, name)
    if name and name not in KINDS:
        raise InputError(f"--topic {wanted!r}: a ULog IMU topic is one of {', '.join(KINDS)} "
                         "(with .N for an instance), or an instance N")  # fmt: skip
    if number and not number.isdigit():
        raise InputError(f"--topic {wanted!r}: the instance is a number (0, 1, ...)")
    return name or None, int(number) if number else None


def _times(d: Any) -> np.ndarray:
    """A topic's sample times, s: ``timestamp_sample`` where the topic has it (a row where it
    is unset is NaN, left out: one damaged row must not move every sample to ``timestamp``,
    the time of publication), else ``timestamp``."""
    t = d.data.get("timestamp_sample")
    if t is None or np.count_nonzero(np.asarray(t) > 0) < 0.5 * len(t):
        return np.asarray(d.data["timestamp"], np.float64) * 1e-6
    t = np.asarray(t, np.float64)
    return np.where(t > 0, t, np.nan) * 1e-6


def _rate(t: np.ndarray) -> float:
    t = t[np.isfinite(t)]
    return float(1.0 / np.median(np.diff(t))) if len(t) >= 2 and np.median(np.diff(t)) > 0 \
        else 0.0  # fmt: skip


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


# --------------------------------------------------------------------------------------------
# Each kind's samples: (time s, accel (N, 3), gyro (N, 3), accel time, gyro time)
# --------------------------------------------------------------------------------------------


def _fifo(d: Any) -> tuple[np.ndarray, np.ndarray]:
    """The samples of a ``sensor_*_fifo`` topic: times (s) and values (SI), every valid one of
    each message (``samples`` of ``x[32]`` ...), ``dt`` us apart, the last at
    ``timestamp_sample``; a message whose ``samples`` or ``dt`` cannot be right is left out."""
    n = np.asarray(d.data["samples"], np.int64)
    dt = np.asarray(d.data["dt"], np.float64)
    scale = np.asarray(d.data["scale"], np.float64)
    end = np.asarray(d.data["timestamp_sample"], np.float64)
    ok = (n >= 1) & (n <= 32) & np.isfinite(dt) & (dt > 0) & (dt < 1e5) & np.isfinite(scale)
    k = np.arange(32)
    valid = ok[:, None] & (k[None, :] < n[:, None])
    t = (end[:, None] - (n[:, None] - 1 - k[None, :]) * dt[:, None]) * 1e-6
    xyz = np.stack([np.column_stack([d.data[f"{a}[{i}]"] for i in range(32)])
                    for a in "xyz"], axis=-1).astype(np.float64) * scale[:, None, None]  # fmt: skip
    return t[valid], xyz[valid]


def _raw(a: Any, g: Any) -> tuple:
    t_a, t_g = _times(a), _times(g)
    acc = np.column_stack([a.data[k] for k in "xyz"]).astype(np.float64)
    gyr = np.column_stack([g.data[k] for k in "xyz"]).astype(np.float64)
    return t_a, acc, t_g, gyr


def _vehicle_imu(d: Any) -> tuple:
    t = _times(d)
    with np.errstate(all="ignore"):
        acc = np.column_stack([d.data[f"delta_velocity[{i}]"] for i in range(3)]).astype(float) \
            / (np.asarray(d.data["delta_velocity_dt"], float) * 1e-6)[:, None]  # fmt: skip
        gyr = np.column_stack([d.data[f"delta_angle[{i}]"] for i in range(3)]).astype(float) \
            / (np.asarray(d.data["delta_angle_dt"], float) * 1e-6)[:, None]  # fmt: skip
    return t, acc, t, gyr


def _sensor_combined(d: Any) -> tuple:
    t = np.asarray(d.data["timestamp"], np.float64) * 1e-6
    acc = np.column_stack([d.data[f"accelerometer_m_s2[{i}]"] for i in range(3)]).astype(float)
    gyr = np.column_stack([d.data[f"gyro_rad[{i}]"] for i in range(3)]).astype(float)
    return t, acc, t, gyr


# --------------------------------------------------------------------------------------------


def _load(path: str | os.PathLike, src: str):
    try:
        from pyulog import ULog
    except ImportError:
        raise InputError("reading a ULog needs pyulog: pip install 'imucal-cli[px4]'") from None
    try:
        with quiet():  # pyulog prints what it skips in a damaged log
            log = ULog(str(path), message_name_filter_list=list(TOPICS))
    except MemoryError:
        raise InputError(f"{src}: damaged ULog (a message asks for more memory than there "
                         "is)") from None  # fmt: skip
    except Exception as exc:  # noqa: BLE001 - pyulog raises plain exceptions
        raise InputError(f"{src}: not a readable ULog ({one_line_reason(exc)})") from None
    found: dict[str, dict[int, Any]] = {name: {} for name in TOPICS}
    for d in log.data_list:
        if d.name in found and len(d.data.get("timestamp", ())) > 0:
            found[d.name][d.multi_id] = d
    return found


def _instances(found: dict, kind: Kind) -> list[int]:
    return sorted(set(found[kind.accel]) & set(found[kind.gyro]))


def _choose(found: dict, wanted: str | None, src: str) -> tuple[Kind, int, list[str]]:
    """The kind and instance to read (see the module notes), and warnings."""
    name, instance = _topic_choice(wanted)
    present = [k for k in KINDS.values() if _instances(found, k)]
    if not present:
        missing = " and ".join(t for t in ("sensor_accel", "sensor_gyro") if not found[t])
        raise InputError(f"{src}: no IMU topic pair in the log ({missing or 'sensor_gyro'} "
                         "missing; log sensor_accel_fifo/sensor_gyro_fifo, sensor_accel/"
                         "sensor_gyro, vehicle_imu or sensor_combined)")  # fmt: skip
    if name is not None:
        kind = KINDS[name]
        if kind not in present:
            raise InputError(f"{src}: --topic {wanted}: no {kind.accel} and {kind.gyro} in the "
                             f"log; IMU topics: {', '.join(k.name for k in present)}")  # fmt: skip
    else:
        kind = _default_kind(found, present, instance)
    instances = _instances(found, kind)
    if instance is None:
        if len(instances) > 1:
            listed = ", ".join(f"{kind.name}.{i} (device_id {_device_id(found, kind, i)})"
                               for i in instances)  # fmt: skip
            raise SeveralStreams(f"{src}: several IMU instances: {listed}; choose one with "
                                 "--topic N or --topic TOPIC.N",
                                 [f"{kind.name}.{i}" for i in instances])  # fmt: skip
        instance = instances[0]
    if instance not in instances:
        raise InputError(f"{src}: no {kind.accel} and {kind.gyro} instance {instance}; "
                         f"instances: {instances}")  # fmt: skip
    return kind, instance, []


def _default_kind(found: dict, present: list[Kind], instance: int | None) -> Kind:
    """The rawest kind logged at a usable rate, else the fastest."""
    def rate(kind: Kind) -> float:
        ids = _instances(found, kind)
        d = found[kind.accel][instance if instance in ids else ids[0]]
        r = _rate(_times(d))
        return r * (float(np.median(d.data["samples"])) if kind.name == "sensor_accel_fifo"
                    else 1.0)  # fmt: skip

    usable = [k for k in present if rate(k) >= MIN_RATE_HZ]
    return usable[0] if usable else max(present, key=rate)


def _device_id(found: dict, kind: Kind, instance: int) -> str:
    d = found[kind.accel][instance]
    for key in ("device_id", "accel_device_id"):
        if key in d.data and len(d.data[key]):
            return str(int(d.data[key][0]))
    return "?"


def _samples(found: dict, kind: Kind, instance: int) -> tuple:
    a, g = found[kind.accel][instance], found[kind.gyro][instance]
    if kind.name == "sensor_accel_fifo":
        t_a, acc = _fifo(a)
        t_g, gyr = _fifo(g)
        return t_a, acc, t_g, gyr
    if kind.name == "sensor_accel":
        return _raw(a, g)
    return _vehicle_imu(a) if kind.name == "vehicle_imu" else _sensor_combined(a)


def read_ulog(path: str | os.PathLike, topic: str | None = None,
              mag_topic: str | None = None) -> Channels:  # fmt: skip
    """Accelerometer, gyroscope (and magnetometer) samples of a PX4 ULog (module notes).

    Raises
    ------
    InputError
        pyulog not installed (names the extra), an unreadable or damaged log, no IMU topic
        pair, several instances and none chosen, or a ``--topic``/``--mag-topic`` not in it.
    """
    src = str(path)
    found = _load(path, src)
    try:
        return _read(found, topic, mag_topic, src)
    except (KeyError, IndexError, ValueError) as exc:  # a damaged format definition
        raise InputError(f"{src}: damaged ULog (a topic lacks a field its message has: "
                         f"{one_line_reason(exc)})") from None  # fmt: skip


def _read(found: dict, topic: str | None, mag_topic: str | None, src: str) -> Channels:
    kind, instance, warnings = _choose(found, topic, src)
    t_a, acc, t_g, gyr = _samples(found, kind, instance)
    ok_a, ok_g = np.isfinite(t_a), np.isfinite(t_g)  # a row whose sample time was unset
    unset = int((~ok_a).sum() + (~ok_g).sum())
    t_a, acc, t_g, gyr = t_a[ok_a], acc[ok_a], t_g[ok_g], gyr[ok_g]
    if min(len(t_a), len(t_g)) < 2:
        raise InputError(f"{src}: {kind.name} instance {instance} holds {min(len(t_a), len(t_g))} "
                         "samples")  # fmt: skip
    order_a, order_g = np.argsort(t_a, kind="stable"), np.argsort(t_g, kind="stable")
    t_a, acc, t_g, gyr = t_a[order_a], acc[order_a], t_g[order_g], gyr[order_g]
    ia, ig = pair_by_time(t_a, t_g)
    if len(ia) == 0:
        raise InputError(f"{src}: {kind.accel} and {kind.gyro} share no time")
    time = t_a[ia] if np.median(np.diff(t_a)) >= np.median(np.diff(t_g)) else t_g[ig]
    acc, gyr = acc[ia], gyr[ig]
    keep = np.concatenate([[True], np.diff(time) > 0]) & np.isfinite(acc).all(1) \
        & np.isfinite(gyr).all(1)  # fmt: skip
    device_id = _device_id(found, kind, instance)
    paired = len(t_a) == len(t_g) == len(ia)
    notes = [
        f"{kind.accel}/{kind.gyro} instance {instance} ({kind.what})"
        + (f", accel device_id {device_id} (for export --format px4 --device-id)"
           if device_id != "?" else ""),
        f"{len(ia)} samples" + ("" if paired else f", paired by time of {len(t_a)} accel and "
                                f"{len(t_g)} gyro samples"),
    ]  # fmt: skip
    if kind.calibrated:
        notes.append(f"{kind.name} holds PX4's calibrated values: a calibration of them is "
                     "what remains after PX4's own")  # fmt: skip
    ch = Channels(time=time[keep], accel=acc[keep], gyro=gyr[keep], accel_units="m/s^2",
                  gyro_units="rad/s", notes=notes, dropped=int((~keep).sum()) + unset,
                  unpaired=int(len(t_a) + len(t_g) - 2 * len(ia)), warnings=warnings)  # fmt: skip
    rate = _rate(ch.time)
    if rate < MIN_RATE_HZ:
        ch.warnings.append(
            f"{kind.accel} and {kind.gyro} are logged at {rate:.3g} Hz: too slow to calibrate "
            "from (PX4's default profile logs them at about 1 Hz); log the full-rate topics: "
            "SDLOG_PROFILE 'Raw FIFO high-rate IMU data' (sensor_accel_fifo, sensor_gyro_fifo) "
            "or 'High rate' (sensor_combined)"
        )
    _temperature(ch, found, instance, time, keep)
    _magnetometer(ch, found, instance, mag_topic, src)
    return ch


def _temperature(ch: Channels, found: dict, instance: int, time, keep) -> None:
    """``sensor_accel``'s temperature (latest per sample) where it is logged."""
    d = found["sensor_accel"].get(instance)
    if d is None or "temperature" not in d.data:
        return
    temp = np.asarray(d.data["temperature"], np.float64)
    if np.isfinite(temp).any():
        ch.temperature = hold_latest(_times(d), temp, time[keep])
        ch.notes.append(f"temperature: sensor_accel instance {instance}'s, latest per sample")


def _magnetometer(ch: Channels, found: dict, instance: int, wanted: str | None, src: str) -> None:
    mags = found["sensor_mag"]
    if wanted is not None:
        number = wanted.rpartition(".")[2]
        if not number.isdigit() or int(number) not in mags:
            raise InputError(f"{src}: --mag-topic {wanted}: sensor_mag instances in the log: "
                             f"{sorted(mags) or 'none'}")  # fmt: skip
        m = mags[int(number)]
    elif mags:
        m = mags.get(instance, mags[min(mags)])
    else:
        return
    ch.mag = hold_latest(_times(m), np.column_stack([m.data[k] for k in "xyz"]).astype(float),
                         ch.time)  # fmt: skip
    ch.mag_units = "gauss"
    ch.notes.append(f"sensor_mag instance {m.multi_id} (gauss), latest per sample")


NAME = "ulog"
FILES = "one PX4 ULog (.ulg)"


def read(paths, options, stats):
    """``imucal import --format ulog``: :func:`read_ulog` of the one path, ``--topic``,
    ``--mag-topic``."""
    path = one_file(paths, options, NAME, FILES)
    return to_recording(read_ulog(path, options.topic, options.mag_topic), paths, stats)
