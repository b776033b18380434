"""The magnetometer for the flight controllers' exporters (PX4, ArduPilot): imucal's ``mag``
section rewritten for what their drivers publish, and what their model cannot hold.

imucal's model is ``h = W (raw - b)`` (uT, or units of the local field), ``W`` a full matrix
that also rotates the magnetometer onto the accelerometer's frame.  PX4 and ArduPilot take the
field as the driver publishes it (PX4 ``sensor_mag`` in gauss, ArduPilot in milligauss), in
the frame the driver has already rotated it to, and correct it with an offset and a
**symmetric** matrix.  So, with ``p = f raw`` what the driver publishes (``f`` target units per
raw unit: exact for raw uT, nT or gauss, else ``--mag-scale`` in uT per raw unit):

    h = M (p - f b),     M = W_uT / (uT per raw unit)   (dimensionless),   M = R P (polar)

and the target gets ``f b`` and ``P``; the rotation ``R`` (how far the magnetometer's axes are
from the accelerometer's, as imucal found it) is not part of their parameters: the file states
its angle, and the values assume the session's raw magnetometer is in the frame the driver
publishes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.formats.session import UT_PER_MAG_UNIT
from imucal_cli.model.calibration import LOCAL_FIELD, Calibration
from imucal_cli.model.mag import MagCalibration

__all__ = ["TARGET_PER_UT", "MagForTarget", "mag_for_target"]

TARGET_PER_UT = {"gauss": 0.01, "mG": 10.0}
"""Target field units per microtesla."""
#: A rotation of the magnetometer beyond this (degrees) means its axes are not the
#: accelerometer's: the driver must rotate them, and the values then are for the wrong frame.
LARGE_ROTATION_DEG = 10.0


@dataclass
class MagForTarget:
    """The ``mag`` section in a target's terms (see the module notes).

    Attributes
    ----------
    offset : ndarray, shape (3,)
        ``f b``: the hard iron as the driver publishes it, target units.
    symmetric : ndarray, shape (3, 3)
        ``P``, dimensionless.
    rotation_deg : float
        Angle of the rotation ``R`` left out, degrees.
    lines : list of str
        Comment lines: the basis of ``p``, the model, what is left out, warnings.
    """

    offset: np.ndarray
    symmetric: np.ndarray
    rotation_deg: float
    lines: list[str]


def mag_for_target(
    cal: Calibration, target: str, unit: str, scale_uT: float | None = None
) -> MagForTarget | None:
    """Rewrite ``cal.mag`` for a target reading the field in ``unit`` (``"gauss"``, ``"mG"``).

    Returns None when the calibration has no magnetometer.

    Raises
    ------
    InputError
        More than 3 channels, raw units that need ``--mag-scale`` and none given, or a
        calibration in units of the local field with no estimate of the field.
    """
    sec = cal.mag
    if sec is None:
        return None
    if sec.bias.shape[0] != 3:
        raise InputError(f"the mag calibration has {sec.bias.shape[0]} channels; {target} "
                         "holds a 3-axis magnetometer")  # fmt: skip
    ut_per_raw, basis = _uT_per_raw(sec, target, unit, scale_uT)
    W, lines = _matrix_in_uT(sec, target, unit)
    f = ut_per_raw * TARGET_PER_UT[unit]
    M = W / ut_per_raw
    U, sv, Vt = np.linalg.svd(M)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        raise InputError(f"the mag matrix is a reflection (left-handed axes): {target}'s "
                         "symmetric matrix cannot hold it")  # fmt: skip
    P = Vt.T @ np.diag(sv) @ Vt
    angle = float(np.degrees(np.linalg.norm(Rotation.from_matrix(R).as_rotvec())))
    lines += [
        f"mag: p = {basis} -> {unit}; imucal: h = M (p - offset), M = R P, P symmetric",
        f"mag: the rotation R ({angle:.2f} deg, the magnetometer's axes onto the "
        f"accelerometer's) is not part of these parameters: they assume the session's raw "
        f"magnetometer is in the frame {target}'s driver publishes",
    ]
    if angle > LARGE_ROTATION_DEG:
        axes = sec.axes if isinstance(sec, MagCalibration) else None
        lines.append(
            f"WARNING: the magnetometer's axes are {angle:.0f} deg from the accelerometer's"
            + (f" ({', '.join(axes)})" if axes else "")
            + f": {target}'s driver must rotate them (its orientation parameter), and these "
            "values are for the unrotated axes: calibrate a session recorded from the driver's "
            "output instead"
        )
    return MagForTarget(offset=f * np.asarray(sec.bias, float), symmetric=P,
                        rotation_deg=angle, lines=lines)  # fmt: skip


def _uT_per_raw(sec, target: str, unit: str, scale_uT: float | None) -> tuple[float, str]:
    """Microtesla per raw unit of the section's raw magnetometer (``--mag-scale``, else its
    known raw units) and the basis of ``p`` as the comment says it.

    Raises
    ------
    InputError
        A ``--mag-scale`` that is not a positive number, or raw units that need one.
    """
    raw_units = sec.units_in or "raw units"
    if scale_uT is not None:
        if not (math.isfinite(scale_uT) and scale_uT > 0):
            raise InputError(f"--mag-scale must be a positive number of uT per raw unit, "
                             f"got {scale_uT!r}")  # fmt: skip
        ut_per_raw = float(scale_uT)
        basis = f"raw ({raw_units}) x {scale_uT:.9g} uT per raw unit (--mag-scale)"
    elif raw_units in UT_PER_MAG_UNIT:
        ut_per_raw = UT_PER_MAG_UNIT[raw_units]
        basis = f"raw, {raw_units} ({ut_per_raw:g} uT each)"
    else:
        raise InputError(
            f"the mag calibration takes raw {raw_units}; {target} reads the field in {unit} as "
            "the driver publishes it: pass --mag-scale (the driver's uT per raw unit, e.g. "
            "0.15 for an AK8963 in 16-bit mode)"
        )
    return ut_per_raw, basis


def _matrix_in_uT(sec, target: str, unit: str) -> tuple[np.ndarray, list[str]]:
    """``W`` (3, 3) in uT per raw unit: a calibration in units of the local field scaled by its
    field estimate (with a comment line saying so).

    Raises
    ------
    InputError
        A calibration in units of the local field without an estimate of the field.
    """
    W = np.asarray(sec.matrix, float)
    lines = []
    if sec.units == LOCAL_FIELD:
        estimate = sec.field_estimate_uT if isinstance(sec, MagCalibration) else None
        if not isinstance(estimate, int | float) or not estimate > 0:
            raise InputError(
                f"the mag calibration is in units of the local field (no field magnitude was "
                f"given): {target} needs {unit}; set [mag] field_uT (from a geomagnetic model "
                "for your place) and calibrate again"
            )
        W = W * float(estimate)
        lines.append(f"mag: calibrated without the field's magnitude; scaled by the estimate "
                     f"{estimate:.4g} uT from the raw units")  # fmt: skip
    return W, lines
