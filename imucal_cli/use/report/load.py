"""Reading the calibrations a report or a history is about (JSON, or those a session stores)."""

from __future__ import annotations

import os
from pathlib import Path

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import Calibration, calibration_from_json

_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def is_hdf5(path: Path) -> bool:
    """Whether ``path`` is an HDF5 file, without importing h5py for a JSON file (start-up time
    of ``imucal report CAL.json``): a file starting with the HDF5 signature is one, a file
    starting with ``{`` is not; anything else asks h5py (the superblock may follow a user
    block)."""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError:
        return False
    if head == _HDF5_SIGNATURE:
        return True
    if head.lstrip()[:1] == b"{" or head.startswith(b"\xef\xbb\xbf{"):
        return False
    import h5py

    return bool(h5py.is_hdf5(path))


def read_session(path):
    """:func:`imucal_cli.formats.session.read_session`, imported when a session is read."""
    from imucal_cli.formats.session import read_session as read

    return read(path)


def load_for_report(path: str | os.PathLike[str]) -> Calibration:
    """Read the calibration a report is about.

    Parameters
    ----------
    path
        A calibration JSON, or a session ``.h5``; of a session the *last* calibration stored
        under ``/calibrations`` is used.  The kind is decided by the HDF5 signature.

    Returns
    -------
    Calibration
        The calibration as read; nothing is re-solved.

    Raises
    ------
    InputError
        The file is missing, unreadable, neither JSON nor HDF5, or a session without a stored
        calibration.  ``CalibrationFileError`` and ``SessionError`` (both ``InputError``) come
        from the readers for malformed files.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected a calibration JSON or a session .h5")
    if is_hdf5(path):
        return _last_stored_calibration(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(
            f"{path}: neither a session (HDF5) nor a calibration (JSON) file"
        ) from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    return calibration_from_json(text, str(path))


def _last_stored_calibration(path: Path) -> Calibration:
    """The last calibration under ``/calibrations`` of a session (names are zero-padded)."""
    session = read_session(path)
    if not session.calibrations:
        raise InputError(
            f"{path}: session has no stored calibration; run `imucal calibrate {path}` first"
        )
    name = max(session.calibrations)
    return calibration_from_json(session.calibrations[name], f"{path}:/calibrations/{name}")


# --------------------------------------------------------------------------------------------
# Building the report dict


def load_all_for_history(paths: list[str | os.PathLike[str]]) -> list[Calibration]:
    """Every calibration the paths hold: a JSON gives one, a session all it stores.

    Parameters
    ----------
    paths
        Calibration JSONs and/or session ``.h5`` files.

    Returns
    -------
    list of Calibration
        In the order given (a session's in the order they were stored).

    Raises
    ------
    InputError
        As :func:`load_for_report`.
    """
    out: list[Calibration] = []
    for item in paths:
        path = Path(item)
        if path.exists() and not path.is_dir() and is_hdf5(path):
            session = read_session(path)
            if not session.calibrations:
                raise InputError(
                    f"{path}: session has no stored calibration; run `imucal calibrate {path}` "
                    "first"
                )
            for name in sorted(session.calibrations):
                out.append(
                    calibration_from_json(
                        session.calibrations[name], f"{path}:/calibrations/{name}"
                    )
                )
        else:
            out.append(load_for_report(path))
    return out
