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

import numpy as np

from imucal_cli.errors import SessionError
from imucal_cli.formats.session.h5open import open_for_reading
from imucal_cli.formats.session.reader import (
    _read_segments,
    _root_attributes,
    check_time,
    raw_datasets,
)
from imucal_cli.model.session import GRAVITY_DEFAULT, Segment, Session, one_line

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
    def __init__(self, path: Path) -> None:
        src = str(path)
        file, unclosed = open_for_reading(path, src)
        try:
            _, text, numbers = _root_attributes(file, src)
            datasets, n = raw_datasets(file, src, unclosed)
            self.segments = _read_segments(file, src, n, datasets.get("accel"),
                                           datasets.get("gyro"), unclosed)  # fmt: skip
        except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
            file.close()
            raise SessionError(f"{src}: damaged HDF5 file ({one_line(exc)})") from None
        except BaseException:
            file.close()
            raise
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

    def _read_into(self, out: np.ndarray, name: str, start: int, stop: int) -> np.ndarray:
        out = out[: stop - start]
        try:
            self.datasets[name].read_direct(out, np.s_[start:stop], np.s_[0 : stop - start])
        except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
            raise SessionError(f"{self.src}: damaged HDF5 file ({one_line(exc)})") from None
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


def samples_of(session: Session) -> SessionSamples:
    """A session already in memory, read as blocks (no copy)."""
    return _InMemory(session)


def open_samples(path: str | os.PathLike) -> SessionSamples:
    """Open a session file to read block by block (close it, or use it in ``with``).

    Raises
    ------
    SessionError
        As :func:`~.reader.read_session`: missing, not a session, damaged.
    """
    path = Path(path)
    try:
        return _File(path)
    except MemoryError:
        raise SessionError(f"{path}: too large to read") from None

