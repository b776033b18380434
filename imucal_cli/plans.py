"""Capture plans: the steps a person (or a bench script) goes through, and what was done.

Built-in plans (:func:`load_plan`):

``six``
    The 6 faces of a cube, static, with ``up`` (``"face +Z up"``, ...).
``qureshi18``
    6 faces + 12 edges at 45 degrees (Qureshi & Golnaraghi section IV-B), static, with ``up``.
``random:N``
    N static poses, unlabelled (no ``up``), as the simulator's plan of that name.
``gyro-axes``
    For each axis X, Y, Z: a still period, then a turn about that axis (rotation steps with
    ``axis``, angle free); a final still period.  The still periods have no ``up``.
``hwangbo-iron``
    Hwangbo & Kanade's right-angle iron: the 6 faces as static steps, then a 90-degree turn
    about each face normal (rotation steps with ``axis`` and ``angle_deg = 90``).
``still:MINUTES``
    One static step held for MINUTES minutes (``hold_s`` = 60 * MINUTES), no ``up``: a still
    recording for ``imucal noise`` (Allan deviation; bias instability needs tens of minutes).
``warmup:MINUTES``
    One static step held for MINUTES minutes through a warm-up or cool-down (a cold start, a
    hair-dryer ramp), the temperature logged (``capture`` refuses columns without ``temp``):
    the recording for ``imucal calibrate --warmup`` (issue 17.3).

A TOML plan file::

    name = "my bench"                # optional; default the file name
    [[step]]
    kind = "static"                  # "static" or "rotation"
    label = "face +Z up"             # what the person is told; default "step N"
    up = [0, 0, 1]                   # static only, optional
    [[step]]
    kind = "rotation"
    label = "turn about +Z"
    axis = [0, 0, 1]                 # rotation only, optional
    angle_deg = 90                   # rotation only, optional

``up`` and ``axis`` are scaled to unit length.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imucal_cli.errors import InputError

__all__ = ["BUILTIN_PLANS", "CaptureSummary", "Plan", "Step", "load_plan", "needs_temperature",
           "plan_poses"]

BUILTIN_PLANS = ("six", "qureshi18", "gyro-axes", "hwangbo-iron", "random:N", "still:MINUTES",
                 "warmup:MINUTES")  # fmt: skip


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
    """

    kind: str
    label: str
    up: np.ndarray | None = field(default=None, compare=False)
    axis: np.ndarray | None = field(default=None, compare=False)
    angle_deg: float | None = None
    hold_s: float | None = None


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
    """

    complete: bool
    done: list[str]
    skipped: list[str]
    missing: list[str]
    end_reason: str
    samples: int
    stats: dict


# --------------------------------------------------------------------------------------------
# Built-ins
# --------------------------------------------------------------------------------------------

_AXES = "XYZ"
_RANDOM_RE = re.compile(r"random:(\d+)")
MAX_RANDOM_POSES = 10000


def _sign(s: float) -> str:
    return "+" if s > 0 else "-"


def _faces() -> list[tuple[str, np.ndarray]]:
    out = []
    for i in (2, 0, 1):  # +Z first: the unit starts flat on the table
        for s in (1.0, -1.0):
            up = np.zeros(3)
            up[i] = s
            out.append((f"face {_sign(s)}{_AXES[i]} up", up))
    return out


def _edges() -> list[tuple[str, np.ndarray]]:
    out = []
    for i, j in ((0, 1), (0, 2), (1, 2)):
        for si in (1.0, -1.0):
            for sj in (1.0, -1.0):
                up = np.zeros(3)
                up[i], up[j] = si, sj
                label = f"edge {_sign(si)}{_AXES[i]}{_sign(sj)}{_AXES[j]} up"
                out.append((label, up / np.sqrt(2.0)))
    return out


def plan_poses(plan: str) -> list[tuple[str, np.ndarray | None]]:
    """The poses of a plan, in the order they are visited.

    Parameters
    ----------
    plan : str
        ``six`` (the 6 faces of a cube), ``qureshi18`` (6 faces + 12 edges at 45 degrees,
        Qureshi & Golnaraghi section IV-B) or ``random:N`` (N unlabelled poses; the simulator
        draws their directions uniformly on the sphere); ``warmup:MINUTES`` is one pose, flat
        (+Z up), held as long as the simulator's hold.

    Returns
    -------
    list of (label, up)
        ``label`` like ``"face +Z up"``, ``"edge +X+Z up"`` or ``"pose 7"`` (1-based);
        ``up`` the nominal unit vector (3,) pointing away from the earth in the fixture frame,
        or None for ``random:N``.

    Raises
    ------
    InputError
        Unknown plan, or N outside 1..10000.
    """
    name = plan.strip().lower()
    if name == "six":
        return list(_faces())
    if name == "qureshi18":
        return list(_faces()) + _edges()
    m = _RANDOM_RE.fullmatch(name)
    if m:
        n = int(m.group(1))
        if not 1 <= n <= MAX_RANDOM_POSES:
            raise InputError(f"plan {plan!r}: N must be between 1 and {MAX_RANDOM_POSES}")
        return [(f"pose {k + 1}", None) for k in range(n)]
    if name.startswith("warmup:"):
        _minutes(name)
        return [("warm-up, +Z up", np.array([0.0, 0.0, 1.0]))]
    raise InputError(f"plan {plan!r} is unknown: use six, qureshi18 or random:N (N poses)")




def _from_poses(name: str) -> Plan:
    steps = tuple(Step("static", label, up=_unit_or_none(up)) for label, up in plan_poses(name))
    return Plan(name.strip().lower(), steps)


def _gyro_axes() -> Plan:
    steps = []
    for i, a in enumerate(_AXES):
        steps.append(Step("static", f"hold still before the turn about +{a}"))
        steps.append(Step("rotation", f"turn about +{a}", axis=np.eye(3)[i].copy()))
    steps.append(Step("static", "hold still after the last turn"))
    return Plan("gyro-axes", tuple(steps))


def _hwangbo_iron() -> Plan:
    faces = _from_poses("six").steps
    turns = tuple(
        Step(
            "rotation",
            f"turn 90 deg about the {f.label.split()[1]} face normal",
            axis=f.up,
            angle_deg=90.0,
        )
        for f in faces
    )
    return Plan("hwangbo-iron", faces + turns)


def _minutes(key: str) -> float:
    """The MINUTES of ``still:MINUTES`` / ``warmup:MINUTES``; refused unless positive."""
    name, _, text = key.partition(":")
    try:
        minutes = float(text.strip())
    except ValueError:
        minutes = float("nan")
    if not math.isfinite(minutes) or minutes <= 0:
        raise InputError(f"plan {name}:{text.strip()}: MINUTES must be a positive number, e.g. "
                         f"{name}:20")  # fmt: skip
    return minutes


def _still(key: str) -> Plan:
    """``still:MINUTES``: one static step held for the whole recording."""
    minutes = _minutes(key)
    step = Step("static", f"hold still for {minutes:g} min (noise)", hold_s=60.0 * minutes)
    return Plan(f"still:{minutes:g}", (step,))


def _warmup(key: str) -> Plan:
    """``warmup:MINUTES`` (issue 17.3): one still step through a warm-up or cool-down, the
    temperature logged; for ``imucal calibrate --warmup``."""
    minutes = _minutes(key)
    step = Step("static", f"leave it still for {minutes:g} min while it warms up or cools down "
                "(temperature logged)", hold_s=60.0 * minutes)  # fmt: skip
    return Plan(f"warmup:{minutes:g}", (step,))


def needs_temperature(plan: Plan) -> bool:
    """A plan whose recording is useless without the temperature (``warmup:MINUTES``)."""
    return plan.name.startswith("warmup:")


def _unit_or_none(v) -> np.ndarray | None:
    if v is None:
        return None
    v = np.asarray(v, dtype=np.float64).reshape(3)
    out = v / np.linalg.norm(v)
    out.flags.writeable = False
    return out


def load_plan(name_or_path: str) -> Plan:
    """A built-in plan by name, or a TOML plan file.

    Parameters
    ----------
    name_or_path : str
        ``six``, ``qureshi18``, ``random:N``, ``gyro-axes``, ``hwangbo-iron``, ``still:MINUTES``,
        or a path to a
        ``.toml`` file (see the module notes).

    Returns
    -------
    Plan

    Raises
    ------
    InputError
        Unknown plan, unreadable file or a bad step (one line naming the file and the step).
    """
    text = str(name_or_path).strip()
    key = text.lower()
    if key in ("six", "qureshi18") or key.startswith("random:"):
        return _from_poses(key)
    if key == "gyro-axes":
        return _gyro_axes()
    if key == "hwangbo-iron":
        return _hwangbo_iron()
    if key.startswith("still:"):
        return _still(key)
    if key.startswith("warmup:"):
        return _warmup(key)
    path = Path(text)
    if path.suffix.lower() == ".toml" or path.exists():
        return _load_file(path)
    raise InputError(
        f"plan {text!r} is unknown: use six, qureshi18, random:N, gyro-axes, hwangbo-iron, "
        "still:MINUTES, warmup:MINUTES or a .toml plan file"
    )


def _load_file(path: Path) -> Plan:
    src = str(path)
    if not path.is_file():
        raise InputError(f"{src}: no such plan file")
    from imucal_cli.formats.inputs import read_text_input

    text = read_text_input(path, what="plan file", max_bytes=1 << 20)
    try:
        data = tomllib.loads(text)
    except RecursionError:
        raise InputError(f"{src}: not valid TOML (nested too deeply)") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{src}: not valid TOML ({exc})") from None
    unknown = sorted(set(data) - {"name", "step"})
    if unknown:
        raise InputError(f"{src}: unknown key {unknown[0]!r} (expected name and [[step]])")
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"{src}: name must be a non-empty string")
    raw = data.get("step")
    if not isinstance(raw, list) or not raw:
        raise InputError(f"{src}: no steps (add [[step]] tables with kind = 'static' or ...)")
    steps = tuple(_parse_step(src, i + 1, item) for i, item in enumerate(raw))
    return Plan(name.strip(), steps)


def _parse_step(src: str, number: int, item) -> Step:
    where = f"{src}: step {number}"
    if not isinstance(item, dict):
        raise InputError(f"{where}: must be a table ([[step]])")
    unknown = sorted(set(item) - {"kind", "label", "up", "axis", "angle_deg"})
    if unknown:
        raise InputError(
            f"{where}: unknown key {unknown[0]!r} (expected kind, label, up, axis, angle_deg)"
        )
    kind = item.get("kind")
    if kind not in ("static", "rotation"):
        raise InputError(f"{where}: kind must be 'static' or 'rotation', got {kind!r}")
    label = item.get("label", f"step {number}")
    if not isinstance(label, str) or not label.strip():
        raise InputError(f"{where}: label must be a non-empty string, got {label!r}")
    wrong = ("axis", "angle_deg") if kind == "static" else ("up",)
    for key in wrong:
        if key in item:
            raise InputError(f"{where}: {key!r} does not apply to a {kind} step")
    vectors = {}
    for key in ("up", "axis"):
        if key in item:
            vectors[key] = _vector(where, key, item[key])
    angle = item.get("angle_deg")
    if angle is not None:
        if (
            isinstance(angle, bool)
            or not isinstance(angle, int | float)
            or not math.isfinite(angle)
        ):
            raise InputError(f"{where}: angle_deg must be a finite number, got {angle!r}")
        angle = float(angle)
    return Step(kind, label.strip(), up=vectors.get("up"), axis=vectors.get("axis"),
                angle_deg=angle)  # fmt: skip


def _vector(where: str, key: str, value) -> np.ndarray:
    ok = isinstance(value, list) and len(value) == 3
    ok = ok and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    if ok:
        v = np.asarray(value, dtype=np.float64)
        if np.isfinite(v).all() and np.linalg.norm(v) > 0:
            return _unit_or_none(v)
    raise InputError(f"{where}: {key} must be 3 finite numbers, not all zero, got {value!r}")
