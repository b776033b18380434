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

A package: :mod:`.model` (``Step``, ``Plan``, ``CaptureSummary``), :mod:`.builtin` (the
built-in plans' steps), :mod:`.files` (TOML plan files); the registry is here, and every name
is imported from here (``from imucal_cli.plans import load_plan``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.plans.builtin import (
    FERRARIS_TURN_DEG,
    GYRO_AXES_TURN_DEG,
    GYRO_MIN_TURNS,
    HK_FACES,
    HK_MOUNTINGS,
    HK_ORIENTATIONS,
    MAX_RANDOM_POSES,
    MAX_TURNS,
    QURESHI_TURNS_PER_AXIS,
    RANDOM_MINIMUM,
    RULER_TURN_DEG,
    TURNS_WHY,
    ferraris,
    free_turns,
    gyro_axes,
    hk_gyro_steps,
    hk_redundant,
    qureshi18,
    qureshi_axes,
    random_poses,
    six,
    still,
    warmup,
)
from imucal_cli.plans.files import load_file
from imucal_cli.plans.model import CaptureSummary, Plan, Step

__all__ = [
    "BUILTIN_PLANS",
    "FERRARIS_TURN_DEG",
    "GYRO_AXES_TURN_DEG",
    "GYRO_MIN_TURNS",
    "HK_FACES",
    "HK_MOUNTINGS",
    "HK_ORIENTATIONS",
    "MAX_RANDOM_POSES",
    "MAX_MINUTES",
    "MAX_TURNS",
    "QURESHI_TURNS_PER_AXIS",
    "RANDOM_MINIMUM",
    "RULER_TURN_DEG",
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
    PlanSpec("six", "the 6 faces of a cube", "poses", six),
    PlanSpec("qureshi18", "6 faces + 12 edges at 45 degrees, Qureshi & Golnaraghi", "poses",
             qureshi18),
    PlanSpec("random:N", f"N unlabelled static poses (N >= {RANDOM_MINIMUM})", "poses",
             random_poses, "count",
             minimum=(RANDOM_MINIMUM, "the gravity-magnitude model has 9 parameters, and N "
                      "unlabelled poses give at most N distinct directions (12 or more let the "
                      "fit check itself against the noise; plan six or qureshi18 for labelled "
                      "faces)")),
    PlanSpec("ferraris", "MaD Lab's Ferraris protocol: the 6 faces and a 360-degree turn on "
             "the table about each axis", "steps", ferraris),
    PlanSpec("gyro-axes", "a 360-degree turn on the table about each of +Z, +X, +Y", "steps",
             gyro_axes),
    PlanSpec("hwangbo-iron", "the 6 faces, then the hk-gyro procedure",
             "iron", lambda _arg: hk_gyro_steps(faces=True)),
    PlanSpec("hk-gyro", "sweeps about 3 faces of a right-angle iron in 2 mountings, then a "
             "ruler-guided 90-degree turn, Hwangbo & Kanade IV-B", "iron",
             lambda _arg: hk_gyro_steps()),
    PlanSpec("hk-redundant", "20 unlabelled orientations of a redundant accelerometer unit, "
             "Hwangbo & Kanade V", "redundant", hk_redundant),
    PlanSpec("qureshi-axes[:N]", "N hand turns, default 18, about x and y with +Z up, then "
             "about z with +X up, Qureshi & Golnaraghi Fig. 2", "rotations", qureshi_axes,
             "count?", minimum=(2, f"3 N turns, and {TURNS_WHY}")),
    PlanSpec("free:N", f"N hand turns about any axes, still between turns (N >= "
             f"{GYRO_MIN_TURNS})", "rotations", free_turns, "count",
             minimum=(GYRO_MIN_TURNS, f"{TURNS_WHY}; 12 or more let its still periods "
                      "calibrate the accelerometer too")),
    PlanSpec("still:MINUTES", "one still hold of MINUTES minutes, for imucal noise", "steps",
             still, "minutes"),
    PlanSpec("warmup:MINUTES", "one still hold, flat, through a warm-up or cool-down of MINUTES "
             "minutes, temperature logged, for imucal calibrate --warmup", "poses", warmup,
             "minutes", temperature=True),
)  # fmt: skip
"""Every built-in plan, in the order they are listed to the user."""

BUILTIN_PLANS = tuple(spec.name for spec in PLANS)

MAX_MINUTES = 7 * 24 * 60
"""The longest hold of ``still:MINUTES`` and ``warmup:MINUTES``: a week, in minutes."""


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
        if not (math.isfinite(minutes) and 0 < minutes <= MAX_MINUTES):
            raise InputError(f"plan {spec.key}:{arg_text}: MINUTES must be a positive number, "
                             f"at most {MAX_MINUTES} (a week), e.g. {spec.key}:20")  # fmt: skip
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
        return load_file(path)
    raise InputError(f"plan {text!r} is unknown: use {plan_list()} or a .toml plan file")
