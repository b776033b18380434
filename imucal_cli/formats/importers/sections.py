"""Labelled sections of a recording, as MaD Lab's ``imucal`` (FAU) annotates Ferraris sessions.

Two forms, both read into labelled segments instead of the automatic segmentation:

- a section list beside the recording: JSON ``{label: {"start": i0, "end": i1}}``, the rows
  ``[i0, i1)`` of the file's data (0-based, end exclusive, as ``DataFrame.iloc``);
- a column of the recording itself holding each row's label (``part`` in MaD Lab's
  ``annotated_session.csv``); consecutive rows with the same label form one section.

Ferraris labels (Ferraris et al. 1995, as MaD Lab names them): ``x_p``/``x_a`` the positive /
negative x axis pointing up (the accelerometer reads +1 g / -1 g on it), likewise ``y_*`` and
``z_*``: static segments with their ``up``; ``x_rot``, ``y_rot``, ``z_rot``: a full turn about
that sensor axis: rotation segments with ``axis`` and ``angle_deg``.  The protocol fixes the
turn's size (360 degrees) but its direction is written as "clockwise" without saying seen from
where, and MaD Lab's own recordings turn both ways; so by default the sign is that of the
gyro's own integral over the turn (and said so), and ``--turn-angle`` states it.  Other labels
become static segments with that label and no ``up``.

A static section must hold one pose: a step inside it (two poses merged, as when sections of
different faces are concatenated) is refused, never averaged.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.session import Segment
from imucal_cli.solvers.segmentation import estimate_noise, find_steps

from .recording import Recording
from .text import is_delimited, split_fields

__all__ = ["FERRARIS", "TURN_DEG", "labelled_segments", "read_section_list", "sections_of_column"]

_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
FERRARIS: dict[str, tuple[str, tuple[float, float, float], str]] = {}
"""Ferraris label -> (kind, up or axis, description)."""
for _a, _v in _AXES.items():
    _neg = tuple(0.0 - c for c in _v)
    FERRARIS[f"{_a}_p"] = ("static", _v, f"face +{_a.upper()} up")
    FERRARIS[f"{_a}_a"] = ("static", _neg, f"face -{_a.upper()} up")  # type: ignore[assignment]
    FERRARIS[f"{_a}_rot"] = ("rotation", _v, f"full turn about {_a.upper()}")

TURN_DEG = 360.0
"""Size of a Ferraris turn, degrees."""


def read_section_list(path: str | Path) -> list[tuple[str, int, int]]:
    """``(label, start, stop)`` rows of a MaD Lab section list, in row order.

    Raises
    ------
    InputError
        Unreadable or not JSON, not ``{label: {"start": int, "end": int}}``, empty or
        overlapping ranges.
    """
    src = str(path)
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(f"{src}: cannot read the section list ({exc.strerror or exc})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{src}: the section list is not JSON ({exc})") from None
    if not isinstance(data, dict) or not data:
        raise InputError(f'{src}: expected {{label: {{"start": row, "end": row}}, ...}}')
    out = []
    for label, rng in data.items():
        ok = isinstance(rng, dict) and all(
            isinstance(rng.get(k), int) and not isinstance(rng.get(k), bool)
            for k in ("start", "end")
        )
        if not ok:
            raise InputError(
                f'{src}: section {label!r} must be {{"start": row, "end": row}} with integer '
                f"rows, got {rng!r}"
            )
        if not 0 <= rng["start"] < rng["end"]:
            raise InputError(f"{src}: section {label!r} rows {rng['start']}:{rng['end']} are empty")
        out.append((str(label), rng["start"], rng["end"]))
    out.sort(key=lambda r: r[1])
    for (a, _, stop), (b, start, _) in zip(out[:-1], out[1:], strict=True):
        if start < stop:
            raise InputError(f"{src}: sections {a!r} and {b!r} overlap (rows {start}-{stop - 1})")
    return out


def sections_of_column(rec: Recording, path: Path, column: str) -> list[tuple[str, int, int]]:
    """``(label, start, stop)`` sample ranges of the runs of equal labels in a text column.

    Raises
    ------
    InputError
        The recording has no header naming ``column``, or a row lacks the field.
    """
    header = [h.strip().strip("\"'") for h in (rec.header or [])]
    if column not in header:
        named = ", ".join(header) if header else "no header line"
        raise InputError(f"{path}: no column {column!r} for --sections (columns: {named})")
    if rec.lines is None:
        raise InputError(f"{path}: --sections {column} needs a text file")
    index = header.index(column)
    lines = Path(path).read_bytes().decode("utf-8", errors="replace").splitlines()
    comma = is_delimited(lines[int(rec.lines[0]) - 1])
    labels = []
    for number in rec.lines:
        fields = split_fields(lines[int(number) - 1].strip(), comma)
        labels.append(fields[index].strip().strip("\"'"))
    labels_arr = np.array(labels, dtype=object)
    change = np.flatnonzero(labels_arr[1:] != labels_arr[:-1]) + 1
    starts = np.r_[0, change]
    stops = np.r_[change, len(labels)]
    return [
        (str(labels[a]), int(a), int(b)) for a, b in zip(starts, stops, strict=True) if labels[a]
    ]


def labelled_segments(
    rec: Recording,
    sections: list[tuple[str, int, int]],
    *,
    turn_angle_deg: float | None = None,
    where: str = "",
) -> tuple[list[Segment], list[str]]:
    """Segments from labelled sections; also notes for the user (how turn signs were set).

    Parameters
    ----------
    rec : Recording
    sections : list of (label, start, stop)
        Sample ranges (rows of the recording), in order.
    turn_angle_deg : float, optional
        Signed angle of every ``*_rot`` turn, degrees; default +-360 with the sign of the gyro
        integral about the turn's axis.
    where : str
        The file(s), for messages.

    Raises
    ------
    InputError
        A range beyond the recording; a static section that holds a step (two poses); a turn
        without gyro data.
    """
    n = len(rec.time)
    static_gyro = []
    for label, start, stop in sections:
        if stop > n:
            raise InputError(
                f"{where}: section {label!r} rows {start}:{stop} go past the {n} rows read"
                + (
                    f" ({rec.stats.malformed} malformed rows were skipped: sections count "
                    "the file's rows)"
                    if rec.stats.malformed
                    else ""
                )
            )
        kind = FERRARIS.get(label, ("static",))[0]
        if kind == "static" and rec.gyro is not None:
            static_gyro.append(rec.gyro[start:stop].mean(axis=0))
    _refuse_steps(rec, sections, where)
    bias = np.median(static_gyro, axis=0) if static_gyro else None
    segments, notes = [], []
    for label, start, stop in sections:
        kind, vector, text = FERRARIS.get(label, ("static", None, ""))
        full = f"{label} ({text})" if text else label
        if kind == "static":
            segments.append(
                Segment(name="", kind="static", start=start, stop=stop, label=full, up=vector)
            )
            continue
        if rec.gyro is None:
            raise InputError(f"{where}: section {label!r} is a turn but there is no gyro data")
        angle = turn_angle_deg
        if angle is None:
            axis_index = int(np.argmax(np.abs(vector)))
            dt = np.diff(rec.time[start:stop], prepend=rec.time[start])
            turned = float(np.sum((rec.gyro[start:stop, axis_index] - bias[axis_index]) * dt))
            angle = TURN_DEG if turned >= 0 else -TURN_DEG
            notes.append(
                f"{label}: {angle:+g} deg about {label[0]} (sign from the gyro; pass "
                f"--turn-angle to state it)"
            )
        segments.append(
            Segment(
                name="",
                kind="rotation",
                start=start,
                stop=stop,
                label=full,
                axis=vector,
                angle_deg=float(angle),
            )
        )
    return [dataclasses.replace(s, name=f"{i:04d}") for i, s in enumerate(segments)], notes


def _refuse_steps(rec: Recording, sections: list[tuple[str, int, int]], where: str) -> None:
    if rec.accel is None:
        return
    static = [(label, a, b) for label, a, b in sections if FERRARIS.get(label, ("static",))[0]
              == "static"]  # fmt: skip
    if not static:
        return
    noise = estimate_noise(rec.time, rec.accel, None)
    for label, a, b in static:
        steps = find_steps(rec.accel[a:b], noise.accel, noise.window)
        if steps:
            row = a + steps[0]
            raise InputError(
                f"{where}: section {label!r} (rows {a}:{b}) holds a step at row {row}: two "
                "poses in one static section, which would be averaged into neither; fix the "
                "sections"
            )
