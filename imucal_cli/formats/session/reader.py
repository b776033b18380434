"""The validating reader: :func:`read_session` opens any file that follows the session format
(written by this package or by another tool) and returns a :class:`~.model.Session`."""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from imucal_cli.errors import ImucalWarning, SessionError
from imucal_cli.formats.config import GRAVITY_RANGE
from imucal_cli.formats.text import clean_text, clean_tree
from imucal_cli.model.session import (
    FORMAT,
    FORMAT_VERSION,
    GRAVITY_DEFAULT,
    LOG_DATASET,
    LOG_GROUP,
    MAG_UNITS,
    MAX_FIELD_UT,
    SEGMENT_ATTRS,
    SEGMENT_KINDS,
    TURN_ANGLE_RULE,
    Segment,
    Session,
    as_float,
    as_int,
    as_str,
    as_turn_angle,
    as_unit_vector,
    check_rate,
    check_readings,
    one_line,
    show,
)

from .h5open import check_dataset, file_size, get_attr, member, open_for_reading
from .imus import read_imus


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
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise SessionError(f"{src}: damaged HDF5 file ({one_line(exc)})") from None
    except MemoryError:
        raise SessionError(f"{src}: too large to read into memory") from None
    finally:
        file.close()
    session.path = path
    return session


def _read_open_file(file: h5py.File, src: str, unclosed: bool) -> Session:
    created, text, numbers = _root_attributes(file, src)
    raw = _read_raw(file, src, unclosed)
    segments = _read_segments(file, src, len(raw["time"]), raw["accel"], raw["gyro"], unclosed)
    reference_name, imus = read_imus(file, src, unclosed)  # several IMUs (issue 28)
    return Session(
        **raw,
        segments=segments,
        created=created,
        sensor=text["sensor"],
        source=text["source"],
        sample_rate_hz=numbers["sample_rate_hz"],
        gravity=GRAVITY_DEFAULT if numbers["gravity"] is None else numbers["gravity"],
        accel_units=text["accel_units"],
        gyro_units=text["gyro_units"],
        calibrations=_read_calibrations(file, src),
        mag_units=text["mag_units"],
        magnetic_field_uT=numbers["magnetic_field_uT"],
        imus=imus,
        reference_name=reference_name,
    )


def _root_attributes(file: h5py.File, src: str) -> tuple[str, dict, dict]:
    """The root attributes, checked: ``created``, the texts (cleaned) and the numbers."""
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
    created = None if created is None else clean_text(created)
    if created is None:
        problem = "is missing" if root["created"] is None else "is not a string"
        raise SessionError(f"{src}: root attribute 'created' {problem}")
    text = {}
    for name in ("sensor", "source", "accel_units", "gyro_units", "mag_units"):
        text[name] = None if root[name] is None else as_str(root[name])
        if text[name] is not None:
            text[name] = clean_text(text[name])
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
    field = numbers["magnetic_field_uT"]
    if field is not None and not field <= MAX_FIELD_UT:  # 1e300: numpy's overflow in the solver
        raise SessionError(f"{src}: root attribute 'magnetic_field_uT' is {field:.6g} uT; a "
                           f"local field is at most {MAX_FIELD_UT:.0f} uT (the Earth's: 25 to "
                           "65)")  # fmt: skip
    g = numbers["gravity"]
    lo, hi = GRAVITY_RANGE
    if g is not None and not lo < g < hi:  # 1e308 broke the solvers' SVD (issue 26)
        raise SessionError(f"{src}: root attribute 'gravity' is {g:.6g} m/s^2; local gravity "
                           f"is between {lo:g} and {hi:g} m/s^2 (9.80665 standard)")  # fmt: skip

    return created, text, numbers


#: The ``/raw`` datasets read, each with its shape: 0 for one value per sample ``(N,)``, k for
#: ``(N, >=k)`` channels.  A channel added to the format (and a :class:`Session` field of the
#: same name) is one entry here: every check and read below is generic.
RAW_CHANNELS: dict[str, int] = {"time": 0, "accel": 3, "gyro": 3, "temperature": 0, "mag": 3,
                                "host_time": 0}  # fmt: skip
#: Extras the toolkit can do without: left out (not refused) when their shape is wrong.
OPTIONAL_RAW = ("host_time",)
RAW_NAMES = tuple(RAW_CHANNELS)


def raw_datasets(file: h5py.File, src: str, unclosed: bool) -> tuple[dict[str, h5py.Dataset], int]:
    """:func:`_raw_datasets`, a read that fails (a chunk whose Fletcher-32 checksum does not
    match, a damaged B-tree) given as the one-line "damaged HDF5 file" every command says."""
    try:
        return _raw_datasets(file, src, unclosed)
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise SessionError(f"{src}: damaged HDF5 file ({one_line(exc)})") from None


