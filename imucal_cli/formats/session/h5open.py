"""Opening session files for reading, so that a file cannot make imucal hang or reach outside it.

- :func:`check_session_file`: the path is an existing, readable regular file (a FIFO would
  block, a directory or device is not a session).
- :func:`open_for_reading`: reads the superblock first (:mod:`.superblock`: a truncated or
  damaged header is a one-line error at once), opens a closed file normally (waiting a few
  seconds for a lock held by another imucal storing a calibration) and a file whose writer did
  not close it in SWMR read mode with few metadata read attempts (HDF5's default retries a
  damaged file for many minutes).  A file left open by an imucal capture that is gone (killed)
  is repaired on the spot, the way ``h5clear -s`` does, and a warning says so.
- :func:`member` / :func:`check_dataset` / :func:`get_attr`: access that refuses links (soft,
  external), virtual datasets and external storage, bounds the declared size of a dataset or
  attribute by the file's size before anything is allocated, and refuses datasets whose chunks
  were never written (HDF5 would invent fill values for them).
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import math
import os
import socket
import stat
import time
import warnings
from pathlib import Path
from typing import Any

import h5py

from imucal_cli.errors import ImucalWarning, SessionError
from imucal_cli.formats.session.superblock import (
    Superblock,
    SuperblockError,
    clear_status_flags,
    read_superblock,
)
from imucal_cli.model.session import FORMAT, LOG_GROUP, as_int, as_str, one_line

#: Metadata read attempts in SWMR read mode (HDF5's default, 100, sleeps for minutes).
SWMR_READ_ATTEMPTS = 8
#: How long a reader waits for a lock held by another process (storing a calibration).
LOCK_WAIT_S = 10.0
#: How long a file marked open for writing but not locked is looked at again before it is
#: called a killed writer's, s: another process storing a calibration marks it a moment before
#: it takes the lock (one of three concurrent calibrations failed to store on a fresh clone).
UNLOCKED_WRITER_WAIT_S = 1.0
#: A dataset may declare at most this many bytes per byte of file (deflate's limit is ~1032).
MAX_EXPANSION = 1100

# Where the writer leaves word of itself (on the /capture_log group, removed on a clean close).
WRITER_PID, WRITER_HOST, WRITER_BOOT = "writer_pid", "writer_host", "writer_boot_id"


def check_session_file(path: Path, src: str) -> os.stat_result:
    """Raise SessionError unless ``path`` is an existing, readable regular file; return its stat."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise SessionError(f"{src}: no such file") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise SessionError(f"{src}: a loop of symbolic links") from None
        raise SessionError(f"{src}: cannot read ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise SessionError(f"{src}: is a directory, not a session file")
    if not stat.S_ISREG(st.st_mode):
        raise SessionError(f"{src}: is not a regular file (a pipe or a device), not a session")
    if not os.access(path, os.R_OK):
        raise SessionError(f"{src}: permission denied")
    return st


def boot_id() -> str:
    """This boot's identity (Linux), so that a process id is compared within one boot only."""
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return ""


def writer_identity() -> dict[str, Any]:
    """The attributes a writer stores so that a reader can tell whether it is still running."""
    return {WRITER_PID: os.getpid(), WRITER_HOST: socket.gethostname(), WRITER_BOOT: boot_id()}


def _writer_state(file: h5py.File) -> str:
    """``"alive"``, ``"gone"`` or ``"unknown"`` for the writer of an unclosed file."""
    try:
        link = file.get(LOG_GROUP, getlink=True)
        if not isinstance(link, h5py.HardLink):
            return "unknown"
        attrs = file[LOG_GROUP].attrs
        pid = as_int(attrs.get(WRITER_PID))
        host, boot = as_str(attrs.get(WRITER_HOST)), as_str(attrs.get(WRITER_BOOT))
    except (OSError, KeyError, RuntimeError, ValueError, TypeError):
        return "unknown"
    if pid is None or host != socket.gethostname():
        return "unknown"
    if boot and boot_id() and boot != boot_id():
        return "gone"  # written before this machine restarted
    if pid == os.getpid():
        return "alive"
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return "gone"
    except OSError:
        return "alive"  # exists, owned by someone else
    return "alive"


def _swmr_fapl():
    """A file-access property list limiting SWMR metadata read attempts, or None if the HDF5
    library does not let us set it (then h5py's defaults apply)."""
    try:
        lib = ctypes.CDLL(h5py.h5p.__file__)
        set_attempts = lib.H5Pset_metadata_read_attempts
    except (OSError, AttributeError):
        return None
    set_attempts.argtypes = [ctypes.c_int64, ctypes.c_uint]
    set_attempts.restype = ctypes.c_int
    fapl = h5py.h5p.create(h5py.h5p.FILE_ACCESS)
    fapl.set_fclose_degree(h5py.h5f.CLOSE_STRONG)
    if set_attempts(fapl.id, SWMR_READ_ATTEMPTS) < 0:
        return None
    return fapl


def _open(path: Path, swmr: bool, mode: str = "r") -> h5py.File:
    if swmr:
        fapl = _swmr_fapl()
        if fapl is not None:
            flags = h5py.h5f.ACC_RDONLY | h5py.h5f.ACC_SWMR_READ
            return h5py.File(h5py.h5f.open(os.fsencode(path), flags, fapl=fapl))
    return h5py.File(path, mode, swmr=swmr)


def locked_by_other(path: Path) -> bool:
    """Whether another process holds an exclusive ``flock`` on the file: HDF5's lock while it
    has the file open for writing (not in SWMR mode)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return False
    finally:
        os.close(fd)  # releases our shared lock, if we got it
    return False


def _busy(exc: OSError, path: Path) -> bool:
    """Whether an open failed because another process is writing the file right now."""
    text = str(exc).lower()
    if "unable to lock" in text or "temporarily unavailable" in text:
        return True
    return "already open for write" in text and locked_by_other(path)


def _open_waiting(path: Path, src: str, swmr: bool, mode: str = "r") -> h5py.File:
    """Open; while another process has the file open for writing, retry for up to
    :data:`LOCK_WAIT_S` (a concurrent ``imucal calibrate`` storing its result)."""
    deadline = time.monotonic() + LOCK_WAIT_S
    delay = 0.02
    while True:
        try:
            return _open(path, swmr, mode)
        except OSError as exc:
            if not _busy(exc, path):
                raise SessionError(f"{src}: damaged HDF5 file ({one_line(exc)})") from None
            if time.monotonic() >= deadline:
                raise SessionError(
                    f"{src}: another program keeps the file open for writing "
                    f"({LOCK_WAIT_S:g} s); try again when it is done"
                ) from None
        except (KeyError, RuntimeError, ValueError) as exc:
            raise SessionError(f"{src}: damaged HDF5 file ({one_line(exc)})") from None
        time.sleep(delay)
        delay = min(delay * 2, 0.5)


def _superblock(path: Path, src: str) -> Superblock:
    """The file's HDF5 superblock, checked (:func:`read_superblock`).

    While another process has the file open for writing (a concurrent ``imucal calibrate``
    storing its result holds HDF5's lock), its header may declare space the library has not
    written yet: that is waited for (up to :data:`LOCK_WAIT_S`), not taken for a truncated
    file."""
    deadline = time.monotonic() + LOCK_WAIT_S
    delay = 0.02
    while True:
        try:
            return _read_superblock(path, src)
        except SessionError:
            if not locked_by_other(path):
                return _read_superblock(path, src)  # again: the writer may have just closed it
            if time.monotonic() >= deadline:
                raise
        time.sleep(delay)
        delay = min(delay * 2, 0.5)


def _read_superblock(path: Path, src: str) -> Superblock:
    check_session_file(path, src)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise SessionError(f"{src}: cannot read ({exc.strerror or exc})") from None
    try:
        return read_superblock(fd)[0]
    except SuperblockError as exc:
        raise SessionError(f"{src}: {exc}") from None
    except OSError as exc:
        raise SessionError(f"{src}: cannot read ({exc.strerror or exc})") from None
    finally:
        os.close(fd)


def open_for_update(path: str | os.PathLike, src: str | None = None) -> h5py.File:
    """Open a closed session read-write (to store a calibration), waiting for a lock held by
    another process for up to :data:`LOCK_WAIT_S`.

    Raises
    ------
    SessionError
        Not an imucal session, still being written, damaged, read-only or locked too long.
    """
    path = Path(path)
    src = str(path) if src is None else src
    block = _superblock(path, src)
    if not os.access(path, os.W_OK):
        raise SessionError(f"{src}: is read-only")
    deadline = time.monotonic() + UNLOCKED_WRITER_WAIT_S
    while block.open_for_write and not locked_by_other(path) and time.monotonic() < deadline:
        time.sleep(0.05)  # another calibrate between opening the file and locking it
        block = _superblock(path, src)
    if block.open_for_write and not locked_by_other(path):
        raise SessionError(
            f"{src}: its writer has not closed it (a capture still running, or killed: "
            f"`imucal report {src}` repairs a killed capture's file)"
        )
    file = _open_waiting(path, src, swmr=False, mode="r+")
    try:
        fmt = as_str(get_attr(file.attrs, "format", src, "root "))
    except SessionError:
        file.close()
        raise
    if fmt != FORMAT:
        file.close()
        raise SessionError(f"{src}: not an imucal session (format is not {FORMAT!r})")
    return file


def open_for_reading(path: str | os.PathLike, src: str | None = None) -> tuple[h5py.File, bool]:
    """Open a session read-only; return the file and whether its writer has not closed it.

    Raises
    ------
    SessionError
        Missing, not a regular file, not HDF5, truncated, damaged, or locked for longer than
        :data:`LOCK_WAIT_S`; one line naming the file.
    """
    path = Path(path)
    src = str(path) if src is None else src
    block = _superblock(path, src)
    if not block.open_for_write or locked_by_other(path):
        # a flag set by a program writing it now (storing a calibration): wait for it
        return _open_waiting(path, src, swmr=False), False
    file = _open_waiting(path, src, swmr=True)
    state = _writer_state(file)
    if state == "alive":
        return file, True
    if state == "gone" and os.access(path, os.W_OK):
        file.close()
        try:
            clear_status_flags(path)
        except (OSError, SuperblockError) as exc:
            warnings.warn(
                f"{src}: its writer did not close it; cannot repair ({one_line(exc)})",
                ImucalWarning,
                stacklevel=2,
            )
            return _open_waiting(path, src, swmr=True), True
        warnings.warn(
            f"{src}: the capture writing it did not close it (killed, or the disk was full); "
            "repaired (cleared HDF5's open-for-writing flag), every sample it flushed is kept",
            ImucalWarning,
            stacklevel=2,
        )
        return _open_waiting(path, src, swmr=False), True
    warnings.warn(
        f"{src}: its writer did not close it (killed?); read as far as it was written. Other "
        f"HDF5 tools open it after `h5clear -s {src}`",
        ImucalWarning,
        stacklevel=2,
    )
    return file, True


# --------------------------------------------------------------------------------------------
# Guarded access
# --------------------------------------------------------------------------------------------


def file_size(file: h5py.File) -> int:
    """Size in bytes of the open file (for the size bounds)."""
    try:
        return int(file.id.get_filesize())
    except (OSError, RuntimeError, ValueError):
        return 0


def member(group: h5py.Group, name: str, src: str) -> h5py.Group | h5py.Dataset | None:
    """``group[name]`` or None when absent; a link (soft or to another file) is refused."""
    where = f"{group.name.rstrip('/')}/{name}"
    try:
        link = group.get(name, getlink=True)
    except (OSError, KeyError, RuntimeError, ValueError) as exc:
        raise SessionError(f"{src}: {where} cannot be read ({one_line(exc)})") from None
    if link is None:
        return None
    if isinstance(link, h5py.ExternalLink):
        raise SessionError(
            f"{src}: {where} is a link to another file ({link.filename}); a session must hold "
            "its own data"
        )
    if not isinstance(link, h5py.HardLink):
        kind = "a soft link" if isinstance(link, h5py.SoftLink) else "a link"
        raise SessionError(f"{src}: {where} is {kind}; a session must hold its own data")
    try:
        return group[name]
    except (OSError, KeyError, RuntimeError, ValueError) as exc:
        raise SessionError(f"{src}: {where} cannot be read ({one_line(exc)})") from None


def check_dataset(ds: h5py.Dataset, src: str, *, limit: int, complete: bool = True) -> None:
    """Refuse a dataset whose data is outside the file, or larger than the file can hold.

    Parameters
    ----------
    ds : h5py.Dataset
    src : str
        The file, for messages.
    limit : int
        The file's size in bytes; the dataset may declare at most ``MAX_EXPANSION`` times that.
    complete : bool
        Also refuse chunks never written (their values would be HDF5 fill values).
    """
    where = ds.name
    try:
        dcpl = ds.id.get_create_plist()
        layout = dcpl.get_layout()
        external = dcpl.get_external_count()
    except (OSError, RuntimeError, ValueError) as exc:
        raise SessionError(f"{src}: {where} cannot be read ({one_line(exc)})") from None
    if layout == h5py.h5d.VIRTUAL:
        raise SessionError(f"{src}: {where} is a virtual dataset (its data lives in other files)")
    if external > 0:
        raise SessionError(f"{src}: {where} keeps its data in an external file; refused")
    nbytes = math.prod(ds.shape) * ds.dtype.itemsize
    if nbytes > MAX_EXPANSION * max(limit, 1):
        raise SessionError(
            f"{src}: {where} declares shape {ds.shape} ({nbytes} bytes), more than a "
            f"{limit}-byte file can hold"
        )
    if not complete or nbytes == 0 or _nan_fill(ds):
        return  # unwritten rows read as NaN, which the reader finds
    try:
        if layout == h5py.h5d.CHUNKED:
            chunks = dcpl.get_chunk()
            wanted = math.prod(math.ceil(n / c) for n, c in zip(ds.shape, chunks, strict=True))
            have = ds.id.get_num_chunks()
            if have < wanted:
                raise SessionError(
                    f"{src}: {where} has {wanted - have} of {wanted} chunks never written "
                    "(their values would be made up)"
                )
        elif layout == h5py.h5d.CONTIGUOUS:
            offset = ds.id.get_offset()
            if offset is None or ds.id.get_storage_size() < nbytes or offset + nbytes > limit:
                raise SessionError(f"{src}: {where} is not (entirely) stored in the file")
    except (OSError, RuntimeError, ValueError) as exc:
        raise SessionError(f"{src}: {where} cannot be read ({one_line(exc)})") from None


def _nan_fill(ds: h5py.Dataset) -> bool:
    try:
        return ds.dtype.kind == "f" and math.isnan(float(ds.fillvalue))
    except (TypeError, ValueError, OSError):
        return False


MAX_ATTRIBUTE_BYTES = 1 << 26
"""An attribute declaring more bytes than this is refused (not read)."""


def get_attr(attrs: h5py.AttributeManager, name: str, src: str, where: str) -> Any:
    """Return attribute ``name`` or None when absent; an unreadable or oversized value is an
    error (``where`` prefixes the message, e.g. ``"root "`` or ``"/segments/0001: "``)."""
    try:
        if name not in attrs:
            return None
        aid = attrs.get_id(name)
        declared = math.prod(aid.shape or ()) * aid.dtype.itemsize
        if declared > MAX_ATTRIBUTE_BYTES:
            raise SessionError(
                f"{src}: {where}attribute {name!r} declares {declared} bytes; refused"
            )
        return attrs[name]
    except (OSError, TypeError, ValueError, KeyError, RuntimeError) as exc:
        raise SessionError(
            f"{src}: {where}attribute {name!r} cannot be read ({one_line(exc)})"
        ) from None
