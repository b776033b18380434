"""Reading a small input file (calibration JSON, TOML config, plan) so that no path can hang,
exhaust memory or give a traceback: only regular files are read (a FIFO would block forever, a
device never end), opened without blocking, bounded in size, and every failure is one line.

The counterpart of :mod:`imucal_cli.formats.output` for what imucal reads whole.
"""

from __future__ import annotations

import errno
import os
import stat
from collections.abc import Iterator
from contextlib import contextmanager

from imucal_cli.errors import InputError

__all__ = ["MAX_TEXT_BYTES", "is_hdf5_file", "read_head", "read_input", "read_text_input"]

#: The HDF5 file signature (HDF5 File Format Specification II.A), at 0, 512, 1024, ...
SIGNATURE = b"\x89HDF\r\n\x1a\n"

#: A calibration, config or plan is a few kB; anything past this is not one.
MAX_TEXT_BYTES = 64 << 20


def _open_regular(path: str | os.PathLike, what: str, error: type[InputError]) -> int:
    """A descriptor on a regular file (opened without blocking), or ``error``."""
    src = str(path)
    flags = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise error(f"{src}: no such file") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise error(f"{src}: a loop of symbolic links") from None
        if exc.errno == errno.EISDIR:
            raise error(f"{src}: is a directory, not a {what}") from None
        raise error(f"{src}: cannot read ({exc.strerror or exc})") from None
    try:
        st = os.fstat(fd)
    except OSError as exc:
        os.close(fd)
        raise error(f"{src}: cannot read ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        os.close(fd)
        raise error(f"{src}: is a directory, not a {what}")
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        raise error(f"{src}: is not a regular file (a pipe or a device), not a {what}")
    return fd


@contextmanager
def _reading(path: str | os.PathLike, what: str, error: type[InputError]) -> Iterator[int]:
    """A descriptor on a regular file (:func:`_open_regular`) while it is read: an ``OSError``
    in the block becomes one line of ``error``; the descriptor is closed after."""
    fd = _open_regular(path, what, error)
    try:
        yield fd
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    finally:
        os.close(fd)


def is_hdf5_file(
    path: str | os.PathLike, *, what: str = "file", error: type[InputError] = InputError
) -> bool:
    """Whether a regular file starts with the HDF5 signature (at 0, 512, 1024, ...): what
    ``h5py.is_hdf5`` tells, without blocking on a FIFO.

    Raises
    ------
    error
        Missing, a directory, not a regular file, or unreadable.
    """
    with _reading(path, what, error) as fd:
        size = os.fstat(fd).st_size
        offset = 0
        while offset + len(SIGNATURE) <= size:
            if os.pread(fd, len(SIGNATURE), offset) == SIGNATURE:
                return True
            offset = 512 if offset == 0 else offset * 2
        return False


def read_head(
    path: str | os.PathLike, n: int, *, what: str = "file", error: type[InputError] = InputError
) -> bytes:
    """The first ``n`` bytes of a regular file (fewer when it is shorter).

    Raises
    ------
    error
        Missing, a directory, not a regular file, or unreadable.
    """
    with _reading(path, what, error) as fd:
        return os.pread(fd, n, 0)


def read_input(
    path: str | os.PathLike,
    *,
    what: str = "file",
    max_bytes: int = MAX_TEXT_BYTES,
    error: type[InputError] = InputError,
) -> bytes:
    """Return the bytes of a regular file of at most ``max_bytes``.

    Parameters
    ----------
    path : path-like
    what : str
        What the file should be, for messages (``"calibration file"``).
    max_bytes : int
    error : InputError subclass
        The exception raised (``CalibrationFileError``, ``ConfigError``, ...).

    Raises
    ------
    error
        Missing, a directory, not a regular file, unreadable, or too large; one line.
    """
    src = str(path)
    with _reading(path, what, error) as fd:
        st = os.fstat(fd)
        if st.st_size > max_bytes:
            raise error(f"{src}: {st.st_size} bytes is too large for a {what}")
        chunks, total = [], 0
        while True:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                break
            total += len(chunk)
            if total > max_bytes:
                raise error(f"{src}: too large for a {what}")
            chunks.append(chunk)
        return b"".join(chunks)


HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
"""The first 8 bytes of an HDF5 file (with no user block): a session, an apply output."""


def read_text_input(
    path: str | os.PathLike,
    *,
    what: str = "file",
    max_bytes: int = MAX_TEXT_BYTES,
    error: type[InputError] = InputError,
) -> str:
    """:func:`read_input` decoded as UTF-8 (a leading byte-order mark is dropped).

    Raises
    ------
    error
        As :func:`read_input`, or the bytes are not UTF-8 (the message gives the offset).
    """
    data = read_input(path, what=what, max_bytes=max_bytes, error=error)
    try:
        return data.decode("utf-8").removeprefix("\ufeff")
    except UnicodeDecodeError:
        if data.startswith(HDF5_SIGNATURE):  # a session where a text file goes (arguments swapped)
            raise error(f"{path}: an HDF5 file (a session?), not a {what}") from None
        raise error(f"{path}: not a text (UTF-8) file") from None
