"""Sessions with several IMUs (``shared/spec/session-format.md``, "Several IMUs"; issue 28).

``/raw`` holds the reference IMU; each other IMU has a group ``/imus/<name>`` with the same
datasets (``time``, ``accel``, ``gyro``, optional ``mag``, ``temperature``), its own sample
times on the reference's clock, never resampled; the group's attributes are the per-IMU ones of
the root (``sensor``, ``accel_units``, ``gyro_units``, ``mag_units``, ``sample_rate_hz``); the
root attribute ``imus`` lists every name, the reference's first.

- :func:`read_imus`: the groups of an open file, validated like ``/raw`` (shapes, finite and
  strictly increasing time, no links or external data, sizes bounded by the file's).
- :func:`imu_session`: one IMU of a set as a session of its own (the reference's segments
  mapped to its samples by time, as the spec says), so that every single-IMU step (the
  solvers, ``apply``, ``noise``) works on it unchanged.
- :func:`set_names`: every IMU's name, the reference's first.
- :func:`imu_group`: one IMU's group checked, to read block by block (``imucal noise --imu``,
  :func:`~.stream.open_samples`); :func:`listed_names`: the names an open file lists.
"""

from __future__ import annotations

from dataclasses import replace

import h5py
import numpy as np

from imucal_cli.errors import SessionError
from imucal_cli.formats.text import clean_text
from imucal_cli.model.imu_stream import IMU_CHANNELS, IMU_TEXT_ATTRS, REFERENCE_NAME, ImuStream
from imucal_cli.model.session import (
    MAG_UNITS,
    Segment,
    Session,
    as_float,
    as_str,
    check_rate,
    check_readings,
    show,
)

from .h5open import check_dataset, file_size, get_attr, member

__all__ = ["imu_group", "imu_session", "imu_names_attr", "listed_imus", "listed_names",
           "map_segments", "read_imus", "set_names"]

MAX_IMUS = 256
"""The most IMUs one session may hold (an IMU array has 4 to 32)."""


def set_names(session: Session) -> list[str]:
    """Every IMU's name, the reference's first (one name for a single IMU)."""
    return [session.reference_name, *session.imus]


def imu_names_attr(names: list[str], src: str) -> list[str]:
    """``names`` checked as the root attribute ``imus`` (unique, non-empty, no ``/``, at most
    :data:`MAX_IMUS`)."""
    if not names:
        raise SessionError(f"{src}: root attribute 'imus' is empty (it lists every IMU's name, "
                           "the reference's first)")  # fmt: skip
    if len(names) > MAX_IMUS:
        raise SessionError(f"{src}: {len(names)} IMUs; at most {MAX_IMUS}")
    for name in names:
        if not name or "/" in name or name in (".", ".."):
            raise SessionError(f"{src}: root attribute 'imus' holds {name!r}, not a group name")
    if len(set(names)) != len(names):
        twice = next(n for n in names if names.count(n) > 1)
        raise SessionError(f"{src}: root attribute 'imus' names {twice!r} twice")
    return names


def _names(value, src: str) -> list[str]:
    """The root attribute ``imus`` as a list of clean strings."""
    items = np.atleast_1d(np.asarray(value, dtype=object)).ravel().tolist()
    names = []
    for item in items:
        text = as_str(item)
        if text is None:
            raise SessionError(f"{src}: root attribute 'imus' must be a list of names, got "
                               f"{show(value)}")  # fmt: skip
        names.append(clean_text(text))
    return imu_names_attr(names, src)


def listed_imus(file: h5py.File, src: str) -> list[str] | None:
    """The root attribute ``imus`` (None: absent, one IMU), checked to name every member of
    ``/imus``: the spec's "The root attribute ``imus`` lists every IMU's name, the reference's
    first".  Every reader of a session calls it (:func:`read_imus` for
    :func:`~.reader.read_session`: ``calibrate``, ``report``, ``label``; and
    :func:`listed_names` for :func:`~.stream.open_samples`: ``noise``, ``apply``), so that
    none reads a set the file itself contradicts, whether it reads the other IMUs or ``/raw``
    alone.

    Raises
    ------
    SessionError
        A member of ``/imus`` the attribute does not list (or no attribute while ``/imus``
        holds members): one line naming them.
    """
    value = get_attr(file.attrs, "imus", src, "root ")
    names = None if value is None else _names(value, src)
    group = member(file, "imus", src)
    others = names[1:] if names else []  # the reference is /raw, never a group of /imus
    unlisted = [n for n in group if n not in others] if isinstance(group, h5py.Group) else []
    if unlisted:
        said = "has no root attribute 'imus'" if names is None else \
            f"lists only {', '.join(names)} in its root attribute 'imus'"  # fmt: skip
        raise SessionError(
            f"{src}: /imus holds {', '.join(clean_text(n) for n in unlisted[:8])}"
            f"{' ...' if len(unlisted) > 8 else ''} but the file {said}, which lists every "
            "IMU of a set: list them there, or delete their groups"
        )
    return names


