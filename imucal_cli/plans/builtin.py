"""The steps of the built-in plans (:data:`imucal_cli.plans.PLANS`): the faces and edges of a
cube, the turn plans (Ferraris, gyro axes, Qureshi & Golnaraghi, free turns), Hwangbo & Kanade's
iron and redundant unit, still and warm-up holds; and the counts they need.
"""

from __future__ import annotations

import math

import numpy as np

from imucal_cli.plans.model import Step

_AXES = "XYZ"
MAX_RANDOM_POSES = 10000
RANDOM_MINIMUM = 9
"""Fewest poses of ``random:N``: N unlabelled poses give at most N distinct gravity directions,
and the gravity-magnitude model has 9 parameters (Qureshi & Golnaraghi eqs. 3-8)."""
GYRO_MIN_TURNS = 5
"""Fewest turns of the turn plans: the gyro's 12-parameter model has 9 matrix entries, and a
turn measured by gravity gives 2 equations on them."""
TURNS_WHY = (f"the gyro's 12-parameter model needs {GYRO_MIN_TURNS} turns (each gives 2 "
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


def six(_arg=None) -> tuple[Step, ...]:
    return tuple(_static(label, up) for label, up in _faces())


def qureshi18(_arg=None) -> tuple[Step, ...]:
    return tuple(_static(label, up) for label, up in _faces() + _edges())


def random_poses(n: int) -> tuple[Step, ...]:
    return tuple(_static(f"pose {k + 1}") for k in range(n))


def gyro_axes(_arg=None) -> tuple[Step, ...]:
    """For +Z, +X, +Y: flat on that face, one full turn about the vertical, still again."""
    steps = []
    for i in (2, 0, 1):
        a = _AXES[i]
        steps.append(_static(f"face +{a} up, against a ruler", _axis(i)))
        turn = f"turn about +{a} by {GYRO_AXES_TURN_DEG:g} deg, back against the ruler"
        steps.append(_rotation(turn, _axis(i), angle_deg=GYRO_AXES_TURN_DEG))
        steps.append(_static(f"still after the turn about +{a}"))
    return tuple(steps)


def ferraris(_arg=None) -> tuple[Step, ...]:
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


def hk_redundant(_arg=None) -> tuple[Step, ...]:
    return tuple(_static(f"orientation {k + 1}") for k in range(HK_ORIENTATIONS))


def qureshi_axes(n: int | None) -> tuple[Step, ...]:
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


def free_turns(n: int) -> tuple[Step, ...]:
    steps = []
    for k in range(1, n + 1):
        up = _axis(2) if k == 1 else None
        steps.append(_static(f"still before turn {k}" + (", +Z up" if k == 1 else ""), up))
        steps.append(_rotation(f"turn {k}"))
    steps.append(_static(f"still after turn {n}"))
    return tuple(steps)


def still(minutes: float) -> tuple[Step, ...]:
    """``still:MINUTES``: one static step held for the whole recording."""
    return (Step("static", f"hold still for {minutes:g} min (noise)", hold_s=60.0 * minutes),)


def warmup(minutes: float) -> tuple[Step, ...]:
    """``warmup:MINUTES`` (issue 17.3): one still step, flat, through a warm-up or cool-down."""
    label = f"leave it still, +Z up, for {minutes:g} min while it warms up or cools down " \
        "(temperature logged)"
    return (_static(label, (0.0, 0.0, 1.0), hold_s=60.0 * minutes),)
