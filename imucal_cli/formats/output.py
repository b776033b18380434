"""Every file imucal writes goes through here: a fresh temporary file, renamed into place.

The rule (issue 11.1), in one place so that every command follows it:

- the output is written to a *fresh* temporary file in the target's folder, created with
  ``O_CREAT | O_EXCL | O_NOFOLLOW`` (never an existing file, never through a link; the name is
  random, so a file or link planted at ``OUTPUT.tmp`` is neither used nor removed);
- it is renamed into place only when complete (``os.replace``, which replaces a link at the
  target rather than writing through it); a failure removes the temporary file and leaves the
  target as it was;
- an existing target is replaced only with ``force``, never when it is one of the inputs
  (checked by identity, so a second name or a link to the input counts too), and never when it
  is not a regular file (``/dev/null``, a FIFO, a directory);
- without ``force`` the final step is ``os.link`` (fails if the target appeared meanwhile), so a
  file created by someone else between the check and the rename is not clobbered.

Use
---
Text or bytes in one go::

    write_output(path, text, force=force, inputs=[session_path])

Streamed, through a file object, h5py or matplotlib::

    with safe_output(path, force=force, inputs=[input_path]) as out:
        with out.open("w") as handle: ...          # text or "wb"
        # or: file = out.h5()  (h5py.File on the temporary file, mode "w"), close it yourself
        # or: fig.savefig(out.open("wb"), format="png")

Call :func:`check_output` first, before any long work, so that a refused output costs nothing.

A capture must be in place from its first sample (so that ``kill -9`` loses at most the last
second): :class:`OutputFile` can :meth:`~OutputFile.publish` early and keep writing to the
same file after the rename.
"""

from __future__ import annotations

import errno
import io
import os
import stat
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

import h5py

from imucal_cli.errors import InputError

__all__ = [
    "OutputError",
    "OutputFile",
    "PLOT_SUFFIXES",
    "SESSION_SUFFIXES",
    "check_output",
    "check_plot_output",
    "check_session_output",
    "check_suffix",
    "same_file",
    "safe_output",
    "write_output",
]

_OPEN_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)
# rename/link cannot make a second name here: fall back to a checked os.replace
_NO_LINK = {errno.EPERM, errno.EXDEV, errno.EMLINK, errno.ENOTSUP, errno.EOPNOTSUPP}


class OutputError(InputError):
    """An output that cannot or must not be written (exit code 2: nothing was saved)."""


