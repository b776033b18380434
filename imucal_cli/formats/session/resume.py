"""Continuing a session a capture wrote (``imucal capture --resume``): :class:`Resumable`, the
part of :class:`~.writer.SessionWriter` that reopens a file (``SessionWriter.reopen``) and keeps
its samples and segments, and :class:`InPlace`, the output of a file updated where it is.
"""

from __future__ import annotations

import os
import time as _time
from pathlib import Path
from typing import Self

import h5py
import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.model.session import Session, io_reason

from .disk import CHUNK_ROWS, Reserve
from .imu_writer import ImuDatasets, ImuLayout
from .reader import read_session
from .segments import SegmentLog, entry_of


class InPlace:
    """The output of a reopened session (``SessionWriter.reopen``): the file is updated where it
    is, so there is no temporary file to publish, commit or discard."""

    published = True

    def __init__(self, path: Path) -> None:
        self.tmp = path

    def commit(self) -> None:
        pass

    def discard(self) -> None:
        pass


class Resumable:
    """:meth:`reopen`: a :class:`~.writer.SessionWriter` that continues a session."""

    @classmethod
    def reopen(cls, path: str | os.PathLike, *, flush_interval_s: float = 1.0,
               imus: dict[str, ImuLayout] | None = None) -> Self:  # fmt: skip
        """Continue a session a capture wrote (``imucal capture --resume``): samples and
        segments are appended after those already there, as if the capture had not stopped.

        The session is read and checked first (a capture killed before it wrote its segment
        groups has them in its log).  Its segments are kept and written again, with the new ones,
        at :meth:`close`; until then they are in the log, so a crash loses none.

        ``imus``: the other IMUs the continuing capture records (``/imus/<name>``, issue 28;
        none for one IMU), which must be those the session holds, each with the same
        channels; their datasets are continued too, each IMU from its own last sample.

        Raises
        ------
        InputError
            Not a session, one with fixed-size datasets (not written by a capture), or one
            whose other IMUs are not ``imus``.
        """
        session = read_session(path)
        self = cls.__new__(cls)
        self.path, self._src = Path(path), str(path)
        try:
            self._file = h5py.File(self.path, "r+", libver="latest")
        except OSError as exc:
            raise InputError(f"{path}: cannot open it to continue ({io_reason(exc)})") from None
        try:
            self._imus = None
            if session.imus or imus:  # several IMUs: the same ones, each continued
                self._imus = ImuDatasets.reopen(self._file, session.imus, dict(imus or {}),
                                                self._src)  # fmt: skip
            self._reopen_datasets(len(session.time))
            self._reopen_segments(session)
            self._file.attrs["resumed"] = int(self._file.attrs.get("resumed", 0)) + 1
            self._file.swmr_mode = True
        except (OSError, InputError) as exc:
            self._file.close()
            if isinstance(exc, InputError):
                raise
            raise InputError(f"{path}: cannot continue it ({io_reason(exc)})") from None
        self._flush_interval_s = float(flush_interval_s)
        self._n_written, self._pending, self._n_pending = len(session.time), [], 0
        self._last_time = float(session.time[-1]) if len(session.time) else None
        self._last_written_time = self._last_time
        host = session.host_time
        self.resumed_host_time = float(host[-1]) if host is not None and len(host) else None
        self._out = InPlace(self.path)  # the file keeps its name: nothing to publish
        self._reserve = Reserve(self.path, 0)
        self._nonfinite = {
            name: [np.flatnonzero(~np.isfinite(data).all(axis=1))] if data is not None else []
            for name, data in (("accel", session.accel), ("gyro", session.gyro))
        }
        self._last_flush = _time.monotonic()
        self.flush()
        return self

    resumed_host_time: float | None = None
    """A reopened session's last ``/raw/host_time``, s (None: new, or not recorded)."""

    def _reopen_datasets(self, n: int) -> None:
        """The /raw datasets of a reopened file, cut to the ``n`` samples it holds whole."""
        raw = self._file["raw"]
        self._datasets = {}
        for name in ("accel", "gyro", "mag", "temperature", "host_time", "time"):  # time last
            ds = raw.get(name)
            if ds is None:
                continue
            if ds.maxshape[0] is not None:
                raise InputError(
                    f"{self._src}: /raw/{name} has a fixed size (the session was not written by "
                    "imucal capture): it cannot be continued"
                )
            if ds.shape[0] != n:  # a killed writer may have written data beyond the last time
                ds.resize(n, axis=0)
            self._datasets[name] = ds
        self._widths = {name: self._datasets[name].shape[1] if name in self._datasets else None
                        for name in ("accel", "gyro", "mag")}  # fmt: skip
        self.chunk_rows = int(self._datasets["time"].chunks[0])

    def _reopen_segments(self, session: Session) -> None:
        """Keep the session's segments: in memory and, until :meth:`close`, in the log."""
        group = self._file.require_group("segments")
        for name in list(group):
            del group[name]
        self._log = SegmentLog(self._file, [entry_of(seg, f"{i:04d}")
                                            for i, seg in enumerate(session.segments)],
                               small=self.chunk_rows < CHUNK_ROWS)  # fmt: skip
