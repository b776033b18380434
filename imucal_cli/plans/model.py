"""What a capture plan is (:mod:`imucal_cli.plans`): its :class:`Step` (what a step writes into
its segment: :meth:`Step.segment_attrs`), the :class:`Plan`, and how a capture went
(:class:`CaptureSummary`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Step:
    """One step of a plan.

    Attributes
    ----------
    kind : str
        ``"static"`` (hold still) or ``"rotation"`` (turn, still before and after).
    label : str
        What the person is told, stored as the segment's label.
    up : ndarray, shape (3,), or None
        Static: nominal unit vector pointing away from the earth, fixture frame.
    axis : ndarray, shape (3,), or None
        Rotation: nominal unit rotation axis, fixture frame.
    angle_deg : float or None
        Rotation: known signed angle about ``axis``, degrees.
    hold_s : float or None
        Static: how long this step is held, s; None uses the capture's ``--hold`` (the
        ``still:MINUTES`` plan sets it to its full duration).
    mounting : int or None
        The unit's mounting in the fixture (1, 2, ...), stored as the segment attribute
        ``mounting``: constraints that hold within one mounting only (Hwangbo & Kanade).
    """

    kind: str
    label: str
    up: np.ndarray | None = field(default=None, compare=False)
    axis: np.ndarray | None = field(default=None, compare=False)
    angle_deg: float | None = None
    hold_s: float | None = None
    mounting: int | None = None

    def segment_attrs(self) -> dict[str, Any]:
        """The attributes of the segment that records this step: ``label``, ``up`` (static)
        or ``axis`` and ``angle_deg`` (rotation), and ``extra`` (``{"mounting": m}``)."""
        out: dict[str, Any] = {"label": self.label}
        if self.kind == "static":
            out["up"] = None if self.up is None else np.asarray(self.up, float)
        else:
            out["axis"] = None if self.axis is None else np.asarray(self.axis, float)
            out["angle_deg"] = self.angle_deg
        if self.mounting is not None:
            out["extra"] = {"mounting": int(self.mounting)}
        return out


@dataclass(frozen=True)
class Plan:
    """A named sequence of steps.

    Attributes
    ----------
    name : str
        ``"six"``, ``"qureshi18"``, ... or a plan file's name.
    steps : tuple of Step
    """

    name: str
    steps: tuple[Step, ...]

    @property
    def static_steps(self) -> list[Step]:
        """The static steps, in order."""
        return [s for s in self.steps if s.kind == "static"]

    @property
    def rotation_steps(self) -> list[Step]:
        """The rotation steps, in order."""
        return [s for s in self.steps if s.kind == "rotation"]


@dataclass
class CaptureSummary:
    """How a capture went: shared by the guided and the unattended mode.

    Attributes
    ----------
    complete : bool
        Every step of the plan was done (or, without a plan, the recording ran its course).
    done, skipped, missing : list of str
        Step labels done, skipped by the person, not done.
    end_reason : str
        Why the recording ended, one line.
    samples : int
        Samples in the session.
    stats : dict
        The recorder's counters (lines, samples, comments, malformed, bytes, duration_s, ...).
    targets : list
        With accuracy targets (``capture --until``): each target's last status (a
        :class:`~imucal_cli.formats.targets.TargetStatus`); ``complete`` then means every
        target was met.
    """

    complete: bool
    done: list[str]
    skipped: list[str]
    missing: list[str]
    end_reason: str
    samples: int
    stats: dict
    targets: list = field(default_factory=list)
