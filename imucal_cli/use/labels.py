"""Labels of an existing session (``imucal label``): faces from the measured direction, one
segment's label, up, axis or angle set by hand.  Only ``/segments`` and root attributes change
(:func:`imucal_cli.formats.session.rewrite_labels`); raw data is never rewritten.

Faces: the mean accelerometer reading of each static segment, turned into a direction by a
calibration when one is given (or stored in the session), by the raw units when they are
physical (``m/s^2``, ``g``), else by an ellipsoid fitted to the poses themselves (9 poses or
more) or the mid-range of each axis (six faces); a pose within ``tolerance_deg`` of a +-axis
gets that face (``up`` is what the accelerometer reads, divided by g).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.estimators.ellipsoid import fit_ellipsoid
from imucal_cli.formats.session import TURN_ANGLE_RULE, Segment, Session, as_turn_angle
from imucal_cli.model.calibration import SensorCalibration

__all__ = ["FACE_TOLERANCE_DEG", "FaceCall", "call_faces", "face_label", "set_segment"]

FACE_TOLERANCE_DEG = 15.0
"""Default: a pose within this angle of a +-axis is that face (hand placement on a table)."""


@dataclass(frozen=True)
class FaceCall:
    """What :func:`call_faces` decided for one static segment.

    Attributes
    ----------
    segment : str
        Segment name.
    direction : ndarray, shape (3,)
        Measured unit direction of the accelerometer reading (up), sensor frame.
    up : ndarray, shape (3,), or None
        The face's up (a +-unit axis), or None when no axis is within the tolerance.
    off_deg : float
        Angle between ``direction`` and the nearest +-axis, degrees.
    """

    segment: str
    direction: np.ndarray
    up: np.ndarray | None
    off_deg: float


def face_label(up: np.ndarray) -> str:
    """``"face +Z up"`` for ``[0, 0, 1]``."""
    k = int(np.argmax(np.abs(up)))
    return f"face {'+' if up[k] > 0 else '-'}{'XYZ'[k]} up"


def _directions(
    session: Session, means: np.ndarray, calibration: SensorCalibration | None
) -> tuple[np.ndarray, str]:
    src = str(session.path or "session")
    if calibration is not None:
        return calibration.apply(means), "the calibration"
    if session.accel_units in ("m/s^2", "g"):
        return means, f"the raw {session.accel_units}"
    if len(means) >= 9:
        try:
            fit = fit_ellipsoid(means, 1.0)
        except ValueError:
            fit = None
        if fit is not None and fit.kind == "ellipsoid":
            return (fit.M @ (means - fit.bias).T).T, "an ellipsoid fitted to the poses"
    low, high = means.min(axis=0), means.max(axis=0)
    mid, half = (high + low) / 2, (high - low) / 2
    if np.all(half > 0):
        d = (means - mid) / half
        if np.all(np.abs(np.linalg.norm(d, axis=1) - 1) < 0.1):
            return d, "the mid-range of each axis over the poses"
    raise InputError(
        f"{src}: cannot tell the directions of raw {session.accel_units or 'unknown-unit'} "
        f"readings from these {len(means)} poses: pass --calibration CAL.json, or "
        "--accel-units if they are m/s^2 or g"
    )


def call_faces(
    session: Session,
    *,
    tolerance_deg: float = FACE_TOLERANCE_DEG,
    calibration: SensorCalibration | None = None,
) -> tuple[list[FaceCall], str]:
    """The face of each static segment from its measured direction.

    Returns
    -------
    calls : list of FaceCall
        One per static segment, in time order.
    basis : str
        How raw readings were turned into directions (for the user).

    Raises
    ------
    InputError
        No accelerometer or static segment, not 3 channels, directions that cannot be told.
    """
    src = str(session.path or "session")
    static = session.static_segments()
    if session.accel is None or not static:
        raise InputError(f"{src}: no static segments with accelerometer data to label")
    if session.accel.shape[1] != 3:
        raise InputError(f"{src}: faces need a 3-axis accelerometer, this one has "
                         f"{session.accel.shape[1]} channels")  # fmt: skip
    if not 0 < tolerance_deg < 45:
        raise InputError(f"--tolerance must be between 0 and 45 degrees, got {tolerance_deg:g}")
    means = np.array([session.accel[s.start : s.stop].mean(axis=0) for s in static])
    d, basis = _directions(session, means, calibration)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    calls = []
    for s, v in zip(static, d, strict=True):
        k = int(np.argmax(np.abs(v)))
        off = float(np.degrees(np.arccos(min(1.0, abs(v[k])))))
        up = None
        if off <= tolerance_deg:
            up = np.zeros(3)
            up[k] = np.sign(v[k])
        calls.append(FaceCall(segment=s.name, direction=v, up=up, off_deg=off))
    return calls, basis


def set_segment(
    segments: list[Segment],
    name: str,
    *,
    label: str | None = None,
    up: np.ndarray | None = None,
    axis: np.ndarray | None = None,
    angle_deg: float | None = None,
) -> list[Segment]:
    """The segments with segment ``name`` changed (the given fields only).

    Raises
    ------
    InputError
        No such segment, or a field that does not fit its kind (up on a rotation, axis or
        angle on a static segment).
    """
    if angle_deg is not None and as_turn_angle(angle_deg) is None:
        raise InputError(f"--angle must be {TURN_ANGLE_RULE}, got {angle_deg:g}")
    names = [s.name for s in segments]
    if name not in names:
        raise InputError(f"no segment {name!r} (the session has {', '.join(names) or 'none'})")
    out = []
    for s in segments:
        if s.name == name:
            if s.kind == "rotation" and up is not None:
                raise InputError(f"segment {name} is a rotation: it has an axis, not an up")
            if s.kind == "static" and (axis is not None or angle_deg is not None):
                raise InputError(f"segment {name} is static: it has an up, not an axis or angle")
            changes = {
                k: v
                for k, v in (("label", label), ("up", up), ("axis", axis), ("angle_deg", angle_deg))
                if v is not None
            }
            s = dataclasses.replace(s, **changes)
        out.append(s)
    return out
