"""Reading the calibrations a report or a history is about (JSON, or those a session stores)."""

from __future__ import annotations

import os
from pathlib import Path

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import Calibration, calibration_from_json
from imucal_cli.formats.inputs import is_hdf5_file, read_input
from imucal_cli.formats.session import read_session

_WHAT = "calibration JSON or session .h5"


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
    if is_hdf5_file(path, what=_WHAT):
        return _last_stored_calibration(path)
    data = read_input(path, what=_WHAT)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(
            f"{path}: neither a session (HDF5) nor a calibration (JSON) file"
        ) from None
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
        if is_hdf5_file(path, what=_WHAT):
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