def _raw_datasets(file: h5py.File, src: str, unclosed: bool) -> tuple[dict[str, h5py.Dataset], int]:
    """Validate the ``/raw`` datasets present (of :data:`RAW_NAMES`); return them and the
    number of samples N to read.

    Shapes are checked (:data:`RAW_CHANNELS`), and each dataset with
    :func:`~.h5open.check_dataset` (no links, no external or virtual data, size bounded by the
    file's).  For a file whose writer did not close it, N is the shortest dataset (an
    interrupted flush may have grown some and not others).
    """
    raw = member(file, "raw", src)
    if raw is not None and not isinstance(raw, h5py.Group):
        raise SessionError(f"{src}: /raw is not a group")
    limit = file_size(file)
    datasets: dict[str, h5py.Dataset] = {}
    for name in RAW_NAMES:
        obj = None if raw is None else member(raw, name, src)
        if obj is None:
            continue
        if not isinstance(obj, h5py.Dataset):
            raise SessionError(f"{src}: /raw/{name} is not a dataset")
        if obj.dtype.kind not in "iuf":
            raise SessionError(f"{src}: /raw/{name} is not numeric (dtype {obj.dtype})")
        check_dataset(obj, src, limit=limit, complete=not unclosed)
        datasets[name] = obj
    if "time" not in datasets:
        raise SessionError(f"{src}: /raw/time is missing")
    if datasets["time"].ndim != 1:
        raise SessionError(f"{src}: /raw/time must be 1-D, has shape {datasets['time'].shape}")
    n = datasets["time"].shape[0]
    for name in OPTIONAL_RAW:
        ds = datasets.get(name)
        n_time = datasets["time"].shape[0]
        if ds is not None and (ds.ndim != 1 or ds.shape[0] < n_time
                               or (ds.shape[0] != n_time and not unclosed)):  # fmt: skip
            del datasets[name]
    if unclosed:
        n = min(ds.shape[0] for ds in datasets.values() if ds.ndim >= 1)
    for name, ds in datasets.items():
        _check_shape(name, ds, n, RAW_CHANNELS[name], src, unclosed)
    kept = written_length(datasets["time"], n)
    if kept < n:
        warnings.warn(
            f"{src}: the last {n - kept} of {n} samples were never written (the capture "
            f"stopped: disk full or killed); reading the first {kept}",
            ImucalWarning,
            stacklevel=3,
        )
    return datasets, kept


def check_time(time: np.ndarray, src: str, first: int = 0, before: float | None = None) -> None:
    """Raise SessionError unless ``time`` (samples ``first`` on, after ``before`` s) is finite
    and strictly increasing."""
    bad = np.flatnonzero(~np.isfinite(time))
    if bad.size:
        raise SessionError(f"{src}: /raw/time is {time[bad[0]]} at sample {first + bad[0]}")
    previous = time if before is None else np.concatenate(([before], time))
    bad = np.flatnonzero(np.diff(previous) <= 0)
    if bad.size:
        i = int(bad[0])
        sample = first + i + (0 if before is None else -1) + 1
        raise SessionError(
            f"{src}: /raw/time is not strictly increasing (sample {sample}: "
            f"{float(previous[i + 1])!r} s after {float(previous[i])!r} s)"
        )


def written_length(dataset: h5py.Dataset, n: int) -> int:
    """Rows of a 1-D dataset before its trailing run of NaN fill values: rows the writer grew
    but never wrote (it writes ``/raw/time`` last, so these samples are incomplete).  Only for
    datasets whose fill value is NaN (what :class:`~.writer.SessionWriter` sets); a binary
    search, so a few small reads."""
    try:
        fill = float(dataset.fillvalue)
    except (TypeError, ValueError):
        return n
    if n == 0 or not np.isnan(fill) or not np.isnan(dataset[n - 1]):
        return n
    lo, hi = 0, n - 1  # dataset[hi] is NaN
    while lo < hi:
        mid = (lo + hi) // 2
        if np.isnan(dataset[mid]):
            hi = mid
        else:
            lo = mid + 1
    return lo


def _check_shape(name: str, ds: h5py.Dataset, n: int, width: int, src: str,
                 unclosed: bool) -> None:  # fmt: skip
    """``(n,)`` (``width`` 0) or ``(n, >=width)``; a file left open may hold more rows."""
    if width == 0:
        if ds.shape != (n,) and (not unclosed or ds.ndim != 1 or ds.shape[0] < n):
            raise SessionError(f"{src}: /raw/{name} must have shape ({n},), has shape {ds.shape}")
        return
    if ds.ndim != 2 or ds.shape[0] < n or ds.shape[1] < width:
        raise SessionError(
            f"{src}: /raw/{name} must have shape (N, >={width}) with N = {n} samples, "
            f"has shape {ds.shape}"
        )
    if not unclosed and ds.shape[0] != n:
        raise SessionError(f"{src}: /raw/{name} has {ds.shape[0]} rows, /raw/time has {n}")


