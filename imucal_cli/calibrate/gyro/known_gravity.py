"""Turns of known angle checked against gravity (issue 24.5): what the accelerometer sees of
the turns and moves between still periods, which no known angle enters.

A design of known turns alone (plan gyro-axes: one full turn about each axis, 0 spare
equations) cannot check its angles against each other; gravity can still check them:

* **a known turn's ends**: a turn by ``angle`` about ``axis`` carries the gravity direction
  the accelerometer reads at its start (at rest: each turn is integrated from rest to rest)
  to a direction it predicts for its end. A turn about the vertical leaves gravity where it
  was whatever its angle (nothing to check); about any other axis a wrong angle ends
  elsewhere (a 270-degree turn about a horizontal axis ends 90 degrees from where a
  360-degree one ends);
* **the moves between still periods** that are not known turns (from one face to the next):
  integrated with the gyro the known angles calibrated, they carry gravity to where the
  accelerometer sees it, or, where those angles are wrong (every gain 25 % small when the
  turns were 270 degrees, not 360), far from it.

Gravity is read with the accelerometer calibration where there is one, else from the raw
accelerometer (its axes taken for the labels', as the gyro's are without one: a few degrees
at most, where its labelled still periods show it; not checked where they do not), so the
check is coarse: a miss beyond :data:`TOLERANCE_DEG` is a known angle that
disagrees with gravity, far beyond the placement of a turn's axis, the angle's stated error,
a hand's flip, or an accelerometer held at nominal values.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.design.gaps import find_gaps, gaps_within
from imucal_cli.formats.session import Segment, Session

#: A miss of gravity beyond this (deg) is a disagreement with the known angles.
TOLERANCE_DEG = 10.0
#: ... and beyond this many std of the gyro's prediction (:func:`moves`).
MISS_STDS = 4.0
#: Samples at each end of a known turn (integrated from rest to rest) that give the gravity
#: direction it starts and ends in: the turn's own, so that a still period recorded apart
#: from it (a session joined from pieces) is not taken for its start.
EDGE = 10
#: Fewest samples between two still periods that make a move (none: pieces joined end to end,
#: the unit moved unrecorded).
MIN_MOVE = 10


def _direction(session: Session, seg: Segment, accel_cal, rows: slice | None = None
               ) -> np.ndarray | None:  # fmt: skip
    """The gravity direction over a segment's samples (or ``rows``), unit vector."""
    a = session.accel[rows if rows is not None else slice(seg.start, seg.stop)]
    a = a[np.isfinite(a).all(axis=1)]
    if not len(a):
        return None
    g = a.mean(axis=0)
    if accel_cal is not None:
        g = accel_cal.apply(g)
    n = float(np.linalg.norm(g))
    return g / n if n > 0 else None


def _angle(u: np.ndarray, v: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(u @ v, -1.0, 1.0))))


def _integrate(session: Session, M: np.ndarray, b: np.ndarray, start: int, stop: int
               ) -> Rotation:  # fmt: skip
    """The attitude change over samples ``start .. stop - 1`` with the rate ``M (z - b)``
    (body frame, trapezoid increments composed in order)."""
    w = (session.gyro[start:stop] - b) @ np.asarray(M, float).T
    dt = np.diff(session.time[start:stop])[:, None]
    phi = 0.5 * (w[1:] + w[:-1]) * dt
    out = Rotation.identity()
    for step in Rotation.from_rotvec(phi):
        out = out * step
    return out


def _miss_std_deg(session: Session, M: np.ndarray, b: np.ndarray, start: int, stop: int,
                  pred: np.ndarray, cov_M: np.ndarray) -> float:  # fmt: skip
    """Std (deg) of a move's predicted gravity direction ``pred`` from the uncertainty of
    ``M`` (``cov_M``, (9, 9), row-major), to first order: an error ``dM`` turns the end
    attitude by ``dtheta = sum_k C_k^T dM z_k dt_k`` (``C_k`` the attitude change from step k
    to the end, body frame), and the prediction ``R^T u0`` by ``[pred]_x dtheta``."""
    z = session.gyro[start:stop] - b
    w = z @ np.asarray(M, float).T
    dt = np.diff(session.time[start:stop])
    zm = 0.5 * (z[1:] + z[:-1])
    steps = Rotation.from_rotvec(0.5 * (w[1:] + w[:-1]) * dt[:, None]).as_matrix()
    J = np.zeros((3, 9))
    C = np.eye(3)  # from after step k to the end, filled backwards
    for k in range(len(dt) - 1, -1, -1):
        J += C.T @ np.kron(np.eye(3), zm[k]) * dt[k]  # d(M z_k) / d vec(M), row-major
        C = steps[k] @ C
    px = np.array([[0.0, -pred[2], pred[1]], [pred[2], 0.0, -pred[0]],
                   [-pred[1], pred[0], 0.0]])  # fmt: skip
    Jp = px @ J
    return float(np.degrees(np.sqrt(max(np.trace(Jp @ cov_M @ Jp.T), 0.0))))


