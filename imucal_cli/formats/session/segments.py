"""The segments (and calibrations) a session writer keeps until it closes.

HDF5 creates no groups or attributes while a file is in SWMR write mode (see the package notes):
:class:`SegmentLog` keeps each segment in memory and logs it, one JSON object per row of the
fixed-length string dataset ``/capture_log/segments``, at the writer's next flush; once the file
is closed, :meth:`SegmentLog.write` turns them into the ``/segments/NNNN`` groups, stores the
calibrations given meanwhile under ``/calibrations`` and removes the log.  A writer killed
before that leaves the log, which :func:`~.reader.read_session` reads instead.
:func:`segment_entry` checks a segment and gives the attributes the format stores.
"""

from __future__ import annotations

import json
import operator
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from imucal_cli.errors import SessionError
from imucal_cli.formats.session.h5open import writer_identity
from imucal_cli.formats.session.store import check_calibration_entry
from imucal_cli.model.session import (
    LOG_GROUP,
    LOG_ITEM_BYTES,
    SEGMENT_ATTRS,
    SEGMENT_KINDS,
    TURN_ANGLE_RULE,
    Segment,
    as_turn_angle,
    as_unit_vector,
)

__all__ = ["SegmentLog", "segment_entry"]

_WRITE_ERRORS = (OSError, RuntimeError)  # h5py raises RuntimeError for some ENOSPC failures


