"""The ``/imus/<name>`` datasets of a session with several IMUs, written beside ``/raw`` by
:class:`~.writer.SessionWriter` (issue 28; spec "Several IMUs").

The groups, their attributes and the root attribute ``imus`` are created with the file's layout
(HDF5 cannot create them once the file is in SWMR mode); the datasets are chunked, resizable,
Fletcher-32 checked and NaN-filled like ``/raw``'s, and written at each of the writer's flushes,
``time`` last.  Each IMU keeps its own sample times (never resampled): its blocks are checked
for finite, strictly increasing time on their own.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import h5py
import numpy as np

from imucal_cli.errors import InputError, SessionError
from imucal_cli.model.imu_stream import ImuStream

from .imus import imu_names_attr

__all__ = ["ImuDatasets", "ImuLayout"]


@dataclass(frozen=True)
class ImuLayout:
    """What one IMU of a set records: channels per sensor (None: no such sensor), whether it
    records a temperature, and its group's attributes (``sensor``, units, ``sample_rate_hz``)."""

    accel: int | None = 3
    gyro: int | None = 3
    mag: int | None = None
    temperature: bool = False
    attrs: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def of(cls, stream: ImuStream) -> ImuLayout:
        """The layout of a complete stream."""
        def width(a):
            return None if a is None else int(np.shape(a)[1])

        return cls(width(stream.accel), width(stream.gyro), width(stream.mag),
                   stream.temperature is not None, stream.attrs())  # fmt: skip

    def shapes(self) -> dict[str, int]:
        """``{dataset: width}`` (0: one value per sample) of the datasets recorded, time last."""
        out = {k: w for k, w in (("accel", self.accel), ("gyro", self.gyro), ("mag", self.mag))
               if w is not None}  # fmt: skip
        if self.temperature:
            out["temperature"] = 0
        out["time"] = 0
        return out


