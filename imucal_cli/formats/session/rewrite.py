"""Changing samples a session writer has already written: :class:`Rewritable`, the part of
:class:`~.writer.SessionWriter` that forgets samples from some point on (a capture whose samples
turned out unusable) and replaces written time stamps known better later (host-clock stamps put
on the device's steady clock when a capture ends).
"""

from __future__ import annotations

import numpy as np

from .disk import WRITE_ERRORS


class Rewritable:
    """Mixed into :class:`~.writer.SessionWriter` (its datasets, counts, segment log)."""

    def truncate(self, n: int) -> None:
        """Forget every sample from the ``n``-th on, written or not, and the segments that
        reach past it (a capture whose samples turned out unusable: its own are dropped, a
        continued session's earlier ones stay)."""
        self._pending, self._n_pending = [], 0
        n = max(min(int(n), self._n_written), 0)
        for dataset in self._datasets.values():
            try:
                dataset.resize(n, axis=0)
            except WRITE_ERRORS:
                pass
        self._n_written = n
        self._last_time = float(self._datasets["time"][n - 1]) if n else None
        self._last_written_time = self._last_time
        self._nonfinite = {name: [rows[rows < n] for rows in found]
                           for name, found in self._nonfinite.items()}  # fmt: skip
        self._log.drop_beyond(n)
        if self._imus is not None:
            self._imus.truncate_after(self._last_time)

    def written_times(self) -> np.ndarray:
        """The times of the samples written so far, s, shape (n_written,)."""
        return np.asarray(self._datasets["time"][: self._n_written], np.float64)

    def retime(self, start: int, time: np.ndarray, *, others: bool = True) -> None:
        """Replace the times of written samples ``[start, start + k)`` by ``time`` (host-clock
        stamps known better later), s, and the other IMUs' times with them (:meth:`~.imu_writer.
        ImuDatasets.remap_times`) unless ``others`` is False (each has its own clock:
        :meth:`retime_imu`); SessionError unless they stay strictly increasing with the
        samples around them; WriteFailed when the write fails."""
        dataset, t = self._datasets["time"], np.asarray(time, np.float64)
        stop = start + t.size
        around = np.concatenate([dataset[max(start - 1, 0):start], t, dataset[stop:stop + 1]])
        if stop > self._n_written or not (np.diff(around) > 0).all() or not np.isfinite(t).all():
            raise self._fail(f"retime: samples {start}-{stop} unwritten or out of order")
        imus = self._imus if others else None
        if imus is not None and imus.n_pending:
            raise self._fail("retime: other IMUs' samples not written yet")
        before = np.asarray(dataset[: self._n_written], np.float64)
        try:
            dataset[start:stop] = t
            if imus is not None:  # several IMUs on one clock: theirs move with /raw's
                after = before.copy()
                after[start:stop] = t
                imus.remap_times(before, after)
            self._check_open().flush()
        except WRITE_ERRORS as exc:
            raise self._write_failed(exc, 0) from None
        if stop == self._n_written:  # the last written sample moved
            self._last_written_time = float(t[-1])
            if not self._n_pending:
                self._last_time = self._last_written_time

    def imu_written_times(self, name: str) -> np.ndarray:
        """Other IMU ``name``'s times written so far, s, shape (n,)."""
        return self._imus.written_times(name)

    def imu_counts(self) -> dict[str, int]:
        """Each other IMU's samples appended so far (written or not); empty for one IMU."""
        return {} if self._imus is None else self._imus.counts()

    def imu_last_times(self) -> dict[str, float | None]:
        """Each other IMU's last time appended (or already in a reopened session), s."""
        return {} if self._imus is None else dict(self._imus.last_times)

    def retime_imu(self, name: str, time: np.ndarray, start: int = 0) -> None:
        """Replace the written times of other IMU ``name`` (stamped by its own port's host
        clock) from its ``start``-th sample on (a continued session's earlier ones stay), s;
        SessionError unless they stay strictly increasing (or while its samples wait);
        WriteFailed when the write fails."""
        try:
            self._imus.retime(name, time, start)
            self._check_open().flush()
        except WRITE_ERRORS as exc:
            raise self._write_failed(exc, 0) from None
