"""Capture plans: the steps a person (or a bench script) goes through, and what was done.

One registry (:data:`PLANS`) names every protocol imucal offers; ``imucal capture`` (guided,
unattended), ``imucal simulate`` (file and ``--serve``) and the virtual device all take their
plan names and steps from it (:func:`load_plan`, :func:`find_plan`):

``six``
    The 6 faces of a cube, static, with ``up`` (``"face +Z up"``, ...).
``qureshi18``
    6 faces + 12 edges at 45 degrees (Qureshi & Golnaraghi section IV-B), static, with ``up``.
``random:N``
    N static poses, unlabelled (no ``up``).
``random:N`` needs N >= 9 (:data:`RANDOM_MINIMUM`): the gravity-magnitude model has 9
    parameters.
``ferraris``
    MaD Lab's Ferraris protocol (Ferraris et al. 1995, as the ``imucal`` package records it):
    for each of X, Y, Z the face with that axis up (``x_p``), one full turn on the table about
    it (-360 degrees: clockwise seen from above, ``x_rot``) back against a ruler, a still
    period, and the opposite face (``x_a``).
``gyro-axes``
    For each of +Z, +X, +Y: the unit flat on that face against a ruler (``up``), one full turn
    (360 degrees, known) about the vertical face normal back against the ruler, a still period.
``hwangbo-iron``
    Hwangbo & Kanade's right-angle iron: the 6 faces, then the gyroscope procedure of
    ``hk-gyro``.
``hk-gyro``
    Hwangbo & Kanade section IV-B: still, then sweeps about the +Z, +X, +Y face normals of the
    iron in mounting 1, the same in mounting 2 (the IMU re-mounted in the iron), and one
    ruler-guided 90-degree turn; every step carries its ``mounting``.
``hk-redundant``
    Hwangbo & Kanade section V: 20 unlabelled orientations of a redundant accelerometer unit.
``qureshi-axes[:N]``
    Qureshi & Golnaraghi Fig. 2: N (default 18) hand turns about x and about y with +Z up, then
    about z with +X up, each between still periods (angles free).
``free:N``
    N hand turns about any axes between still periods, starting flat with +Z up.
``still:MINUTES``
    One static step held for MINUTES minutes (``hold_s`` = 60 * MINUTES), no ``up``: a still
    recording for ``imucal noise`` (Allan deviation; bias instability needs tens of minutes).
``warmup:MINUTES``
    One static step, flat (+Z up), held for MINUTES minutes through a warm-up or cool-down (a
    cold start, a hair-dryer ramp), the temperature logged (``capture`` refuses columns without
    ``temp``): the recording for ``imucal calibrate --warmup`` (issue 17.3).

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
    mounting = 1                     # optional: the unit's mounting in the fixture (1, 2, ...)

``up`` and ``axis`` are scaled to unit length.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.inputs import read_text_input

__all__ = [
    "BUILTIN_PLANS",
    "PLANS",
    "CaptureSummary",
    "Plan",
    "PlanSpec",
    "Step",
    "find_plan",
    "hk_gyro_steps",
    "load_plan",
    "needs_temperature",
    "plan_help",
    "plan_list",
    "plan_poses",
]


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


# --------------------------------------------------------------------------------------------
# Built-ins
# --------------------------------------------------------------------------------------------

_AXES = "XYZ"
MAX_RANDOM_POSES = 10000
RANDOM_MINIMUM = 9
"""Fewest poses of ``random:N``: N unlabelled poses give at most N distinct gravity directions,
and the gravity-magnitude model has 9 parameters (Qureshi & Golnaraghi eqs. 3-8)."""
GYRO_MIN_TURNS = 5
"""Fewest turns of the turn plans: the gyro's 12-parameter model has 9 matrix entries, and a
turn measured by gravity gives 2 equations on them."""
_TURNS_WHY = (f"the gyro's 12-parameter model needs {GYRO_MIN_TURNS} turns (each gives 2 "
              "equations for the 9 of its matrix; with an accelerometer calibrated earlier, "
              "calibrate --accel CAL.json)")
FERRARIS_TURN_DEG = -360.0
"""MaD Lab's Ferraris turns: one full turn about the vertical axis, clockwise seen from above
(``imucal``'s default ``expected_angle``)."""
MAX_TURNS = 1000
QURESHI_TURNS_PER_AXIS = 18
HK_ORIENTATIONS = 20
HK_MOUNTINGS = 2
GYRO_AXES_TURN_DEG = 360.0
RULER_TURN_DEG = 90.0
HK_FACES = ((2, "+Z"), (0, "+X"), (1, "+Y"))
"""Face normals the iron is swept about, in the order visited (Hwangbo & Kanade IV-B)."""


def _sign(s: float) -> str:
    return "+" if s > 0 else "-"


def _axis(i: int, scale: float = 1.0) -> tuple[float, float, float]:
    """``scale`` times the unit vector of axis ``i`` (0, 1, 2 = X, Y, Z)."""
    return tuple(scale if k == i else 0.0 for k in range(3))


def _faces() -> list[tuple[str, tuple]]:
    out = []
    for i in (2, 0, 1):  # +Z first: the unit starts flat on the table
        for s in (1.0, -1.0):
            out.append((f"face {_sign(s)}{_AXES[i]} up", _axis(i, s)))
    return out


def _edges() -> list[tuple[str, tuple]]:
    out = []
    r = math.sqrt(2.0)
    for i, j in ((0, 1), (0, 2), (1, 2)):
        for si in (1.0, -1.0):
            for sj in (1.0, -1.0):
                up = [0.0, 0.0, 0.0]
                up[i], up[j] = si / r, sj / r
                label = f"edge {_sign(si)}{_AXES[i]}{_sign(sj)}{_AXES[j]} up"
                out.append((label, tuple(up)))
    return out


def plan_poses(plan: str) -> list[tuple[str, np.ndarray | None]]:
    """The poses of a static plan, in the order they are visited.

    Parameters
    ----------
    plan : str
        ``six`` (the 6 faces of a cube), ``qureshi18`` (6 faces + 12 edges at 45 degrees,
        Qureshi & Golnaraghi section IV-B) or ``random:N`` (N unlabelled poses; the simulator
        draws their directions uniformly on the sphere).

    Returns
    -------
    list of (label, up)
        ``label`` like ``"face +Z up"``, ``"edge +X+Z up"`` or ``"pose 7"`` (1-based);
        ``up`` the nominal unit vector (3,) pointing away from the earth in the fixture frame,
        or None for ``random:N``.

    Raises
    ------
    InputError
        Not a static plan, or N outside 1..10000.
    """
    spec, arg = find_plan(plan)
    if spec is None or spec.simulator != "poses":
        raise InputError(f"plan {plan!r} is unknown: use six, qureshi18 or random:N (N poses)")
    return [(s.label, s.up) for s in spec.build(arg).steps]


def _frozen(v) -> np.ndarray | None:
    """A read-only copy of a built-in unit vector (exact as written: not re-normalised)."""
    if v is None:
        return None

    out = np.array(v, dtype=np.float64).reshape(3)
    out.flags.writeable = False
    return out


def _static(label: str, up=None, **kw) -> Step:
    return Step("static", label, up=_frozen(up), **kw)


def _rotation(label: str, axis=None, **kw) -> Step:
    return Step("rotation", label, axis=_frozen(axis), **kw)


def _six(_arg=None) -> tuple[Step, ...]:
    return tuple(_static(label, up) for label, up in _faces())


def _qureshi18(_arg=None) -> tuple[Step, ...]:
    return tuple(_static(label, up) for label, up in _faces() + _edges())


def _random(n: int) -> tuple[Step, ...]:
    return tuple(_static(f"pose {k + 1}") for k in range(n))


def _gyro_axes(_arg=None) -> tuple[Step, ...]:
    """For +Z, +X, +Y: flat on that face, one full turn about the vertical, still again."""
    steps = []
    for i in (2, 0, 1):
        a = _AXES[i]
        steps.append(_static(f"face +{a} up, against a ruler", _axis(i)))
        turn = f"turn about +{a} by {GYRO_AXES_TURN_DEG:g} deg, back against the ruler"
        steps.append(_rotation(turn, _axis(i), angle_deg=GYRO_AXES_TURN_DEG))
        steps.append(_static(f"still after the turn about +{a}"))
    return tuple(steps)


def _ferraris(_arg=None) -> tuple[Step, ...]:
    """MaD Lab's Ferraris protocol: per axis its ``_p`` face, the full turn about it on the
    table (``_rot``), a still period, then its ``_a`` face."""
    steps = []
    for i in (0, 1, 2):
        a, name = _AXES[i], _AXES[i].lower()
        steps.append(_static(f"face +{a} up ({name}_p), against a ruler", _axis(i)))
        turn = (f"turn about +{a} (up) by {FERRARIS_TURN_DEG:g} deg: one full turn clockwise "
                f"seen from above, back against the ruler ({name}_rot)")  # fmt: skip
        steps.append(_rotation(turn, _axis(i), angle_deg=FERRARIS_TURN_DEG))
        steps.append(_static(f"still after the turn about +{a}"))
        steps.append(_static(f"face -{a} up ({name}_a)", _axis(i, -1.0)))
    return tuple(steps)


def hk_gyro_steps(
    mountings: int = HK_MOUNTINGS, faces: bool = False, ruler_deg: float = RULER_TURN_DEG
) -> tuple[Step, ...]:
    """Hwangbo & Kanade IV-B: sweeps about three orthogonal faces per mounting, a ruler turn
    of ``ruler_deg``; with ``faces``, the 6 faces of the iron first (plan ``hwangbo-iron``).

    ``up`` is known in mounting 1 only (there the sensor is aligned with the iron)."""
    eye, ez = [_axis(i) for i in range(3)], _axis(2)
    steps = [_static(label, up, mounting=1) for label, up in _faces()] if faces else []
    steps.append(_static("mounting 1: still, +Z up (biases)", ez, mounting=1))
    for m in range(1, mountings + 1):
        for k, (face, name) in enumerate(HK_FACES):
            up = eye[face] if m == 1 else None
            if m > 1 or k > 0:
                steps.append(_static(f"mounting {m}: still, {name} up", up, mounting=m))
            steps.append(_rotation(f"mounting {m}: sweep about {name}", eye[face], mounting=m))
            steps.append(
                _static(f"mounting {m}: still after the sweep about {name}", up, mounting=m)
            )
    ruler = f"mounting 1: ruler-guided {ruler_deg:g}-degree turn about +Z"
    steps += [
        _static("mounting 1: still, +Z up, iron against the ruler", ez, mounting=1),
        _rotation(ruler, ez, angle_deg=float(ruler_deg), mounting=1),
        _static("mounting 1: still, +Z up, after the ruler turn", ez, mounting=1),
    ]
    return tuple(steps)


def _hk_redundant(_arg=None) -> tuple[Step, ...]:
    return tuple(_static(f"orientation {k + 1}") for k in range(HK_ORIENTATIONS))


def _qureshi_axes(n: int | None) -> tuple[Step, ...]:
    """Qureshi & Golnaraghi Fig. 2: turns about x and y with +Z up, about z with +X up."""
    n = QURESHI_TURNS_PER_AXIS if n is None else n
    steps = []
    for i, face, face_label in ((0, 2, "+Z"), (1, 2, "+Z"), (2, 0, "+X")):
        tag = f"{'xyz'[i]} turn"
        for k in range(1, n + 1):
            where = f", {face_label} up" if k == 1 else ""
            up = _axis(face) if k == 1 else None
            steps.append(_static(f"still before {tag} {k}{where}", up))
            steps.append(_rotation(f"turn {k} about {'xyz'[i]}", _axis(i)))
        steps.append(_static(f"still after {tag} {n}"))
    return tuple(steps)


def _free(n: int) -> tuple[Step, ...]:
    steps = []
    for k in range(1, n + 1):
        up = _axis(2) if k == 1 else None
        steps.append(_static(f"still before turn {k}" + (", +Z up" if k == 1 else ""), up))
        steps.append(_rotation(f"turn {k}"))
    steps.append(_static(f"still after turn {n}"))
    return tuple(steps)


def _still(minutes: float) -> tuple[Step, ...]:
    """``still:MINUTES``: one static step held for the whole recording."""
    return (Step("static", f"hold still for {minutes:g} min (noise)", hold_s=60.0 * minutes),)


def _warmup(minutes: float) -> tuple[Step, ...]:
    """``warmup:MINUTES`` (issue 17.3): one still step, flat, through a warm-up or cool-down."""
    label = f"leave it still, +Z up, for {minutes:g} min while it warms up or cools down " \
        "(temperature logged)"
    return (_static(label, (0.0, 0.0, 1.0), hold_s=60.0 * minutes),)


@dataclass(frozen=True)
class PlanSpec:
    """One built-in plan of the registry.

    Attributes
    ----------
    name : str
        What the user types, with its argument's name: ``"six"``, ``"random:N"``,
        ``"qureshi-axes[:N]"``.
    summary : str
        One line for ``--help`` and error messages.
    simulator : str
        Which virtual experiment of :mod:`imucal_cli.simulate` plays it: ``"poses"`` (the
        triad on poses), ``"rotations"`` (hand turns), ``"iron"`` (Hwangbo & Kanade's iron),
        ``"redundant"`` (the redundant unit) or ``"steps"`` (any list of steps).
    steps : callable
        ``steps(arg) -> tuple of Step`` from the parsed argument (None when absent).
    arg : str or None
        ``"count"`` (an integer, required), ``"count?"`` (optional), ``"minutes"`` or None.
    temperature : bool
        The recording is useless without the temperature (``capture`` refuses a stream
        without it).
    minimum : int and str
        The smallest count the plan calibrates with, and why (a smaller one is refused by
        :func:`find_plan`, so by capture and simulate, with the minimum stated).
    """

    name: str
    summary: str
    simulator: str
    steps: Callable[[Any], tuple[Step, ...]]
    arg: str | None = None
    temperature: bool = False
    minimum: tuple[int, str] = (1, "")

    @property
    def key(self) -> str:
        """The name without its argument: ``random``, ``qureshi-axes``."""
        return self.name.split(":")[0].split("[")[0]

    def build(self, arg=None) -> Plan:
        """The plan for a parsed argument (see :func:`find_plan`)."""
        name = self.key if arg is None else f"{self.key}:{arg:g}"
        return Plan(name, self.steps(arg))


PLANS: tuple[PlanSpec, ...] = (
    PlanSpec("six", "the 6 faces of a cube", "poses", _six),
    PlanSpec("qureshi18", "6 faces + 12 edges at 45 degrees, Qureshi & Golnaraghi", "poses",
             _qureshi18),
    PlanSpec("random:N", f"N unlabelled static poses (N >= {RANDOM_MINIMUM})", "poses",
             _random, "count",
             minimum=(RANDOM_MINIMUM, "the gravity-magnitude model has 9 parameters, and N "
                      "unlabelled poses give at most N distinct directions (12 or more let the "
                      "fit check itself against the noise; plan six or qureshi18 for labelled "
                      "faces)")),
    PlanSpec("ferraris", "MaD Lab's Ferraris protocol: the 6 faces and a 360-degree turn on "
             "the table about each axis", "steps", _ferraris),
    PlanSpec("gyro-axes", "a 360-degree turn on the table about each of +Z, +X, +Y", "steps",
             _gyro_axes),
    PlanSpec("hwangbo-iron", "the 6 faces, then the hk-gyro procedure",
             "iron", lambda _arg: hk_gyro_steps(faces=True)),
    PlanSpec("hk-gyro", "sweeps about 3 faces of a right-angle iron in 2 mountings, then a "
             "ruler-guided 90-degree turn, Hwangbo & Kanade IV-B", "iron",
             lambda _arg: hk_gyro_steps()),
    PlanSpec("hk-redundant", "20 unlabelled orientations of a redundant accelerometer unit, "
             "Hwangbo & Kanade V", "redundant", _hk_redundant),
    PlanSpec("qureshi-axes[:N]", "N hand turns, default 18, about x and y with +Z up, then "
             "about z with +X up, Qureshi & Golnaraghi Fig. 2", "rotations", _qureshi_axes,
             "count?", minimum=(2, f"3 N turns, and {_TURNS_WHY}")),
    PlanSpec("free:N", f"N hand turns about any axes, still between turns (N >= "
             f"{GYRO_MIN_TURNS})", "rotations", _free, "count",
             minimum=(GYRO_MIN_TURNS, f"{_TURNS_WHY}; 12 or more let its still periods "
                      "calibrate the accelerometer too")),
    PlanSpec("still:MINUTES", "one still hold of MINUTES minutes, for imucal noise", "steps",
             _still, "minutes"),
    PlanSpec("warmup:MINUTES", "one still hold, flat, through a warm-up or cool-down of MINUTES "
             "minutes, temperature logged, for imucal calibrate --warmup", "poses", _warmup,
             "minutes", temperature=True),
)  # fmt: skip
"""Every built-in plan, in the order they are listed to the user."""

BUILTIN_PLANS = tuple(spec.name for spec in PLANS)


def plan_list() -> str:
    """The plan names for a message: ``six, qureshi18, random:N, ...``."""
    return ", ".join(BUILTIN_PLANS)


def plan_help() -> str:
    """Every plan with its summary, for ``--help``: ``six: the 6 faces of a cube; ...``."""
    items = "; ".join(f"{p.name}: {p.summary}" for p in PLANS)
    return f"{items}; or a TOML plan file ([[step]] kind, label, up, axis, angle_deg, mounting)."


def find_plan(name: str) -> tuple[PlanSpec | None, Any]:
    """The registry entry of a plan name and its parsed argument; (None, None) when the name
    is no built-in plan (it may be a plan file).

    Raises
    ------
    InputError
        A built-in plan with a bad argument (``random:0``, ``still:abc``, ``free`` without N).
    """
    text = str(name).strip()
    key, colon, arg_text = text.lower().partition(":")
    spec = next((p for p in PLANS if p.key == key), None)
    if spec is None:
        return None, None
    if not colon:
        if spec.arg in ("count", "minutes"):
            raise InputError(f"plan {text!r}: say how many, as in {spec.name}")
        return spec, None
    if spec.arg is None:
        raise InputError(f"plan {text!r}: {spec.key} takes no argument")
    arg_text = arg_text.strip()
    if spec.arg == "minutes":
        try:
            minutes = float(arg_text)
        except ValueError:
            minutes = float("nan")
        if not math.isfinite(minutes) or minutes <= 0:
            raise InputError(f"plan {spec.key}:{arg_text}: MINUTES must be a positive number, "
                             f"e.g. {spec.key}:20")  # fmt: skip
        return spec, minutes
    high = MAX_RANDOM_POSES if spec.key == "random" else MAX_TURNS
    if not re.fullmatch(r"\d+", arg_text) or not 1 <= int(arg_text) <= high:
        raise InputError(f"plan {text!r}: N must be between {spec.minimum[0]} and {high}")
    low, why = spec.minimum
    if int(arg_text) < low:
        raise InputError(f"plan {text!r}: N must be at least {low}: {why}")
    return spec, int(arg_text)


def needs_temperature(plan: Plan) -> bool:
    """A registry plan whose recording is useless without the temperature
    (``warmup:MINUTES``); plan files never are."""
    try:
        spec, _ = find_plan(plan.name)
    except InputError:
        return False
    return spec is not None and spec.temperature


def _unit_or_none(v) -> np.ndarray | None:
    if v is None:
        return None

    v = np.asarray(v, dtype=np.float64).reshape(3)
    out = v / np.linalg.norm(v)
    out.flags.writeable = False
    return out


def load_plan(name_or_path: str) -> Plan:
    """A built-in plan by name (:data:`PLANS`), or a TOML plan file.

    Parameters
    ----------
    name_or_path : str
        A name of :data:`BUILTIN_PLANS` (``six``, ``random:12``, ``still:20``, ...), or a path
        to a ``.toml`` file (see the module notes).

    Returns
    -------
    Plan

    Raises
    ------
    InputError
        Unknown plan, unreadable file or a bad step (one line naming the file and the step).
    """
    text = str(name_or_path).strip()
    spec, arg = find_plan(text)
    if spec is not None:
        return spec.build(arg)
    path = Path(text)
    if path.suffix.lower() == ".toml" or path.exists():
        return _load_file(path)
    raise InputError(f"plan {text!r} is unknown: use {plan_list()} or a .toml plan file")


def _load_file(path: Path) -> Plan:
    src = str(path)
    if not path.is_file():
        raise InputError(f"{src}: no such plan file")

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
    unknown = sorted(set(item) - {"kind", "label", "up", "axis", "angle_deg", "mounting"})
    if unknown:
        raise InputError(
            f"{where}: unknown key {unknown[0]!r} "
            "(expected kind, label, up, axis, angle_deg, mounting)"
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
    mounting = item.get("mounting")
    if mounting is not None and (
        isinstance(mounting, bool) or not isinstance(mounting, int) or mounting < 1
    ):
        raise InputError(f"{where}: mounting must be an integer >= 1, got {mounting!r}")
    return Step(kind, label.strip(), up=vectors.get("up"), axis=vectors.get("axis"),
                angle_deg=angle, mounting=mounting)  # fmt: skip


def _vector(where: str, key: str, value) -> np.ndarray:
    ok = isinstance(value, list) and len(value) == 3
    ok = ok and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    if ok:
        v = np.asarray(value, dtype=np.float64)
        if np.isfinite(v).all() and np.linalg.norm(v) > 0:
            return _unit_or_none(v)
    raise InputError(f"{where}: {key} must be 3 finite numbers, not all zero, got {value!r}")
