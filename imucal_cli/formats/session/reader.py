"""The validating reader: :func:`read_session` opens any file that follows the session format
(written by this package or by another tool) and returns a :class:`~.model.Session`."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from imucal_cli.errors import SessionError

from .h5open import get_attr, open_for_reading
from .model import (
    FORMAT,
    FORMAT_VERSION,
    GRAVITY_DEFAULT,
    LOG_DATASET,
    MAG_UNITS,
    SEGMENT_ATTRS,
    SEGMENT_KINDS,
    Segment,
    Session,
    as_float,
    as_int,
    as_str,
    as_unit_vector,
    one_line,
    show,
)


def read_session(path: str | os.PathLike) -> Session:
    """Read and validate a session file.

    Parameters
    ----------
    path : str or path-like
        The HDF5 session file.

    Returns
    -------
    Session
        Arrays as float64; segments sorted by start, ``up``/``axis`` scaled to unit length.

    Raises
    ------
    SessionError
        The file is missing, not HDF5, or does not follow the session format.  The message is
        one line naming the file and the problem.
    """
    path = Path(path)
    src = str(path)
    file, unclosed = open_for_reading(path, src)
    try:
        session = _read_open_file(file, src, unclosed)
    except (OSError, KeyError, RuntimeError) as exc:
        raise SessionError(f"{src}: damaged HDF5 file ({one_line(exc)})") from None
    finally:
        file.close()
    session.path = path
    return session


def _read_open_file(file: h5py.File, src: str, unclosed: bool) -> Session:
    root = {
        name: get_attr(file.attrs, name, src, "root ")
        for name in (
            "format", "format_version", "created", "sensor", "source", "sample_rate_hz",
            "gravity", "accel_units", "gyro_units", "mag_units", "magnetic_field_uT",
        )
    }  # fmt: skip
    fmt = root["format"]
    if fmt is None:
        raise SessionError(f"{src}: not an imucal session (no root attribute 'format')")
    if as_str(fmt) != FORMAT:
        raise SessionError(
            f"{src}: not an imucal session (format is {show(fmt)}, expected {FORMAT!r})"
        )
    version = root["format_version"]
    if version is None:
        raise SessionError(f"{src}: root attribute 'format_version' is missing")
    if as_int(version) != FORMAT_VERSION:
        raise SessionError(
            f"{src}: unsupported format_version {show(version)} (this reader reads "
            f"version {FORMAT_VERSION})"
        )
    created = as_str(root["created"])
    if created is None:
        problem = "is missing" if root["created"] is None else "is not a string"
        raise SessionError(f"{src}: root attribute 'created' {problem}")
    text = {}
    for name in ("sensor", "source", "accel_units", "gyro_units", "mag_units"):
        text[name] = None if root[name] is None else as_str(root[name])
        if root[name] is not None and text[name] is None:
            raise SessionError(f"{src}: root attribute {name!r} is not a string")
    if text["mag_units"] is not None and text["mag_units"] not in MAG_UNITS:
        raise SessionError(
            f"{src}: root attribute 'mag_units' is {text['mag_units']!r}, expected one of "
            f"{', '.join(MAG_UNITS)}"
        )
    numbers = {}
    for name in ("sample_rate_hz", "gravity", "magnetic_field_uT"):
        numbers[name] = None if root[name] is None else as_float(root[name])
        if root[name] is not None and (numbers[name] is None or numbers[name] <= 0):
            raise SessionError(
                f"{src}: root attribute {name!r} must be a positive number, got {show(root[name])}"
            )

    time, accel, gyro, temperature, mag, host_time = _read_raw(file, src, unclosed)
    segments = _read_segments(file, src, len(time), accel, gyro, unclosed)
    return Session(
        time=time,
        accel=accel,
        gyro=gyro,
        temperature=temperature,
        segments=segments,
        created=created,
        sensor=text["sensor"],
        source=text["source"],
        sample_rate_hz=numbers["sample_rate_hz"],
        gravity=GRAVITY_DEFAULT if numbers["gravity"] is None else numbers["gravity"],
        accel_units=text["accel_units"],
        gyro_units=text["gyro_units"],
        calibrations=_read_calibrations(file),
        mag=mag,
        mag_units=text["mag_units"],
        magnetic_field_uT=numbers["magnetic_field_uT"],
        host_time=host_time,
    )


def _read_raw(file: h5py.File, src: str, unclosed: bool) -> tuple[np.ndarray | None, ...]:
    """``time, accel, gyro, temperature, mag, host_time`` of ``/raw`` (None where absent),
    validated; a ``/raw/host_time`` of another length than ``/raw/time`` is ignored."""
    raw = file.get("raw")
    datasets: dict[str, h5py.Dataset] = {}
    for name in ("time", "accel", "gyro", "temperature", "mag", "host_time"):
        obj = raw.get(name) if isinstance(raw, h5py.Group) else None
        if obj is None:
            continue
        if not isinstance(obj, h5py.Dataset):
            raise SessionError(f"{src}: /raw/{name} is not a dataset")
        if obj.dtype.kind not in "iuf":
            raise SessionError(f"{src}: /raw/{name} is not numeric (dtype {obj.dtype})")
        datasets[name] = obj
    if "time" not in datasets:
        raise SessionError(f"{src}: /raw/time is missing")
    if datasets["time"].ndim != 1:
        raise SessionError(f"{src}: /raw/time must be 1-D, has shape {datasets['time'].shape}")
    n = datasets["time"].shape[0]
    host = datasets.pop("host_time", None)
    if unclosed:
        # An interrupted flush may have grown some datasets and not others.
        n = min(ds.shape[0] for ds in datasets.values() if ds.ndim >= 1)
    if host is not None and (host.ndim != 1 or host.shape[0] < n):
        host = None  # an extra the toolkit can do without
    elif host is not None:
        datasets["host_time"] = host
    for name in ("accel", "gyro", "mag"):
        ds = datasets.get(name)
        if ds is not None and (ds.ndim != 2 or ds.shape[0] < n or ds.shape[1] < 3):
            raise SessionError(
                f"{src}: /raw/{name} must have shape (N, >=3) with N = {n} samples, "
                f"has shape {ds.shape}"
            )
        if ds is not None and not unclosed and ds.shape[0] != n:
            raise SessionError(f"{src}: /raw/{name} has {ds.shape[0]} rows, /raw/time has {n}")
    ds = datasets.get("temperature")
    if ds is not None and (ds.shape != (n,) and (not unclosed or ds.ndim != 1)):
        raise SessionError(f"{src}: /raw/temperature must have shape ({n},), has shape {ds.shape}")

    def load(name: str) -> np.ndarray | None:
        if name not in datasets:
            return None
        return np.asarray(datasets[name][:n], dtype=np.float64)

    time = load("time")
    bad = np.flatnonzero(~np.isfinite(time))
    if bad.size:
        raise SessionError(f"{src}: /raw/time is {time[bad[0]]} at sample {bad[0]}")
    bad = np.flatnonzero(np.diff(time) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise SessionError(
            f"{src}: /raw/time is not strictly increasing "
            f"(sample {i}: {float(time[i])!r} s after {float(time[i - 1])!r} s)"
        )
    return time, load("accel"), load("gyro"), load("temperature"), load("mag"), load("host_time")


def _read_segments(
    file: h5py.File,
    src: str,
    n: int,
    accel: np.ndarray | None,
    gyro: np.ndarray | None,
    unclosed: bool,
) -> list[Segment]:
    segments = []
    group = file.get("segments")
    if isinstance(group, h5py.Group):
        for name in group:
            obj = group.get(name)
            if isinstance(obj, h5py.Group):
                where = f"/segments/{name}"
                get = _attr_getter(obj.attrs, src, where)
                segment = _parse_segment(name, get, src, where, n, accel, gyro)
                segment.extra.update(_extra_attrs(obj.attrs.items()))
                segments.append(segment)
    log = file.get(LOG_DATASET)
    if not segments and isinstance(log, h5py.Dataset):
        # The writer was killed before it wrote the segment groups: use its SWMR-safe log.
        for row, item in enumerate(log[()]):
            where = f"/{LOG_DATASET}[{row}]"
            try:
                entry = json.loads(bytes(item).decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError):
                raise SessionError(f"{src}: {where} is not a JSON object") from None
            if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
                raise SessionError(f"{src}: {where} is not a segment")
            if unclosed and isinstance(entry.get("stop"), int) and entry["stop"] > n:
                continue  # describes samples the writer did not get to save
            segment = _parse_segment(entry["name"], entry.get, src, where, n, accel, gyro)
            segment.extra.update(_extra_attrs((k, v) for k, v in entry.items() if k != "name"))
            segments.append(segment)
    segments.sort(key=lambda s: s.start)
    return segments


def _extra_attrs(items) -> dict[str, Any]:
    """Plain Python values of the attributes the format does not name."""
    extra = {}
    for key, value in items:
        if key in SEGMENT_ATTRS:
            continue
        if isinstance(value, bytes):
            value = value.decode("utf-8", "replace")
        elif isinstance(value, np.ndarray):
            value = value.tolist()
        elif isinstance(value, np.generic):
            value = value.item()
        extra[key] = value
    return extra


def _attr_getter(attrs: h5py.AttributeManager, src: str, where: str) -> Callable[[str], Any]:
    return lambda name: get_attr(attrs, name, src, f"{where}: ")


def _parse_segment(
    name: str,
    get: Callable[[str], Any],
    src: str,
    where: str,
    n: int,
    accel: np.ndarray | None,
    gyro: np.ndarray | None,
) -> Segment:
    def fail(problem: str) -> SessionError:
        return SessionError(f"{src}: {where}: {problem}")

    values = {}
    for key in ("kind", "start", "stop"):
        values[key] = get(key)
        if values[key] is None:
            raise fail(f"attribute {key!r} is missing")
    kind = as_str(values["kind"])
    if kind not in SEGMENT_KINDS:
        raise fail(f"unknown kind {show(values['kind'])} (expected 'static' or 'rotation')")
    start, stop = as_int(values["start"]), as_int(values["stop"])
    for key, number in (("start", start), ("stop", stop)):
        if number is None:
            raise fail(f"{key!r} must be an integer sample index, got {show(values[key])}")
    if start >= stop:
        raise fail(f"start {start} is not before stop {stop}")
    if start < 0 or stop > n:
        raise fail(f"samples [{start}, {stop}) are outside the recorded range [0, {n}]")
    label = get("label")
    if label is not None and as_str(label) is None:
        raise fail("attribute 'label' is not a string")
    label = None if label is None else as_str(label)

    up = axis = angle_deg = None
    if kind == "static":
        raw_up = get("up")
        if raw_up is not None:
            up = as_unit_vector(raw_up)
            if up is None:
                raise fail(f"'up' must be 3 finite numbers, not all zero, got {show(raw_up)}")
        data, dataset = accel, "/raw/accel"
    else:
        raw_axis = get("axis")
        if raw_axis is not None:
            axis = as_unit_vector(raw_axis)
            if axis is None:
                raise fail(f"'axis' must be 3 finite numbers, not all zero, got {show(raw_axis)}")
        raw_angle = get("angle_deg")
        if raw_angle is not None:
            angle_deg = as_float(raw_angle)
            if angle_deg is None:
                raise fail(f"'angle_deg' must be a finite number, got {show(raw_angle)}")
        data, dataset = gyro, "/raw/gyro"
    if data is None:
        raise fail(f"{kind} segment but the file has no {dataset}")
    bad = np.flatnonzero(~np.isfinite(data[start:stop]).all(axis=1))
    if bad.size:
        raise fail(f"{dataset} has NaN or inf at sample {start + int(bad[0])}, inside the segment")
    return Segment(name, kind, start, stop, label, up, axis, angle_deg)


def _read_calibrations(file: h5py.File) -> dict[str, str]:
    calibrations = {}
    group = file.get("calibrations")
    if isinstance(group, h5py.Group):
        for name in group:
            obj = group.get(name)
            if isinstance(obj, h5py.Group) and "json" in obj.attrs:
                text = as_str(obj.attrs["json"])
                if text is not None:
                    calibrations[name] = text
    return calibrations
