"""Faults injected into a simulated session, to test and bench that they are found (issue 10.6).

Each function takes a session, its truth calibration and the index of a static segment (in
``session.static_segments()``) and returns a new session with that hold spoiled as a person
or a bench would spoil it:

* :func:`bump` - the unit was knocked and held in a shifted pose: a constant offset of the
  true acceleration (m/s^2) over the whole hold.
* :func:`spike` - a few samples of the hold far off (a glitch on the bus, a tap).
* :func:`slow_motion` - the unit tilted slowly during the hold (gravity turning by a few
  degrees from the start to the end).
* :func:`wrong_label` - the hold's ``up`` label turned by ``angle_deg`` (178 deg: the face
  opposite to the one that was up).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.formats.calibration import Calibration
from imucal_cli.formats.session import Session

FAULTS = ("bump", "spike", "slow-motion", "wrong-label")


def _hold(session: Session, k: int):
    return session.static_segments()[k]


def _sensitivity(truth: Calibration) -> np.ndarray:
    """Raw units per m/s^2 (the inverse of the calibration matrix)."""
    return np.linalg.pinv(np.asarray(truth.accel.matrix, float))


def bump(
    session: Session, truth: Calibration, k: int, offset_ms2: float, direction=None
) -> Session:
    """Hold ``k`` offset by ``offset_ms2`` (m/s^2) along ``direction`` (calibrated frame;
    default along the hold's gravity, the direction that spoils a fit most)."""
    seg = _hold(session, k)
    if direction is None:
        M = np.asarray(truth.accel.matrix, float)
        raw = session.accel[seg.start : seg.stop].mean(axis=0)
        direction = M @ (raw - np.asarray(truth.accel.bias, float))
    d = np.asarray(direction, float)
    accel = session.accel.copy()
    accel[seg.start : seg.stop] += _sensitivity(truth) @ (offset_ms2 * d / np.linalg.norm(d))
    return replace(session, accel=accel)


def spike(
    session: Session, truth: Calibration, k: int, size_ms2: float = 20.0, n: int = 3
) -> Session:
    """``n`` samples in the middle of hold ``k`` off by ``size_ms2`` (m/s^2) on every axis."""
    seg = _hold(session, k)
    accel = session.accel.copy()
    mid = (seg.start + seg.stop) // 2
    accel[mid : mid + n] += _sensitivity(truth) @ np.full(3, size_ms2)
    return replace(session, accel=accel)


def slow_motion(session: Session, truth: Calibration, k: int, angle_deg: float = 3.0) -> Session:
    """Hold ``k`` tilting steadily by ``angle_deg`` in total (about an axis across gravity)."""
    seg = _hold(session, k)
    S = _sensitivity(truth)
    M = np.asarray(truth.accel.matrix, float)
    b = np.asarray(truth.accel.bias, float)
    raw = session.accel[seg.start : seg.stop]
    f = (raw - b) @ M.T  # true specific force (plus noise)
    mean = f.mean(axis=0)
    axis = np.cross(mean, [1.0, 0.0, 0.0])
    if np.linalg.norm(axis) < 1e-6 * np.linalg.norm(mean):
        axis = np.cross(mean, [0.0, 1.0, 0.0])
    axis /= np.linalg.norm(axis)
    frac = np.linspace(-0.5, 0.5, len(raw))[:, None]
    turns = Rotation.from_rotvec(frac * np.radians(angle_deg) * axis)
    moved = turns.apply(np.tile(mean, (len(raw), 1))) - mean
    accel = session.accel.copy()
    accel[seg.start : seg.stop] = raw + moved @ S.T
    return replace(session, accel=accel)


def wrong_label(session: Session, k: int, angle_deg: float = 178.0) -> Session:
    """Hold ``k``'s ``up`` label turned by ``angle_deg`` about an axis across it."""
    seg = _hold(session, k)
    up = np.asarray(seg.up, float)
    axis = np.cross(up, [1.0, 0.0, 0.0])
    if np.linalg.norm(axis) < 1e-6:
        axis = np.cross(up, [0.0, 1.0, 0.0])
    axis /= np.linalg.norm(axis)
    new_up = Rotation.from_rotvec(np.radians(angle_deg) * axis).apply(up.copy())
    segments = [replace(s, up=new_up) if s is seg else s for s in session.segments]
    return replace(session, segments=segments)


def inject(session: Session, truth: Calibration, fault: str, k: int, size: float | None = None):
    """One of :data:`FAULTS` by name (``size``: m/s^2 for bump/spike, degrees otherwise)."""
    if fault == "bump":
        return bump(session, truth, k, 0.5 if size is None else size)
    if fault == "spike":
        return spike(session, truth, k, 20.0 if size is None else size)
    if fault == "slow-motion":
        return slow_motion(session, truth, k, 3.0 if size is None else size)
    if fault == "wrong-label":
        return wrong_label(session, k, 178.0 if size is None else size)
    raise ValueError(f"fault must be one of {FAULTS}, not {fault!r}")


def g_sensitive(session: Session, truth: Calibration, level: float, seed: int = 0
                ) -> tuple[Session, Calibration]:  # fmt: skip
    """A g-sensitive gyro (issue 24.6): each entry of ``C`` (rad/s per m/s^2 of specific
    force) drawn uniformly in +-``level`` from ``seed``, so that the gyro reads
    ``S (omega + C f) + b`` (rounded and clipped as the part's counts are). The specific force
    ``f`` is the session's accelerometer through its true calibration (the true force plus
    the accelerometer's own noise, which ``C`` scales to nothing). The truth's gyro section
    gains ``g_sensitivity`` (``S C``, raw units per m/s^2, the spec's term:
    ``calibrated = matrix @ (raw - bias - g_sensitivity @ a)``) and
    ``g_sensitivity_physical`` (``C``)."""
    if session.accel is None or session.gyro is None or truth.gyro is None:
        return session, truth
    C = level * np.random.default_rng([int(seed), 24, 6]).uniform(-1.0, 1.0, (3, 3))
    S = np.linalg.inv(np.asarray(truth.gyro.matrix, float))
    G = S @ C
    f = truth.accel.apply(session.accel)
    gyro = session.gyro + f @ G.T
    if np.issubdtype(np.asarray(session.gyro).dtype, np.integer) or (
            session.gyro_units == "counts"):  # fmt: skip
        # The counts are already rounded: rounding again would shift a still period by the
        # same fraction of a count in every sample (its rate is constant there). The part
        # rounds with its noise before it, which a dither of one count restores.
        dither = np.random.default_rng([int(seed), 24, 7]).uniform(-0.5, 0.5, gyro.shape)
        gyro = np.clip(np.rint(gyro + dither), -32768, 32767)
    gyro = gyro.astype(np.asarray(session.gyro).dtype, copy=False)
    sec = replace(truth.gyro, extra={**truth.gyro.extra, "g_sensitivity": G.tolist(),
                                     "g_sensitivity_physical": C.tolist(),
                                     "g_sensitivity_unit": f"{session.gyro_units} per m/s^2"})
    return replace(session, gyro=gyro), replace(truth, gyro=sec)
