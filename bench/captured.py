"""A simulated session segmented as ``imucal capture --no-prompt`` segments what it records
(issue 24): the capture's own :func:`imucal_cli.capture.unattended.segment_recording` run on
the samples, each segment labelled by the plan step it matches (``Step.segment_attrs``, as
the recorder writes it). Simulating straight to a file cuts every segment at the true motion;
a capture finds them from the data, a little late where a smooth turn starts slowly, and
sees the moves between poses as turns of their own. The benches and tests grade the user's
path with it where a live capture through the virtual port would take minutes per session.

A plan file can be written here: :data:`FERRARIS_TOML` is MaD Lab's Ferraris protocol (the
six faces, then a full turn on the table about each of +X, +Y, +Z, still before and after).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from imucal_cli.capture.unattended import segment_recording
from imucal_cli.formats.session import Segment, Session
from imucal_cli.plans import load_plan

FERRARIS_TOML = "\n".join(
    ['name = "ferraris-like"']
    + [f'[[step]]\nkind = "static"\nlabel = "face {f} up"\nup = {u}'
       for f, u in (("+X", "[1, 0, 0]"), ("-X", "[-1, 0, 0]"), ("+Y", "[0, 1, 0]"),
                    ("-Y", "[0, -1, 0]"), ("+Z", "[0, 0, 1]"), ("-Z", "[0, 0, -1]"))]
    + [f'[[step]]\nkind = "static"\nlabel = "face +{a} up"\nup = {u}\n'
       f'[[step]]\nkind = "rotation"\nlabel = "360 about +{a}"\naxis = {u}\nangle_deg = 360\n'
       f'[[step]]\nkind = "static"\nlabel = "face +{a} up"\nup = {u}'
       for a, u in (("X", "[1, 0, 0]"), ("Y", "[0, 1, 0]"), ("Z", "[0, 0, 1]"))]
) + "\n"  # fmt: skip


def ferraris_plan(folder: Path) -> Path:
    """Write :data:`FERRARIS_TOML` into ``folder``; return its path."""
    path = Path(folder) / "ferraris-like.toml"
    path.write_text(FERRARIS_TOML)
    return path


def as_captured(session: Session, plan: str) -> Session:
    """``session`` with the segments an unattended capture of ``plan`` would write."""
    entries, _, _ = segment_recording(session.time, session.accel, session.gyro,
                                      load_plan(plan))  # fmt: skip
    segments = [
        Segment(f"{i:04d}", e.kind, e.start, e.stop,
                **({} if e.step is None else e.step.segment_attrs()))
        for i, e in enumerate(entries)
    ]  # fmt: skip
    return replace(session, segments=segments)
