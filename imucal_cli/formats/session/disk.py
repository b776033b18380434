"""The disk a session is written to: how much room is left, the chunk size on a nearly full
disk, the space a writer sets aside at its start, and what becomes of samples whose write
failed (:class:`FailedWrites`, a part of :class:`~.writer.SessionWriter`).

A write that fails (disk full: h5py raises ``OSError`` or ``RuntimeError``) keeps the samples in
memory; :meth:`FailedWrites.release_reserve` frees the space set aside so that a retry can
succeed, :meth:`FailedWrites.drop_pending` writes what still fits and gives up the rest.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from imucal_cli.errors import WriteFailed

CHUNK_ROWS = 1024  # samples per HDF5 chunk of the /raw datasets
MIN_CHUNK_ROWS = 64  # on a nearly full disk: a chunk takes no more space than it must
CHUNKS_IN_FREE_SPACE = 256  # chunks are at most this fraction of the free space
WRITE_ERRORS = (OSError, RuntimeError)  # h5py raises RuntimeError for some ENOSPC failures


def free_bytes(path: Path) -> int | None:
    """Bytes an unprivileged writer may still use on the file system of ``path`` (its folder),
    or None when the system does not say."""
    try:
        st = os.statvfs(Path(path).parent)
    except (OSError, AttributeError):
        return None
    return st.f_bavail * st.f_frsize


def chunk_rows(free: int | None, row_bytes: int) -> int:
    """Rows per chunk of the ``/raw`` datasets: :data:`CHUNK_ROWS`, or fewer (a power of two,
    at least :data:`MIN_CHUNK_ROWS`) where a chunk of every dataset would take more than
    1/:data:`CHUNKS_IN_FREE_SPACE` of the free space: HDF5 allocates a chunk whole, so on a
    nearly full disk a large one would fail where the samples themselves still fit."""
    if free is None:
        return CHUNK_ROWS
    rows = CHUNK_ROWS
    while rows > MIN_CHUNK_ROWS and rows * row_bytes * CHUNKS_IN_FREE_SPACE > free:
        rows //= 2
    return rows


class Reserve:
    """Disk space held in a hidden file next to the session, freed when a write fails."""

    def __init__(self, path: Path, nbytes: int) -> None:
        self._path: Path | None = None
        try:
            st = os.statvfs(path.parent)
            nbytes = min(nbytes, st.f_bavail * st.f_frsize // 16)  # a little of what is left
        except OSError:
            pass
        if nbytes <= 0:
            return
        reserve = path.with_name(f".{path.name}.{os.getpid()}.reserve.tmp")
        try:
            fd = os.open(reserve, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
        except OSError:
            return
        self._path = reserve
        try:
            os.posix_fallocate(fd, 0, nbytes)
        except (OSError, AttributeError):
            try:
                os.write(fd, bytes(nbytes))
            except OSError:
                pass
        finally:
            os.close(fd)

    def release(self) -> bool:
        if self._path is None:
            return False
        try:
            os.unlink(self._path)
        except OSError:
            pass
        self._path = None
        return True




class FailedWrites:
    """:class:`~.writer.SessionWriter`'s answer to a write that failed: the ``/raw`` datasets
    and the segment log shrunk back to what was written, the reserve freed, the samples not
    written kept, written in part or given up."""

    def _roll_back(self, log_rows: int) -> None:
        """After a failed write, shrink ``/raw`` and the log back to what was written.  HDF5
        keeps a chunk it could not allocate (a full disk) as if it were written: rows written
        into it again on a retry were lost when the file closed (read back as the NaN fill
        value).  Shrinking drops that chunk, so the retry writes fresh ones."""
        for dataset in self._datasets.values():
            try:
                dataset.resize(self._n_written, axis=0)
            except WRITE_ERRORS:
                pass
        self._log.roll_back(log_rows)
        if self._imus is not None:
            self._imus.roll_back()

    def release_reserve(self) -> bool:
        """Free the disk space set aside at the start; return whether there was any."""
        return self._reserve.release()

    def drop_pending(self) -> int:
        """Write what still fits of the samples not written, chunk by chunk, then give up the
        rest: shrink ``/raw`` back to what was written and drop segments that reach past it.
        Returns the number of samples given up."""
        self._salvage()
        if self._imus is not None:
            self._imus.drop_pending()
        dropped = self._n_pending
        self._pending, self._n_pending = [], 0
        for dataset in self._datasets.values():
            try:
                dataset.resize(self._n_written, axis=0)
            except WRITE_ERRORS:
                pass
        self._last_time = self._last_written_time
        kept = self._n_written
        self._log.drop_beyond(kept)
        return dropped

    def _salvage(self) -> None:
        if not self._pending:
            return
        rows = {name: np.concatenate([b[name] for b in self._pending]) for name in self._datasets}
        done = 0
        for start in range(0, self._n_pending, self.chunk_rows):
            stop = min(start + self.chunk_rows, self._n_pending)
            part = {name: rows[name][start:stop] for name in rows}
            self._pending, n_before = [part], self._n_pending
            self._n_pending = stop - start
            try:
                self.flush()
            except WriteFailed:
                self._n_pending = n_before - done
                break
            done = stop
            self._n_pending = n_before - done
        self._pending = [{name: rows[name][done:] for name in rows}] if self._n_pending else []