def known_turn_ends(session: Session, accel_cal, used, axes: np.ndarray,
                    axis_sigma: np.ndarray | None = None) -> list[str]:  # fmt: skip
    """Known turns whose end attitude gravity sees away from where their angle ends them:
    beyond the tolerance (the accelerometer's reading at the turn's moving edges, and without
    a calibration its own errors) plus :data:`MISS_STDS` times what the axis' own error moves
    the end (``axis_sigma``, rad per tangent component: a turn by ``theta`` about an axis off
    by ``eps`` ends up to ``2 |sin(theta / 2)| |eps|`` away; hand turns 2 deg RMS off their
    labels put 134- and 160-degree turns' ends 10.2-10.8 deg from the labels' prediction, 2
    seeds in 20, 9.6-10.5 with the true accelerometer). A 360-degree turn's end is its start
    whatever the axis: a 270-degree one is still 90 deg off it."""
    out = []
    sigma = np.zeros(len(used)) if axis_sigma is None else np.asarray(axis_sigma, float)
    for seg, axis, s in zip(used, axes, sigma, strict=True):
        k = min(EDGE, (seg.stop - seg.start) // 10)
        if k < 1:
            continue
        u0 = _direction(session, seg, accel_cal, slice(seg.start, seg.start + k))
        u1 = _direction(session, seg, accel_cal, slice(seg.stop - k, seg.stop))
        if u0 is None or u1 is None:
            continue
        turn = Rotation.from_rotvec(np.radians(seg.angle_deg) * np.asarray(axis, float))
        pred = turn.inv().apply(u0)
        by_axis = np.degrees(2 * abs(np.sin(np.radians(seg.angle_deg) / 2)) * s)
        if _angle(pred, u1) > TOLERANCE_DEG + MISS_STDS * by_axis:
            ends_at = _angle(u0, pred)
            out.append(f"{seg.label or seg.name}: the accelerometer sees it end "
                       f"{_angle(u0, u1):.0f} deg from where it started; a {seg.angle_deg:g}-"
                       "degree turn about its axis ends " + (
                           "where it started" if ends_at < 1 else
                           f"{ends_at:.0f} deg from there"))  # fmt: skip
    return out


def moves(session: Session, accel_cal, M: np.ndarray, b: np.ndarray, known,
          cov_M: np.ndarray | None = None) -> tuple[list[str], int]:  # fmt: skip
    """The moves between consecutive still periods that hold no known turn, integrated with
    the gyro ``M``, ``b``: those that miss gravity by more than the tolerance (in words), and
    how many were checked. With ``cov_M`` (the uncertainty of ``M``, (9, 9)) a miss must
    also exceed :data:`MISS_STDS` times its own std: labels placed 5 degrees off put a
    known-turn gyro's axes degrees off, and a 170-degree move 15 degrees from gravity."""
    statics = sorted(session.static_segments(), key=lambda s: s.start)
    gaps = find_gaps(session.time)
    out, checked = [], 0
    for s0, s1 in zip(statics[:-1], statics[1:], strict=True):
        if s1.start - s0.stop < MIN_MOVE or any(k.start < s1.start and k.stop > s0.stop
                                                for k in known):  # fmt: skip
            continue
        if gaps and gaps_within(gaps, s0.stop - 1, s1.start + 1):
            continue
        u0, u1 = _direction(session, s0, accel_cal), _direction(session, s1, accel_cal)
        if u0 is None or u1 is None:
            continue
        checked += 1
        pred = _integrate(session, M, b, s0.stop - 1, s1.start + 1).inv().apply(u0)
        miss = _angle(pred, u1)
        std = 0.0 if cov_M is None else _miss_std_deg(session, M, b, s0.stop - 1,
                                                       s1.start + 1, pred, cov_M)  # fmt: skip
        if miss > max(TOLERANCE_DEG, MISS_STDS * std):
            within = "" if cov_M is None else f" (its std {std:.2g} deg)"
            out.append(f"from {s0.label or s0.name} to {s1.label or s1.name} the "
                       f"accelerometer sees gravity turn {_angle(u0, u1):.0f} deg, the gyro "
                       f"turns it {_angle(u0, pred):.0f} deg, to {miss:.0f} deg from "
                       f"there{within}")  # fmt: skip
    return out, checked


def _raw_in_labels(session: Session) -> bool:
    """Without an accelerometer calibration: do the raw accelerometer's axes read the labels'
    frame (each still period with an ``up`` label within twice the tolerance of it, one at
    least)? A part mounted turned, or an axis of opposite sign, cannot check the gyro."""
    labelled = [s for s in session.static_segments() if s.up is not None]
    for seg in labelled:
        u = _direction(session, seg, None)
        up = np.asarray(seg.up, float) / np.linalg.norm(seg.up)
        if u is None or _angle(u, up) > 2 * TOLERANCE_DEG:
            return False
    return bool(labelled)


def gravity_disagreement(session: Session, accel_cal, used, axes: np.ndarray, M: np.ndarray,
                         b: np.ndarray, cov_M: np.ndarray | None = None,
                         axis_sigma: np.ndarray | None = None) -> str | None:  # fmt: skip
    """A warning where gravity disagrees with the known angles (module notes), else None;
    ``cov_M``: the uncertainty of ``M`` (:func:`moves`); ``axis_sigma``: of each known
    turn's axis (:func:`known_turn_ends`)."""
    if session.accel is None or (accel_cal is None and not _raw_in_labels(session)):
        return None
    ends = known_turn_ends(session, accel_cal, used, axes, axis_sigma)
    missed, checked = moves(session, accel_cal, M, b, used, cov_M)
    if not ends and not missed:
        return None
    parts = []
    if ends:
        parts.append("; ".join(ends))
    if missed:
        more = f" and {len(missed) - 3} more" if len(missed) > 3 else ""
        parts.append(f"{len(missed)} of the {checked} moves between still periods, integrated "
                     f"with the gyro the known angles give, miss where the accelerometer sees "
                     f"gravity by more than {TOLERANCE_DEG:g} deg: {'; '.join(missed[:3])}"
                     f"{more}")  # fmt: skip
    return ("the turns of known angle disagree with what gravity measures (" + "; ".join(parts)
            + "): a turn's angle or axis is wrong (check angle_deg and that the unit ended "
            "against the stop it started from), or it was turned more or less than "
            "labelled")  # fmt: skip
