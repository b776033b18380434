"""Storing a calibration in a session: :func:`store_calibration` adds ``/calibrations/<name>``
and never touches ``/raw`` or ``/segments``."""

from __future__ import annotations

import json
import os
from pathlib import Path

import h5py

from imucal_cli.errors import SessionError
from imucal_cli.formats.session.h5open import member, open_for_update
from imucal_cli.model.session import one_line


def check_calibration_entry(src: str, json_text: str, name: str | None) -> None:
    """Raise SessionError unless ``json_text`` is JSON and ``name`` a valid group name."""
    try:
        json.loads(json_text)
    except (TypeError, ValueError, RecursionError) as exc:
        raise SessionError(f"{src}: calibration to store is not valid JSON ({exc})") from None
    if name is not None and (not isinstance(name, str) or not name or "/" in name or name == "."):
        raise SessionError(f"{src}: {name!r} is not a valid calibration name")


def store_calibration(path: str | os.PathLike, json_text: str, name: str | None = None) -> str:
    """Store a calibration JSON in a session as ``/calibrations/<name>``, attribute ``json``.

    Never touches ``/raw`` or ``/segments``.

    Parameters
    ----------
    path : str or path-like
        An existing session file.
    json_text : str
        The calibration JSON.
    name : str, optional
        Subgroup name; default the next zero-padded number (``"0000"``, ``"0001"``, ...).

    Returns
    -------
    str
        The name used.

    Raises
    ------
    SessionError
        The file is not a session or cannot be written, ``json_text`` is not JSON, or ``name``
        is taken or not a valid name.
    """
    path = Path(path)
    src = str(path)
    check_calibration_entry(src, json_text, name)
    file = open_for_update(path, src)
    try:
        with file:
            return _store(file, src, json_text, name)
    except (OSError, RuntimeError, KeyError, ValueError) as exc:
        raise SessionError(f"{src}: cannot store the calibration ({one_line(exc)})") from None


def _store(file: h5py.File, src: str, json_text: str, name: str | None) -> str:
    group = member(file, "calibrations", src)
    if group is None:
        group = file.create_group("calibrations")
    elif not isinstance(group, h5py.Group):
        raise SessionError(f"{src}: /calibrations is not a group")
    if name is None:
        numbers = [int(key) for key in group if key.isascii() and key.isdigit()]
        name = f"{max(numbers, default=-1) + 1:04d}"
    if name in group:
        raise SessionError(f"{src}: /calibrations/{name} already exists")
    group.create_group(name).attrs["json"] = json_text
    file.flush()
    return name