def _read_raw(file: h5py.File, src: str, unclosed: bool) -> dict[str, np.ndarray | None]:
    """Every channel of :data:`RAW_CHANNELS` (None where absent), validated, as float64."""
    datasets, n = raw_datasets(file, src, unclosed)
    raw = {name: None if name not in datasets else
           np.asarray(datasets[name][:n], dtype=np.float64) for name in RAW_CHANNELS}  # fmt: skip
    check_time(raw["time"], src)
    check_rate(raw["time"], src)
    for name, values in raw.items():
        check_readings(name, values, src)
    return raw


def _read_segments(
    file: h5py.File,
    src: str,
    n: int,
    accel: np.ndarray | None,
    gyro: np.ndarray | None,
    unclosed: bool,
) -> list[Segment]:
    segments = []
    group = member(file, "segments", src)
    if isinstance(group, h5py.Group):
        for name in group:
            obj = member(group, name, src)
            if isinstance(obj, h5py.Group):
                where = f"/segments/{name}"
                attr = partial(get_attr, obj.attrs, src=src, where=f"{where}: ")
                segment = _parse_segment(name, attr, src, where, n, accel, gyro)
                extra = ((key, attr(key)) for key in obj.attrs if key not in SEGMENT_ATTRS)
                segment.extra.update(_extra_attrs(extra))
                segments.append(segment)
    log_group = member(file, LOG_GROUP, src)
    log = member(log_group, "segments", src) if isinstance(log_group, h5py.Group) else None
    if not segments and isinstance(log, h5py.Dataset):
        # The writer was killed before it wrote the segment groups (or the disk was full):
        # use its SWMR-safe log.  A row whose chunk was never written reads as empty bytes
        # and is skipped below, so the log is never refused for it.
        check_dataset(log, src, limit=file_size(file), complete=False)
        if log.dtype.kind != "S" or log.ndim != 1:
            raise SessionError(f"{src}: /{LOG_DATASET} is not a list of JSON strings")
        for row, item in enumerate(log[()]):
            where = f"/{LOG_DATASET}[{row}]"
            if not bytes(item).strip(b"\0"):
                continue  # a row grown but never written (the flush failed)
            try:
                entry = json.loads(bytes(item).decode("utf-8"))
            except (UnicodeDecodeError, ValueError, RecursionError):
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
        extra[clean_text(str(key))] = clean_tree(value)
    return extra


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
    label = None if label is None else clean_text(as_str(label))

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
            angle_deg = as_turn_angle(raw_angle)
            if angle_deg is None:
                raise fail(f"'angle_deg' must be {TURN_ANGLE_RULE}, got {show(raw_angle)}")
        data, dataset = gyro, "/raw/gyro"
    if data is None:
        raise fail(f"{kind} segment but the file has no {dataset}")
    bad = first_nonfinite_row(data, start, stop)
    if bad is not None:
        raise fail(f"{dataset} has NaN or inf at sample {bad}, inside the segment"
                   + _dead_columns(data, start, stop))  # fmt: skip
    return Segment(name, kind, start, stop, label, up, axis, angle_deg)


CHECK_ROWS = 1 << 16
"""Rows read at a time where a check of a long range of an HDF5 dataset must not read it all."""


def _dead_columns(data, start: int, stop: int) -> str:
    """Words for the columns NaN or inf in every sample of ``[start, stop)`` (a dead or unread
    axis: the sketch printed nan for it), or ''."""
    rows = np.asarray(data[start:stop])
    if rows.ndim != 2:
        return ""
    dead = np.flatnonzero(~np.isfinite(rows).any(axis=0))
    if not dead.size:
        return ""
    names = ", ".join("xyz"[c] if rows.shape[1] == 3 else f"channel {c + 1}" for c in dead)
    return (f": axis {names} is NaN or inf in every sample of it (a dead or unread axis, or "
            "a sketch printing nan for it)")


def first_nonfinite_row(data, start: int, stop: int) -> int | None:
    """The first row in ``[start, stop)`` of ``data`` (an array, or an HDF5 dataset read
    :data:`CHECK_ROWS` rows at a time) holding NaN or inf, or None."""
    step = stop - start if isinstance(data, np.ndarray) else CHECK_ROWS
    for a in range(start, stop, max(step, 1)):
        rows = np.asarray(data[a : min(a + step, stop)])
        if not np.isfinite(rows).all():
            return a + int(np.flatnonzero(~np.isfinite(rows).all(axis=1))[0])
    return None


def _read_calibrations(file: h5py.File, src: str) -> dict[str, str]:
    calibrations = {}
    group = member(file, "calibrations", src)
    if isinstance(group, h5py.Group):
        for name in group:
            obj = member(group, name, src)
            if isinstance(obj, h5py.Group):
                text = as_str(get_attr(obj.attrs, "json", src, f"/calibrations/{name}: "))
                if text is not None:
                    calibrations[name] = text
    return calibrations