def read_imus(file: h5py.File, src: str, unclosed: bool) -> tuple[str, dict[str, ImuStream]]:
    """The reference's name and the other IMUs of an open session file.

    A file without the root attribute ``imus`` holds one IMU; one whose ``/imus`` holds a
    group the attribute does not list is refused (:func:`listed_imus`).  A file left open by
    its writer (a killed capture) is read up to each group's shortest dataset and last written
    time.

    Raises
    ------
    SessionError
        A listed IMU without its group, a group not listed, a dataset of the wrong shape or
        type, time that is not finite and strictly increasing, links or data outside the file.
    """
    names = listed_imus(file, src)
    if names is None:
        return REFERENCE_NAME, {}
    group = member(file, "imus", src)
    if len(names) > 1 and not isinstance(group, h5py.Group):
        raise SessionError(f"{src}: root attribute 'imus' lists {', '.join(names[1:])} but the "
                           "file has no /imus group")  # fmt: skip
    limit = file_size(file)
    imus = {}
    for name in names[1:]:
        obj = member(group, name, src)
        if not isinstance(obj, h5py.Group):
            raise SessionError(f"{src}: /imus/{name} is missing (the root attribute 'imus' "
                               "lists it)" if obj is None else f"{src}: /imus/{name} is not a "
                               "group")  # fmt: skip
        imus[name] = _read_group(obj, f"/imus/{name}", src, limit, unclosed)
    return names[0], imus


def _group_datasets(group: h5py.Group, where: str, src: str, limit: int,
                    unclosed: bool) -> tuple[dict[str, h5py.Dataset], int]:  # fmt: skip
    """The datasets of an ``/imus/<name>`` group, their shapes checked (none read), and the
    number of samples to read (a file left open by its writer: its shortest dataset)."""
    datasets = {}
    for name in IMU_CHANNELS:
        obj = member(group, name, src)
        if obj is None:
            continue
        if not isinstance(obj, h5py.Dataset):
            raise SessionError(f"{src}: {where}/{name} is not a dataset")
        if obj.dtype.kind not in "iuf":
            raise SessionError(f"{src}: {where}/{name} is not numeric (dtype {obj.dtype})")
        check_dataset(obj, src, limit=limit, complete=not unclosed)
        datasets[name] = obj
    if "time" not in datasets:
        raise SessionError(f"{src}: {where}/time is missing")
    if datasets["time"].ndim != 1:
        raise SessionError(f"{src}: {where}/time must be 1-D, has shape {datasets['time'].shape}")
    n = datasets["time"].shape[0]
    if unclosed:
        n = min(ds.shape[0] for ds in datasets.values() if ds.ndim >= 1)
    for name, ds in datasets.items():
        width = IMU_CHANNELS[name]
        ok = ds.ndim == 1 if width == 0 else ds.ndim == 2 and ds.shape[1] >= width
        if not ok or ds.shape[0] < n or (ds.shape[0] != n and not unclosed):
            want = f"({n},)" if width == 0 else f"({n}, >={width})"
            raise SessionError(f"{src}: {where}/{name} must have shape {want}, has shape "
                               f"{ds.shape}")  # fmt: skip
    return datasets, n


def _written(time: np.ndarray, unclosed: bool) -> int:
    """Samples written: all, or in a file left open by its writer up to the last finite time
    (rows grown but never written read as the NaN fill value)."""
    if not unclosed:
        return len(time)
    written = np.flatnonzero(np.isfinite(time))
    return int(written[-1]) + 1 if written.size else 0


def _read_group(group: h5py.Group, where: str, src: str, limit: int,
                unclosed: bool) -> ImuStream:  # fmt: skip
    datasets, n = _group_datasets(group, where, src, limit, unclosed)
    arrays = {name: np.asarray(ds[:n], dtype=np.float64) for name, ds in datasets.items()}
    n = _written(arrays["time"], unclosed)
    arrays = {k: v[:n] for k, v in arrays.items()}
    _check_time(arrays["time"], src, where)
    check_rate(arrays["time"], src, where)
    for name, values in arrays.items():
        check_readings(name, values, src, where=where)
    return ImuStream(**arrays, **_group_attrs(group, where, src))


def listed_names(file: h5py.File, src: str) -> list[str]:
    """Every IMU's name in an open session file, the reference's first (the root attribute
    ``imus``, checked by :func:`listed_imus`; ``[reference]`` for a file of one IMU)."""
    names = listed_imus(file, src)
    return [REFERENCE_NAME] if names is None else names


