"""Opening session files for reading: checks before HDF5 sees the file, and attribute access
that turns every HDF5 failure into a one-line :class:`~imucal_cli.errors.SessionError`."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import h5py

from imucal_cli.errors import SessionError

from .model import FORMAT, as_str, one_line


def check_session_file(path: Path, src: str) -> None:
    """Raise SessionError unless ``path`` is a readable HDF5 file."""
    if not path.exists():
        raise SessionError(f"{src}: no such file")
    if path.is_dir():
        raise SessionError(f"{src}: is a directory, not a session file")
    if not os.access(path, os.R_OK):
        raise SessionError(f"{src}: permission denied")
    if not h5py.is_hdf5(path):
        raise SessionError(f"{src}: not an HDF5 file")


def open_for_reading(path: Path, src: str) -> tuple[h5py.File, bool]:
    """Open a session read-only; return the file and whether its writer has not closed it.

    A file still being written (or whose SWMR writer was killed) carries the HDF5 "open for
    writing" flag and only opens in SWMR read mode.
    """
    check_session_file(path, src)
    try:
        return h5py.File(path, "r"), False
    except OSError:
        pass
    try:
        return h5py.File(path, "r", swmr=True), True
    except OSError as exc:
        raise SessionError(
            f"{src}: cannot open the HDF5 file ({one_line(exc)}); if the program that wrote "
            f"it was killed, `h5clear -s {src}` clears the flag"
        ) from None


def open_for_update(path: Path, src: str) -> h5py.File:
    """Open an existing session to change what it says about its samples (``r+``).

    Raises
    ------
    SessionError
        Not a file, cannot be opened for writing, or not an imucal session.
    """
    check_session_file(path, src)
    try:
        file = h5py.File(path, "r+")
    except OSError as exc:
        raise SessionError(f"{src}: cannot open for writing ({one_line(exc)})") from None
    if as_str(file.attrs.get("format")) != FORMAT:
        file.close()
        raise SessionError(f"{src}: not an imucal session (format is not {FORMAT!r})")
    return file


def get_attr(attrs: h5py.AttributeManager, name: str, src: str, where: str) -> Any:
    """Return attribute ``name`` or None when absent; an unreadable value is an error."""
    if name not in attrs:
        return None
    try:
        return attrs[name]
    except (OSError, TypeError, ValueError) as exc:
        raise SessionError(
            f"{src}: {where}attribute {name!r} cannot be read ({one_line(exc)})"
        ) from None