def _describe(exc: OSError) -> str:
    return exc.strerror or str(exc)


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether ``a`` and ``b`` name the same existing file (following links)."""
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def check_output(
    path: str | os.PathLike,
    *,
    force: bool = False,
    inputs: Iterable[str | os.PathLike | None] = (),
    flag: str = "--force",
) -> Path:
    """Refuse an output before any work is done; return it as a :class:`Path`.

    Parameters
    ----------
    path : path-like
        The file to write.
    force : bool
        Whether an existing file may be replaced.
    inputs : iterable of path-like
        Files the command reads: never replaced, whatever ``force`` says.
    flag : str
        The option that allows replacing, named in the message.

    Raises
    ------
    OutputError
        The target is an input, a directory, not a regular file, exists without ``force``, or
        its folder does not exist.
    """
    path = Path(path)
    src = str(path)
    for item in inputs:
        if item is not None and same_file(path, item):
            raise OutputError(f"{src}: is the input {item}; choose another output file")
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise OutputError(f"{src}: cannot use as output ({_describe(exc)})") from None
    if st is not None:
        if stat.S_ISLNK(st.st_mode):
            try:
                target = os.stat(path)
            except OSError:
                target = None  # a dangling or looping link: replacing the link itself is fine
            if target is not None and stat.S_ISDIR(target.st_mode):
                raise OutputError(f"{src}: is a directory; give a file name")
        elif stat.S_ISDIR(st.st_mode):
            raise OutputError(f"{src}: is a directory; give a file name")
        elif not stat.S_ISREG(st.st_mode):
            raise OutputError(f"{src}: is not a regular file (refusing to replace it)")
        if not force:
            raise OutputError(f"{src}: already exists (pass {flag} to replace it)")
    parent = path.parent
    if not parent.is_dir():
        raise OutputError(f"{src}: folder {parent} does not exist")
    return path


SESSION_SUFFIXES = (".h5", ".hdf5")
"""The names of a session file (any case): what ``calibrate`` and every reader take for one."""

PLOT_SUFFIXES = (".png",)
"""The name of a ``--plot`` (always PNG)."""


def check_suffix(path: str | os.PathLike, suffixes: tuple[str, ...], what: str) -> Path:
    """Refuse an output whose name promises another format (``x.csv`` for an HDF5 session, a
    PNG or HTML); return it as a :class:`Path`.

    Parameters
    ----------
    path : path-like
        The file to write.
    suffixes : tuple of str
        The names it may end in (any case), ``(".h5", ".hdf5")``.
    what : str
        What is written, for the message: ``"imucal import writes an HDF5 session"``.

    Raises
    ------
    OutputError
        ``path`` does not end in one of ``suffixes``.
    """
    path = Path(path)
    if path.suffix.lower() not in suffixes:
        raise OutputError(f"{path}: {what}: name the output {' or '.join(suffixes)}")
    return path


def check_session_output(path: str | os.PathLike, command: str) -> Path:
    """:func:`check_suffix` of a session that ``command`` (``imucal import``) writes."""
    return check_suffix(path, SESSION_SUFFIXES, f"{command} writes an HDF5 session")


def check_plot_output(path: str | os.PathLike) -> Path:
    """:func:`check_suffix` of a ``--plot`` (PNG)."""
    return check_suffix(path, PLOT_SUFFIXES, "--plot draws a PNG image")


class OutputFile:
    """A fresh temporary file next to ``target``; :meth:`commit` renames it into place.

    Prefer :func:`safe_output` / :func:`write_output`; use this class directly when the file
    must be in place before it is complete (:meth:`publish`, for a capture).

    Attributes
    ----------
    target : Path
        The file that will be written.
    tmp : Path
        The temporary file (``.NAME.<random>.tmp`` in the target's folder), created empty.
    """

    def __init__(
        self,
        target: str | os.PathLike,
        *,
        force: bool = False,
        inputs: Iterable[str | os.PathLike | None] = (),
        flag: str = "--force",
    ) -> None:
        self.target = check_output(target, force=force, inputs=inputs, flag=flag)
        self.force = force
        self._flag = flag
        self._published = False
        self._done = False
        folder = self.target.parent
        for _ in range(16):
            tmp = folder / f".{self.target.name}.{os.urandom(4).hex()}.tmp"
            try:
                self._fd = os.open(tmp, _OPEN_FLAGS | _CLOEXEC, 0o666)
                break
            except FileExistsError:
                continue
            except OSError as exc:
                raise OutputError(f"{self.target}: cannot write ({_describe(exc)})") from None
        else:  # pragma: no cover - 16 collisions of 32 random bits
            raise OutputError(f"{self.target}: cannot create a temporary file in {folder}")
        self.tmp = tmp
        self._ino = os.fstat(self._fd)[stat.ST_INO], os.fstat(self._fd)[stat.ST_DEV]
        self._copy_mode()

    def _copy_mode(self) -> None:
        """A replaced file keeps its permission bits."""
        if not self.force:
            return
        try:
            st = os.stat(self.target)
        except OSError:
            return
        if stat.S_ISREG(st.st_mode):
            try:
                os.fchmod(self._fd, stat.S_IMODE(st.st_mode))
            except OSError:
                pass

    # writing -------------------------------------------------------------------------------
    def open(self, mode: str = "w", **kwargs: Any) -> IO:
        """A file object on the temporary file (``"w"``/``"wb"``; the caller closes it)."""
        if mode not in ("w", "wb"):
            raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
        fd = os.dup(self._fd)
        if mode == "w":
            kwargs.setdefault("encoding", "utf-8")
            kwargs.setdefault("newline", "\n")
        return os.fdopen(fd, mode, **kwargs)

    def h5(self, **kwargs: Any):
        """``h5py.File`` on the temporary file in mode ``"w"`` (checked to be that very file)."""
        file = h5py.File(self.tmp, "w", **kwargs)
        try:
            handle = file.id.get_vfd_handle()
            st = os.fstat(handle) if isinstance(handle, int) else None
        except (OSError, TypeError, ValueError, NotImplementedError):
            st = None
        if st is not None and (st.st_ino, st.st_dev) != self._ino:
            file.close()
            raise OutputError(f"{self.target}: the temporary file was replaced while in use")
        return file

    # finishing -----------------------------------------------------------------------------
    def _ours(self) -> bool:
        try:
            st = os.lstat(self.tmp)
        except OSError:
            return False
        return (st.st_ino, st.st_dev) == self._ino

    def publish(self) -> Path:
        """Give the file its final name now; writing may go on (same open file).

        Raises
        ------
        OutputError
            The target appeared meanwhile (without ``force``) or the rename failed.
        """
        if self._published:
            return self.target
        try:
            os.fsync(self._fd)
        except OSError:
            pass
        target = self.target
        try:
            if self.force:
                os.replace(self.tmp, target)
            else:
                self._link_into_place()
        except FileExistsError:
            raise OutputError(
                f"{target}: already exists (pass {self._flag} to replace it)"
            ) from None
        except OSError as exc:
            raise OutputError(f"{target}: cannot write ({_describe(exc)})") from None
        self._published = True
        _fsync_folder(target.parent)
        return target

    def _link_into_place(self) -> None:
        try:
            os.link(self.tmp, self.target, follow_symlinks=False)
        except FileExistsError:
            raise
        except OSError as exc:
            if exc.errno not in _NO_LINK:
                raise
            if os.path.lexists(self.target):  # a file system without hard links (FAT)
                raise FileExistsError(errno.EEXIST, "exists") from None
            os.replace(self.tmp, self.target)
            return
        os.unlink(self.tmp)

    def commit(self) -> Path:
        """Rename the complete file into place and close it; return the target."""
        try:
            self.publish()
        except BaseException:
            self.discard()
            raise
        self._close()
        return self.target

    def discard(self) -> None:
        """Remove the temporary file (only if it is still ours and not published)."""
        if not self._published and self._ours():
            try:
                os.unlink(self.tmp)
            except OSError:
                pass
        self._close()

    def _close(self) -> None:
        if not self._done:
            self._done = True
            try:
                os.close(self._fd)
            except OSError:
                pass

    @property
    def published(self) -> bool:
        """Whether the file has its final name."""
        return self._published


def _fsync_folder(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextmanager
def safe_output(
    path: str | os.PathLike,
    *,
    force: bool = False,
    inputs: Iterable[str | os.PathLike | None] = (),
    flag: str = "--force",
) -> Iterator[OutputFile]:
    """Write ``path`` through a fresh temporary file, renamed into place when the block ends.

    An exception inside the block removes the temporary file and leaves ``path`` untouched.
    An ``OSError`` (disk full, ...) becomes a one-line :class:`OutputError` naming ``path``.
    See the module notes for the rule; :func:`check_output` for the refusals.
    """
    out = OutputFile(path, force=force, inputs=inputs, flag=flag)
    try:
        yield out
    except OSError as exc:
        out.discard()
        raise OutputError(f"{out.target}: cannot write ({_describe(exc)})") from None
    except BaseException:
        out.discard()
        raise
    out.commit()


def write_output(
    path: str | os.PathLike,
    data: str | bytes,
    *,
    force: bool = False,
    inputs: Iterable[str | os.PathLike | None] = (),
    flag: str = "--force",
) -> Path:
    """Write ``data`` (text as UTF-8, or bytes) to ``path`` following the module's rule.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    OutputError
        Refused (see :func:`check_output`) or the write failed; ``path`` is untouched then.
    """
    with safe_output(path, force=force, inputs=inputs, flag=flag) as out:
        with out.open("wb") as handle:
            handle.write(data.encode("utf-8") if isinstance(data, str) else data)
    return out.target


@contextmanager
def h5_image(
    path: str | os.PathLike,
    *,
    force: bool = False,
    inputs: Iterable[str | os.PathLike | None] = (),
    flag: str = "--force",
) -> Iterator[h5py.File]:
    """An HDF5 file built in memory (``h5py.File`` on a buffer), written to ``path`` whole by
    :func:`write_output` when the block ends; for outputs whose data are in memory anyway.  A
    full disk then fails a plain write (one line); the close of an HDF5 file that could not
    write its data raised h5py's RuntimeError and crashed the process at exit."""
    check_output(path, force=force, inputs=inputs, flag=flag)
    image = io.BytesIO()
    with h5py.File(image, "w") as file:
        yield file
    write_output(path, image.getvalue(), force=force, inputs=inputs, flag=flag)
