"""A session read block by block: its attributes and segments as :func:`~.reader.read_session`
gives them, its ``/raw`` channels a block at a time, so that a day-long recording is analysed
in constant memory (``imucal noise``; issue 14).

:func:`open_samples` opens a file (the same checks as :func:`~.reader.read_session`, except that
``/raw/time`` is checked as it is read: :meth:`SessionSamples.blocks` and
:meth:`SessionSamples.check_time`); :func:`samples_of` wraps a :class:`~.model.Session` already
in memory, so one analysis serves both.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import h5py
import numpy as np

from imucal_cli.errors import SessionError
from imucal_cli.formats.session.h5open import open_for_reading
from imucal_cli.formats.session.reader import (
    _read_segments,
    _root_attributes,
    check_time,
    raw_datasets,
)
from imucal_cli.model.imu_stream import IMU_TEXT_ATTRS, REFERENCE_NAME
from imucal_cli.model.session import (
    GRAVITY_DEFAULT,
    Segment,
    Session,
    check_rate,
    check_readings,
    one_line,
)

from .imus import imu_group, listed_names, map_segments, set_names

__all__ = ["BLOCK_ROWS", "SessionSamples", "open_samples", "samples_of"]

BLOCK_ROWS = 1 << 16
"""Samples per block: numpy's loops stay in the processor's cache (a few hundred kB)."""


class SessionSamples:
    """A session's attributes and segments, and its ``/raw`` channels read on demand.

    Attributes
    ----------
    path : Path or None
    n : int
        Samples.
    segments : list of Segment
    sensor, accel_units, gyro_units, mag_units : str or None
    gravity : float
    channels : dict of str to int
        The ``/raw`` channels present (``time``, ``accel``, ``gyro``, ...), each with its
        number of columns (0 for one value per sample).
    imus : list of str
        Every IMU's name in the session, the reference's first (one name for one IMU).
    imu : str or None
        The IMU whose channels these are when the session holds several (``/raw`` for the
        reference, ``/imus/<name>`` for another; its segments the reference's, mapped by
        time); None for a session of one IMU.
    """

    path: Path | None
    n: int
    segments: list[Segment]
    sensor: str | None
    accel_units: str | None
    gyro_units: str | None
    mag_units: str | None
    gravity: float
    channels: dict[str, int]
    imus: list[str]
    imu: str | None

    def units(self, name: str) -> str | None:
        """The raw units of channel ``accel``, ``gyro`` or ``mag`` (None: not stated)."""
        return {"accel": self.accel_units, "gyro": self.gyro_units,
                "mag": self.mag_units}.get(name)  # fmt: skip

    def read(self, name: str, start: int, stop: int) -> np.ndarray:
        """Samples ``[start, stop)`` of channel ``name`` as float64."""
        raise NotImplementedError

    def blocks(
        self, names: tuple[str, ...], start: int, stop: int, rows: int = BLOCK_ROWS
    ) -> Iterator[tuple[np.ndarray, ...]]:
        """The channels ``names`` over ``[start, stop)``, ``rows`` samples at a time (float64;
        an array is valid until the next block).  ``time`` is checked as it is read (finite,
        strictly increasing)."""
        raise NotImplementedError

    def check_time(self, start: int, stop: int) -> None:
        """Raise :class:`SessionError` unless ``/raw/time`` is finite and strictly increasing
        over ``[start, stop)``."""

    def close(self) -> None:
        """Release the file, if any."""

    def __enter__(self) -> SessionSamples:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _InMemory(SessionSamples):
    def __init__(self, session: Session) -> None:
        self.session = session
        self.path = session.path
        self.n = len(session.time)
        self.segments = session.segments
        self.sensor = session.sensor
        self.accel_units = session.accel_units
        self.gyro_units = session.gyro_units
        self.mag_units = session.mag_units
        self.gravity = session.gravity
        self.imus = set_names(session)
        self.imu = session.reference_name if session.imus else None
        self.channels = {}
        for name in ("time", "accel", "gyro", "mag", "temperature"):
            value = getattr(session, name, None)
            if value is not None:
                self.channels[name] = 0 if np.ndim(value) == 1 else np.shape(value)[1]

    def read(self, name: str, start: int, stop: int) -> np.ndarray:
        return np.asarray(getattr(self.session, name)[start:stop], dtype=np.float64)

    def blocks(self, names, start, stop, rows=BLOCK_ROWS):
        arrays = [np.asarray(getattr(self.session, name), dtype=np.float64) for name in names]
        for a in range(start, stop, rows):
            yield tuple(x[a : min(a + rows, stop)] for x in arrays)


class _File(SessionSamples):
    def __init__(self, path: Path, imu: str | None = None) -> None:
        src = str(path)
        file, unclosed = open_for_reading(path, src)
        try:
            _, text, numbers = _root_attributes(file, src)
            datasets, n = raw_datasets(file, src, unclosed)
            self.segments = _read_segments(file, src, n, datasets.get("accel"),
                                           datasets.get("gyro"), unclosed)  # fmt: skip
            self.imus = listed_names(file, src)
            name = _chosen(self.imus, imu, src)
            if name != self.imus[0]:  # another IMU of the set: /imus/<name>
                datasets, time, attrs = imu_group(file, src, name, unclosed)
                self.segments = map_segments(self.segments, _raw_time(file), time)
                n = len(time)
                text = {**text, **{k: attrs.get(k) for k in IMU_TEXT_ATTRS}}
        except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
            file.close()
            raise SessionError(f"{src}: damaged HDF5 file ({one_line(exc)})") from None
        except BaseException:
            file.close()
            raise
        self.imu = name if len(self.imus) > 1 else None
        self.where = "/raw" if name == self.imus[0] else f"/imus/{name}"
        self.file = file
        self.src = src
        self.datasets = datasets
        self.path = path
        self.n = n
        self.sensor = text["sensor"]
        self.accel_units = text["accel_units"]
        self.gyro_units = text["gyro_units"]
        self.mag_units = text["mag_units"]
        self.gravity = GRAVITY_DEFAULT if numbers["gravity"] is None else numbers["gravity"]
        self.channels = {name: 0 if ds.ndim == 1 else ds.shape[1]
                         for name, ds in datasets.items()}  # fmt: skip
        try:
            check_rate(self.read("time", 0, min(n, BLOCK_ROWS)), src, self.where)
        except BaseException:
            file.close()
            raise

    def _read_into(self, out: np.ndarray, name: str, start: int, stop: int) -> np.ndarray:
        out = out[: stop - start]
        try:
            self.datasets[name].read_direct(out, np.s_[start:stop], np.s_[0 : stop - start])
        except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
            raise SessionError(f"{self.src}: damaged HDF5 file ({one_line(exc)})") from None
        check_readings(name, out, self.src, start, self.where)
        return out

    def _buffer(self, name: str, rows: int) -> np.ndarray:
        width = self.channels[name]
        return np.empty((rows,) if width == 0 else (rows, width))

    def read(self, name: str, start: int, stop: int) -> np.ndarray:
        return self._read_into(self._buffer(name, stop - start), name, start, stop).copy()

    def blocks(self, names, start, stop, rows=BLOCK_ROWS):
        buffers = [self._buffer(name, min(rows, max(stop - start, 1))) for name in names]
        last = None
        if "time" in names and 0 < start < stop:  # the order across the range's start
            last = float(self._read_into(np.empty(1), "time", start - 1, start)[0])
        for a in range(start, stop, rows):
            b = min(a + rows, stop)
            block = tuple(self._read_into(buf, name, a, b)
                          for buf, name in zip(buffers, names, strict=True))  # fmt: skip
            if "time" in names:
                t = block[names.index("time")]
                check_time(t, self.src, first=a, before=last)
                last = float(t[-1])
            yield block

    def check_time(self, start: int, stop: int) -> None:
        for _ in self.blocks(("time",), start, stop):
            pass

    def close(self) -> None:
        self.file.close()


def _raw_time(file) -> h5py.Dataset:
    """``/raw/time`` of an open file (indexed per segment bound, never read whole)."""
    return file["raw"]["time"]


def _chosen(names: list[str], imu: str | None, src: str) -> str:
    """The IMU to read: ``imu`` among ``names``, the reference (the first) by its name or as
    ``reference``, or by default.

    Raises
    ------
    SessionError
        A name the session does not hold (the names listed).
    """
    if imu is None or imu == names[0] or (imu == REFERENCE_NAME and imu not in names):
        return names[0]
    if imu not in names:
        raise SessionError(f"{src}: no IMU {imu!r} (IMUs: {', '.join(names)})")
    return imu


def samples_of(session: Session) -> SessionSamples:
    """A session already in memory, read as blocks (no copy)."""
    return _InMemory(session)


def open_samples(path: str | os.PathLike, imu: str | None = None) -> SessionSamples:
    """Open a session file to read block by block (close it, or use it in ``with``).

    ``imu``: in a session of several IMUs, the IMU to read (its name; the reference also as
    ``reference``) [default: the reference, ``/raw``].  Another IMU's channels are read from
    ``/imus/<name>`` block by block as ``/raw``'s (its time whole, to map the reference's
    segments to its samples).

    Raises
    ------
    SessionError
        As :func:`~.reader.read_session`: missing, not a session, damaged; an IMU the session
        does not hold.
    """
    path = Path(path)
    try:
        return _File(path, imu)
    except MemoryError:
        raise SessionError(f"{path}: too large to read") from None

