"""Rewriting what a session says about its samples: :func:`rewrite_labels` replaces
``/segments`` and sets root attributes, and never touches ``/raw`` or ``/calibrations``."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from imucal_cli.errors import SessionError
from imucal_cli.formats.session.h5open import open_for_update
from imucal_cli.model.session import SEGMENT_ATTRS, SEGMENT_KINDS, Segment, as_unit_vector, one_line

__all__ = ["ROOT_LABELS", "rewrite_labels"]

ROOT_LABELS = ("sensor", "gravity", "accel_units", "gyro_units")
"""Root attributes :func:`rewrite_labels` may set (None removes one)."""


def _check(segments: list[Segment], n: int, src: str) -> None:
    last = -1
    for s in segments:
        where = f"{src}: segment {s.name}"
        if s.kind not in SEGMENT_KINDS:
            raise SessionError(f"{where}: unknown kind {s.kind!r}")
        if not 0 <= s.start < s.stop <= n:
            raise SessionError(f"{where}: samples [{s.start}, {s.stop}) not within the {n} samples")
        if s.start < last:
            raise SessionError(f"{where}: segments must be in time order")
        last = s.start
        if s.kind == "static" and (s.axis is not None or s.angle_deg is not None):
            raise SessionError(f"{where}: a static segment has no axis or angle")
        if s.kind == "rotation" and s.up is not None:
            raise SessionError(f"{where}: a rotation segment has no up")
        for name, v in (("up", s.up), ("axis", s.axis)):
            if v is not None and as_unit_vector(v) is None:
                raise SessionError(f"{where}: {name} must be 3 finite numbers, not all zero")
        if s.angle_deg is not None and not np.isfinite(s.angle_deg):
            raise SessionError(f"{where}: angle_deg must be finite")


def rewrite_labels(
    path: str | os.PathLike, segments: list[Segment], attrs: dict[str, Any] | None = None
) -> None:
    """Replace a session's ``/segments`` and set root attributes; ``/raw`` is never touched.

    The new segments are written to a new group first and swapped in only when complete, so an
    interruption leaves the old labels or the new ones, never a mix.

    Parameters
    ----------
    path : str or path-like
        An existing session file.
    segments : list of Segment
        The segments, in time order; they are renamed ``0000``, ``0001``, ...
    attrs : dict, optional
        Root attributes from :data:`ROOT_LABELS`; a None value removes the attribute.

    Raises
    ------
    SessionError
        Not a session, cannot be written, a segment outside the samples or out of order, a
        field that does not fit its kind, an attribute not in :data:`ROOT_LABELS`.
    """
    path = Path(path)
    src = str(path)
    attrs = dict(attrs or {})
    for key in attrs:
        if key not in ROOT_LABELS:
            raise SessionError(f"{src}: {key!r} is not a label this command sets")
    with open_for_update(path, src) as file:
        time = file.get("raw/time")
        if not isinstance(time, h5py.Dataset):
            raise SessionError(f"{src}: no /raw/time")
        _check(segments, int(time.shape[0]), src)
        try:
            if "segments.new" in file:
                del file["segments.new"]
            group = file.create_group("segments.new")
            for k, s in enumerate(segments):
                sub = group.create_group(f"{k:04d}").attrs
                sub["kind"], sub["start"], sub["stop"] = s.kind, int(s.start), int(s.stop)
                if s.label is not None:
                    sub["label"] = s.label
                for name, v in (("up", s.up), ("axis", s.axis)):
                    if v is not None:
                        sub[name] = as_unit_vector(v)
                if s.angle_deg is not None:
                    sub["angle_deg"] = float(s.angle_deg)
                for key, value in s.extra.items():
                    if key not in SEGMENT_ATTRS:
                        sub[key] = value
            if "segments" in file:
                del file["segments"]
            file.move("segments.new", "segments")
            for key, value in attrs.items():
                if value is None:
                    file.attrs.pop(key, None)
                else:
                    file.attrs[key] = value
        except (OSError, RuntimeError, TypeError, ValueError) as exc:
            raise SessionError(f"{src}: cannot write the labels ({one_line(exc)})") from None