def segment_entry(
    name: str,
    kind: str,
    start: Any,
    stop: Any,
    n_samples: int,
    *,
    label: str | None = None,
    up: Any = None,
    axis: Any = None,
    angle_deg: Any = None,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Validate one segment and return it as the attributes the format stores (plain JSON
    values; ``up``/``axis`` scaled to unit length).  Raises ``ValueError`` with the problem."""
    if kind not in SEGMENT_KINDS:
        raise ValueError(f"unknown kind {kind!r} (expected 'static' or 'rotation')")
    try:
        start, stop = operator.index(start), operator.index(stop)
    except TypeError:
        raise ValueError(f"start and stop must be integers, got {start!r}, {stop!r}") from None
    if not 0 <= start < stop <= n_samples:
        raise ValueError(
            f"samples [{start}, {stop}) are not a non-empty range within the "
            f"{n_samples} samples appended so far"
        )
    if label is not None and not isinstance(label, str):
        raise ValueError(f"label must be a string, got {label!r}")
    entry: dict[str, Any] = {"name": name, "kind": kind, "start": start, "stop": stop}
    if label is not None:
        entry["label"] = label
    for key, value in (extra or {}).items():
        if key in SEGMENT_ATTRS or key == "name":
            raise ValueError(f"extra attribute {key!r} is one the format defines")
        if not isinstance(value, int | float | str | list):
            raise ValueError(f"extra attribute {key!r} must be a number, string or list")
        entry[key] = value
    wrong = {"up": up} if kind == "rotation" else {"axis": axis, "angle_deg": angle_deg}
    for option, value in wrong.items():
        if value is not None:
            raise ValueError(f"{option!r} does not apply to a {kind} segment")
    for option, value in (("up", up), ("axis", axis)):
        if value is not None:
            vector = as_unit_vector(value)
            if vector is None:
                raise ValueError(
                    f"{option!r} must be 3 finite numbers, not all zero, got {value!r}"
                )
            entry[option] = vector.tolist()
    if angle_deg is not None:
        if as_turn_angle(angle_deg) is None:
            raise ValueError(f"'angle_deg' must be {TURN_ANGLE_RULE}, got {angle_deg!r}")
        entry["angle_deg"] = float(angle_deg)
    return entry


def entry_of(segment: Segment, name: str) -> dict[str, Any]:
    """The stored attributes of a segment read back (a continued session's), named ``name``."""
    entry: dict[str, Any] = {"name": name, "kind": segment.kind, "start": int(segment.start),
                             "stop": int(segment.stop)}  # fmt: skip
    optional = {
        "label": segment.label,
        "angle_deg": segment.angle_deg,
        "up": None if segment.up is None else np.asarray(segment.up).tolist(),
        "axis": None if segment.axis is None else np.asarray(segment.axis).tolist(),
    }
    entry.update({k: v for k, v in optional.items() if v is not None}, **segment.extra)
    return entry


class SegmentLog:
    """The segments and calibrations of a session being written (see the module notes).

    Parameters
    ----------
    file : h5py.File
        The session, open for writing (not yet in SWMR mode): its log is created, replacing
        one a killed writer left.
    entries : iterable of dict
        Segments the session holds already (a continued capture): kept, and logged again.
    small : bool
        A nearly full disk: the log grows one row (segment) at a time, not 16.
    """

    def __init__(self, file: h5py.File, entries=(), *, small: bool = False) -> None:
        if LOG_GROUP in file:
            del file[LOG_GROUP]
        group = file.create_group(LOG_GROUP)
        group.attrs.update(writer_identity())
        self.dataset = group.create_dataset(
            "segments", shape=(0,), maxshape=(None,), chunks=(1 if small else 16,),
            dtype=f"S{LOG_ITEM_BYTES}",
        )
        self.entries: list[dict[str, Any]] = []  # every segment, as stored
        self._pending: list[bytes] = []  # log rows not written yet
        self.calibrations: dict[str, str] = {}
        for entry in entries:  # as the session holds them
            self._keep(entry, json.dumps(entry).encode("utf-8"))

    def add(self, entry: dict[str, Any]) -> None:
        """Keep a segment (from :func:`segment_entry`) and log it at the next :meth:`flush`.

        Raises
        ------
        ValueError
            Its log row would be longer than the log holds (a label too long).
        """
        logged = json.dumps(entry).encode("utf-8")
        if len(logged) > LOG_ITEM_BYTES:
            raise ValueError("too long for the log")
        self._keep(entry, logged)

    def _keep(self, entry: dict[str, Any], logged: bytes) -> None:
        self.entries.append(entry)
        self._pending.append(logged)

    def flush(self) -> None:
        """Append the rows not logged yet to the log (inside the writer's flush)."""
        if self._pending:
            start = self.dataset.shape[0]
            self.dataset.resize(start + len(self._pending), axis=0)
            self.dataset[start:] = np.array(self._pending, dtype=f"S{LOG_ITEM_BYTES}")

    def flushed(self) -> None:
        """The writer's flush succeeded: every row is in the log."""
        self._pending = []

    def roll_back(self, rows: int) -> None:
        """After a failed flush, shrink the log back to the ``rows`` it held."""
        try:
            self.dataset.resize(rows, axis=0)
        except _WRITE_ERRORS:
            pass

    def drop_beyond(self, kept: int) -> None:
        """Forget the segments that reach past the first ``kept`` samples (not written)."""
        self.entries = [s for s in self.entries if s["stop"] <= kept]
        self._pending = [row for row in self._pending if json.loads(row)["stop"] <= kept]

    def add_calibration(self, src: str, name: str, json_text: str) -> None:
        """Store a calibration JSON as ``/calibrations/<name>`` at :meth:`write`.

        Raises
        ------
        SessionError
            ``json_text`` is not JSON, or ``name`` is taken or not a valid name.
        """
        check_calibration_entry(src, json_text, name)
        if name in self.calibrations:
            raise SessionError(f"{src}: /calibrations/{name} already exists")
        self.calibrations[name] = json_text

    def write(self, path: Path, attrs: dict[str, Any] | None = None) -> None:
        """Into the closed file at ``path``: the segment groups, the calibrations and the
        root ``attrs``; the log removed."""
        with h5py.File(path, "r+") as file:
            file.attrs.update(attrs or {})
            group = file["segments"]
            for entry in self.entries:
                attrs = group.create_group(entry["name"]).attrs
                for key, value in entry.items():
                    if key in ("up", "axis"):
                        attrs[key] = np.asarray(value, dtype=np.float64)
                    elif key != "name":
                        attrs[key] = value
            del file[LOG_GROUP]
            if self.calibrations:
                calibrations = file.create_group("calibrations")
                for name, text in self.calibrations.items():
                    calibrations.create_group(name).attrs["json"] = text