class ImuDatasets:
    """The other IMUs' datasets of an open session file, with their samples not yet written.

    Parameters
    ----------
    file : h5py.File
        The session, before SWMR mode (groups and attributes are created here).
    layouts : dict of str to ImuLayout
        The other IMUs, in order.
    reference : str
        The name of the IMU in ``/raw``.
    chunk_rows : int
        Rows per chunk (the writer's, shrunk on a nearly full disk).
    src : str
        The file, for messages.
    """

    def __init__(self, file: h5py.File, layouts: dict[str, ImuLayout], reference: str,
                 chunk_rows: int, src: str) -> None:  # fmt: skip
        self._src = src
        names = imu_names_attr([reference, *layouts], src)
        file.attrs["imus"] = np.array(names, dtype=h5py.string_dtype())
        root = file.create_group("imus")
        self.datasets: dict[str, dict[str, h5py.Dataset]] = {}
        self.layouts = dict(layouts)
        for name, layout in layouts.items():
            group = root.create_group(name)
            group.attrs.update(layout.attrs)
            self.datasets[name] = {}
            for ds_name, width in layout.shapes().items():
                tail = (width,) if width else ()
                self.datasets[name][ds_name] = group.create_dataset(
                    ds_name, shape=(0, *tail), maxshape=(None, *tail),
                    chunks=(chunk_rows, *tail), dtype="f8", fillvalue=np.nan, fletcher32=True,
                )  # fmt: skip
        self._pending: dict[str, list[dict[str, np.ndarray]]] = {n: [] for n in layouts}
        self.n_written = dict.fromkeys(layouts, 0)
        self._last_time: dict[str, float | None] = dict.fromkeys(layouts)
        self._last_written_time: dict[str, float | None] = dict.fromkeys(layouts)

    @classmethod
    def reopen(cls, file: h5py.File, imus: dict[str, ImuStream], layouts: dict[str, ImuLayout],
               src: str) -> ImuDatasets:  # fmt: skip
        """The ``/imus`` datasets of a session continued (``imucal capture --resume``), each
        IMU's cut to the ``imus[name]`` samples it holds whole (a killed writer may have
        written data beyond its last time); ``layouts``: what the resumed capture records,
        which must be what the session holds.

        Raises
        ------
        InputError
            The capture's IMUs (names, sensors, channels) are not the session's, or a
            dataset has a fixed size (not written by a capture).
        """
        held = {name: ImuLayout.of(stream) for name, stream in imus.items()}
        _check_same_imus(src, held, layouts)
        self = cls.__new__(cls)
        self._src, self.layouts, self.datasets = src, dict(layouts), {}
        for name, layout in layouts.items():
            n, group = len(imus[name].time), file["imus"][name]
            self.datasets[name] = {}
            for ds_name in layout.shapes():
                ds = group[ds_name]
                if ds.maxshape[0] is not None:
                    raise InputError(f"{src}: /imus/{name}/{ds_name} has a fixed size (the "
                                     "session was not written by imucal capture): it cannot "
                                     "be continued")  # fmt: skip
                if ds.shape[0] != n:
                    ds.resize(n, axis=0)
                self.datasets[name][ds_name] = ds
        self._pending = {n: [] for n in layouts}
        self.n_written = {name: len(imus[name].time) for name in layouts}
        self._last_time = {name: float(imus[name].time[-1]) if len(imus[name].time) else None
                           for name in layouts}  # fmt: skip
        self._last_written_time = dict(self._last_time)
        return self

    @property
    def n_pending(self) -> int:
        """Samples appended and not yet written, all IMUs."""
        return sum(len(b["time"]) for blocks in self._pending.values() for b in blocks)

    def counts(self) -> dict[str, int]:
        """Each IMU's samples appended so far, written or not."""
        return {name: n + sum(len(b["time"]) for b in self._pending[name])
                for name, n in self.n_written.items()}  # fmt: skip

    @property
    def last_times(self) -> dict[str, float | None]:
        """Each IMU's last time appended (or held by a continued session), s."""
        return dict(self._last_time)

    def append(self, name: str, time, **values) -> None:
        """Buffer a block of IMU ``name``'s samples: ``time`` (k,) and each recorded dataset
        (``accel=``, ``gyro=``, ``mag=`` (k, n), ``temperature=`` (k,)).

        Raises
        ------
        SessionError
            An unknown IMU, a missing or unexpected dataset, a wrong shape, or times that are
            not finite and strictly increasing after its earlier ones.
        """
        if name not in self.layouts:
            raise SessionError(f"{self._src}: append: no IMU {name!r} in this session")
        t = np.atleast_1d(np.asarray(time, np.float64))
        block = {"time": t}
        for ds_name, width in self.layouts[name].shapes().items():
            if ds_name == "time":
                continue
            value = values.get(ds_name)
            if value is None:
                raise SessionError(f"{self._src}: append to IMU {name}: {ds_name} is missing")
            array = np.asarray(value, np.float64).reshape((len(t), width) if width else (len(t),))
            block[ds_name] = array
        extra = [k for k, v in values.items() if v is not None and k not in block]
        if extra:
            raise SessionError(f"{self._src}: append to IMU {name}: it does not record "
                               f"{', '.join(extra)}")  # fmt: skip
        last = self._last_time[name]
        previous = t if last is None else np.concatenate(([last], t))
        if not np.isfinite(t).all() or np.any(np.diff(previous) <= 0):
            raise SessionError(f"{self._src}: append to IMU {name}: time is not finite and "
                               "strictly increasing")  # fmt: skip
        if t.size:
            self._pending[name].append(block)
            self._last_time[name] = float(t[-1])

    def write(self) -> None:
        """Write every buffered block (``time`` last); raises what h5py raises (the writer
        rolls back with :meth:`roll_back`)."""
        for name, blocks in self._pending.items():
            if not blocks:
                continue
            start = self.n_written[name]
            stop = start + sum(len(b["time"]) for b in blocks)
            for ds_name, ds in self.datasets[name].items():
                ds.resize(stop, axis=0)
                ds[start:stop] = np.concatenate([b[ds_name] for b in blocks])

    def written(self) -> None:
        """The buffered blocks are in the file: forget them."""
        for name, blocks in self._pending.items():
            if blocks:
                self.n_written[name] += sum(len(b["time"]) for b in blocks)
                self._last_written_time[name] = float(blocks[-1]["time"][-1])
            self._pending[name] = []

    def roll_back(self) -> None:
        """After a failed write: every dataset back to what was written (blocks kept)."""
        for name, sets in self.datasets.items():
            for ds in sets.values():
                try:
                    ds.resize(self.n_written[name], axis=0)
                except (OSError, RuntimeError):
                    pass

    def drop_pending(self) -> int:
        """Give up the blocks not written; return how many samples that was."""
        dropped = self.n_pending
        self._pending = {n: [] for n in self._pending}
        self.roll_back()
        self._last_time = dict(self._last_written_time)
        return dropped

    def remap_times(self, old: np.ndarray, new: np.ndarray) -> None:
        """Move every written time of every IMU as ``/raw``'s moved from ``old`` to ``new``
        (both (n,), s, strictly increasing): piecewise linear between ``/raw``'s samples,
        shifted as its first or last sample was outside them (so they stay in order: the
        map is strictly increasing).  Raises what h5py raises; SessionError while blocks
        wait to be written (their times would not move)."""
        if self.n_pending:
            raise SessionError(f"{self._src}: retime: other IMUs' samples not written yet")
        for name, sets in self.datasets.items():
            n = self.n_written[name]
            if not n:
                continue
            t = np.asarray(sets["time"][:n], np.float64)
            moved = np.interp(t, old, new)
            moved[t < old[0]] = t[t < old[0]] + (new[0] - old[0])
            moved[t > old[-1]] = t[t > old[-1]] + (new[-1] - old[-1])
            sets["time"][:n] = moved
            self._last_time[name] = self._last_written_time[name] = float(moved[-1])

    def written_times(self, name: str) -> np.ndarray:
        """IMU ``name``'s times written so far, s, shape (n,)."""
        return np.asarray(self.datasets[name]["time"][: self.n_written[name]], np.float64)

    def retime(self, name: str, time: np.ndarray, start: int = 0) -> None:
        """Replace the written times of IMU ``name`` from its ``start``-th sample on (its own
        clock's stamps known better later; a continued session's earlier ones stay), s, shape
        (n_written - start,); SessionError unless finite and strictly increasing after the
        samples before ``start``, or while its samples wait to be written.  Raises what h5py
        raises."""
        t = np.asarray(time, np.float64)
        ds, n = self.datasets[name]["time"], self.n_written[name]
        around = np.concatenate([ds[max(start - 1, 0):start] if start > 0 else [], t])
        if self._pending[name] or not 0 <= start <= n or t.shape != (n - start,) or not (
                np.isfinite(t).all() and (np.diff(around) > 0).all()):  # fmt: skip
            raise SessionError(f"{self._src}: retime of IMU {name}: {t.size} times for "
                               f"{n - start} written, or out of order")  # fmt: skip
        if t.size:
            ds[start:n] = t
            self._last_time[name] = self._last_written_time[name] = float(t[-1])

    def truncate_after(self, t_last: float | None) -> None:
        """Forget every sample later than ``t_last`` (None: all), written or not (the writer
        cut ``/raw`` there)."""
        self._pending = {n: [] for n in self._pending}
        for name, sets in self.datasets.items():
            time = sets["time"][: self.n_written[name]]
            n = 0 if t_last is None else int(np.searchsorted(time, t_last, side="right"))
            for ds in sets.values():
                try:
                    ds.resize(n, axis=0)
                except (OSError, RuntimeError):
                    pass
            self.n_written[name] = n
            self._last_time[name] = self._last_written_time[name] = float(time[n - 1]) \
                if n else None  # fmt: skip


def _check_same_imus(src: str, held: dict[str, ImuLayout],
                     capture: dict[str, ImuLayout]) -> None:  # fmt: skip
    """Refuse, in one line, a resumed capture whose other IMUs are not the session's: their
    names (so the number of ports or of triads per line) and each one's sensors, channels and
    temperature."""
    if list(held) != list(capture):
        raise InputError(f"{src}: the session holds the IMUs {', '.join(held) or 'none'} "
                         f"beside the reference, this capture "
                         f"{', '.join(capture) or 'none'}: resume with the same ports and "
                         "--columns as the capture that began it")  # fmt: skip
    for name, layout in capture.items():
        if layout.shapes() != held[name].shapes():
            raise InputError(f"{src}: IMU {name} records {_fields(held[name])} in the session, "
                             f"{_fields(layout)} in this capture: resume with the --columns "
                             "of the capture that began it")  # fmt: skip


def _fields(layout: ImuLayout) -> str:
    """``accel 3, gyro 3, temperature`` for a message."""
    return ", ".join(f"{k} {w}" if w else k for k, w in layout.shapes().items() if k != "time")