def imu_group(file: h5py.File, src: str, name: str,
              unclosed: bool) -> tuple[dict[str, h5py.Dataset], np.ndarray, dict]:  # fmt: skip
    """IMU ``name``'s group ``/imus/<name>`` of an open file, to read block by block
    (``imucal noise --imu``): its datasets, checked as :func:`read_imus` checks them and not
    read; its time, read (8 bytes a sample) and checked (finite, strictly increasing; a file
    left open by its writer up to the last time written); its attributes.

    Raises
    ------
    SessionError
        No such group, or a group :func:`read_imus` refuses.
    """
    where = f"/imus/{name}"
    group = member(file, "imus", src)
    obj = member(group, name, src) if isinstance(group, h5py.Group) else None
    if not isinstance(obj, h5py.Group):
        raise SessionError(f"{src}: {where} is missing (the root attribute 'imus' lists it)")
    datasets, n = _group_datasets(obj, where, src, file_size(file), unclosed)
    time = np.asarray(datasets["time"][:n], dtype=np.float64)
    time = time[: _written(time, unclosed)]
    _check_time(time, src, where)
    return datasets, time, _group_attrs(obj, where, src)


def _check_time(time: np.ndarray, src: str, where: str) -> None:
    bad = np.flatnonzero(~np.isfinite(time))
    if bad.size:
        raise SessionError(f"{src}: {where}/time is {time[bad[0]]} at sample {bad[0]}")
    bad = np.flatnonzero(np.diff(time) <= 0)
    if bad.size:
        i = int(bad[0])
        raise SessionError(f"{src}: {where}/time is not strictly increasing (sample {i + 1}: "
                           f"{float(time[i + 1])!r} s after {float(time[i])!r} s)")  # fmt: skip


def _group_attrs(group: h5py.Group, where: str, src: str) -> dict:
    out: dict = {}
    for name in IMU_TEXT_ATTRS:
        value = get_attr(group.attrs, name, src, f"{where}: ")
        if value is None:
            continue
        text = as_str(value)
        if text is None:
            raise SessionError(f"{src}: {where}: attribute {name!r} is not a string")
        out[name] = clean_text(text)
    if out.get("mag_units") is not None and out["mag_units"] not in MAG_UNITS:
        raise SessionError(f"{src}: {where}: attribute 'mag_units' is {out['mag_units']!r}, "
                           f"expected one of {', '.join(MAG_UNITS)}")  # fmt: skip
    rate = get_attr(group.attrs, "sample_rate_hz", src, f"{where}: ")
    if rate is not None:
        number = as_float(rate)
        if number is None or number <= 0:
            raise SessionError(f"{src}: {where}: attribute 'sample_rate_hz' must be a positive "
                               f"number, got {show(rate)}")  # fmt: skip
        out["sample_rate_hz"] = number
    return out


# --------------------------------------------------------------------------------------------
# One IMU of a set as a session of its own
# --------------------------------------------------------------------------------------------


def map_segments(segments: list[Segment], ref_time: np.ndarray, time: np.ndarray,
                 offset_s: float = 0.0) -> list[Segment]:  # fmt: skip
    """The reference's segments as sample ranges of another IMU (spec: an IMU belongs to a
    segment for the samples whose time falls within the reference's ``[time[start],
    time[stop-1]]``).

    Parameters
    ----------
    segments : list of Segment
        The reference's, indexing ``ref_time``.
    ref_time, time : ndarray
        The reference's sample times and the IMU's, s.
    offset_s : float
        Added to the IMU's times first (its time offset to the reference, when known).

    Returns
    -------
    list of Segment
        The same names, kinds and labels; a segment left with fewer than 2 samples of the IMU
        is left out.
    """
    t = np.asarray(time, float) + offset_s
    out = []
    for seg in segments:
        lo, hi = ref_time[seg.start], ref_time[seg.stop - 1]
        start = int(np.searchsorted(t, lo, side="left"))
        stop = int(np.searchsorted(t, hi, side="right"))
        if stop - start >= 2:
            out.append(replace(seg, start=start, stop=stop, extra=dict(seg.extra)))
    return out


def imu_session(session: Session, name: str, offset_s: float = 0.0,
                segments: list[Segment] | None = None) -> Session:  # fmt: skip
    """IMU ``name`` of a set as a single-IMU :class:`Session` (the reference's own name gives
    the session without its other IMUs).

    ``segments``: the reference's (default its own; a session segmented at calibration
    passes those); they are mapped to the IMU's samples by time (:func:`map_segments`, its
    times plus ``offset_s``).  Root attributes the IMU does not set (gravity, the field, the
    creation time) are the session's.
    """
    segments = session.segments if segments is None else segments
    if name == session.reference_name:
        return replace(session, imus={}, segments=list(segments))
    if name not in session.imus:
        raise SessionError(f"{session.path or 'session'}: no IMU {name!r} (IMUs: "
                           f"{', '.join(set_names(session))})")  # fmt: skip
    imu = session.imus[name]
    return Session(
        time=imu.time, accel=imu.accel, gyro=imu.gyro, temperature=imu.temperature,
        segments=map_segments(segments, session.time, imu.time, offset_s),
        created=session.created, sensor=imu.sensor, source=session.source,
        sample_rate_hz=imu.sample_rate_hz, gravity=session.gravity,
        accel_units=imu.accel_units, gyro_units=imu.gyro_units, path=session.path,
        mag=imu.mag, mag_units=imu.mag_units, magnetic_field_uT=session.magnetic_field_uT,
        reference_name=name,
    )  # fmt: skip
