"""ArduPilot parameters (``INS_ACCOFFS_*``, ``INS_ACCSCAL_*``, ``INS_GYROFFS_*``, and the
compass's ``COMPASS_OFS_*``, ``COMPASS_DIA_*``, ``COMPASS_ODI_*``) as a ``.parm`` file
(``NAME,VALUE`` lines, ``#`` comments; Mission Planner and MAVProxy ``param load``).

ArduPilot corrects the first IMU in the sensor frame, then rotates to the body frame
(``AP_InertialSensor_Backend::_rotate_and_correct_accel``/``_gyro``)::

    accel = R_board @ ((p - INS_ACCOFFS_[XYZ]) * INS_ACCSCAL_[XYZ])     m/s^2, per axis
    gyro  = R_board @ (p - INS_GYROFFS_[XYZ])                          rad/s

``p`` is the sample as the driver reports it (m/s^2, rad/s, after the driver's own axis
rotation).  Offset and diagonal scale only: the misalignment of imucal's full calibration (and
the gyro's scale) is lost, and the file says how much
(:func:`~imucal_cli.formats.exporters.diagonal_fit`).  ArduPilot's own accel calibration
refuses scales outside 0.8 .. 1.2 and offsets beyond 3.5 m/s^2; values outside are flagged.
A temperature-dependent bias (``bias_tempco``, issue 17.1) goes into ArduPilot's temperature
calibration of the first IMU (``AP_InertialSensor_tempcal.cpp``), applied before the offset::

    p' = p - P(T - 35) + P(CALTEMP - 35),   P(x) = (c1 x + c2 x^2 + c3 x^3) * 1e-6

with ``T`` and ``CALTEMP`` clamped to ``INS_TCAL1_TMIN`` .. ``TMAX``: ``INS_TCAL1_ENABLE`` = 1,
``INS_TCAL1_ACCk_[XYZ]``/``GYRk_[XYZ]`` the polynomial re-expanded about ArduPilot's fixed 35 C
(times 1e6), and ``INS_ACC1_CALTEMP``/``INS_GYR1_CALTEMP`` = ``temperature_ref``, the
temperature the offsets hold for.

``--device-id`` writes ``INS_ACC_ID``/``INS_GYR_ID`` (ArduPilot resets the calibration of a
device whose id changed).

The first compass (``AP_Compass_Backend::correct_field``), in milligauss::

    mag = D @ ((p + COMPASS_OFS_[XYZ]) * COMPASS_SCALE),
    D = [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]]

the offset is *added* (it is minus the hard iron) and ``D`` is symmetric: imucal's rotation of
the magnetometer onto the accelerometer is not part of it (the file says how far it was).
``COMPASS_SCALE`` is written as 1.  Offsets beyond ArduPilot's default ``COMPASS_OFFS_MAX``
(1800 mG) are flagged.
"""

from __future__ import annotations

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.exporters import (
    ExportOptions,
    Published,
    clock_lines,
    fmt,
    model_lines,
    offset_scale_fits,
    provenance,
)
from imucal_cli.formats.exporters.magnetic import mag_for_target
from imucal_cli.model.calibration import Calibration

__all__ = ["export_ardupilot"]

_SCALE_RANGE = (0.8, 1.2)
_TCAL_REF_C = 35.0  # ArduPilot's TEMP_REFERENCE
_TCAL_SCALE = 1e6  # ArduPilot's SCALE_FACTOR of the INS_TCAL coefficients
_MAX_OFFSET = 3.5  # m/s^2
_MAX_COMPASS_OFFSET = 1800.0  # mG, ArduPilot's default COMPASS_OFFS_MAX


def export_ardupilot(cal: Calibration, opts: ExportOptions) -> str:
    """ArduPilot ``INS_ACCOFFS_*``, ``INS_ACCSCAL_*``, ``INS_GYROFFS_*`` as ``NAME,VALUE``."""
    target = "ArduPilot"
    lost, fits = offset_scale_fits(cal, target, opts, also=("mag",))
    comments = provenance(cal, "ArduPilot parameters (.parm: Mission Planner 'Load from "
                          "file', MAVProxy 'param load')") + [  # fmt: skip
        "ArduPilot applies: accel = R_board @ ((p - INS_ACCOFFS_x) * INS_ACCSCAL_x) per axis, "
        "gyro = R_board @ (p - INS_GYROFFS_x);",
        "p as the driver reports it (m/s^2, rad/s); offsets in those units, scales unitless.",
        *model_lines(),
        *lost,
    ]
    params: list[tuple[str, str]] = []
    for name, _, fit in fits:
        if name == "accel":
            if opts.device_id is not None:
                params.append(("INS_ACC_ID", str(int(opts.device_id))))
            params += [(f"INS_ACCOFFS_{a}", fmt(v)) for a, v in zip("XYZ", fit.offset,
                                                                     strict=True)]  # fmt: skip
            params += [(f"INS_ACCSCAL_{a}", fmt(v)) for a, v in zip("XYZ", fit.scale,
                                                                     strict=True)]  # fmt: skip
            lo, hi = _SCALE_RANGE
            if np.any(fit.scale < lo) or np.any(fit.scale > hi):
                comments.append(f"WARNING: a scale outside ArduPilot's accepted {lo} .. {hi}: "
                                "check the driver's units (--accel-scale)")  # fmt: skip
            if np.any(np.abs(fit.offset) > _MAX_OFFSET):
                comments.append(f"WARNING: an offset beyond ArduPilot's accepted {_MAX_OFFSET} "
                                "m/s^2: check the driver's units (--accel-scale)")  # fmt: skip
        else:
            if opts.device_id is not None:
                params.append(("INS_GYR_ID", str(int(opts.device_id))))
            params += [(f"INS_GYROFFS_{a}", fmt(v)) for a, v in zip("XYZ", fit.offset,
                                                                     strict=True)]  # fmt: skip
    params += _thermal(fits, comments)
    params += _compass(cal, opts, target, comments)
    comments += clock_lines(cal)
    lines = ["# " + c for c in comments]
    lines += [f"{n},{v}" for n, v in params]
    return "\n".join(lines) + "\n"


def _compass(cal: Calibration, opts: ExportOptions, target: str, comments: list[str]):
    """``COMPASS_*`` of the first compass (milligauss), or nothing without a magnetometer."""
    mag = mag_for_target(cal, target, "mG", opts.scale.get("mag"))
    if mag is None:
        return []
    comments.append("ArduPilot applies: mag = D @ ((p + COMPASS_OFS_x) * COMPASS_SCALE), "
                    "D symmetric from COMPASS_DIA_x and COMPASS_ODI_x (xy, xz, yz); mG")
    comments += mag.lines
    if np.any(np.abs(mag.offset) > _MAX_COMPASS_OFFSET):
        comments.append(f"WARNING: an offset beyond ArduPilot's default COMPASS_OFFS_MAX "
                        f"({_MAX_COMPASS_OFFSET:g} mG): raise it or check --mag-scale")  # fmt: skip
    P = mag.symmetric
    params = [(f"COMPASS_OFS_{a}", fmt(-v)) for a, v in zip("XYZ", mag.offset, strict=True)]
    params += [(f"COMPASS_DIA_{a}", fmt(P[i, i])) for i, a in enumerate("XYZ")]
    params += [(f"COMPASS_ODI_{a}", fmt(P[i, j]))
               for a, (i, j) in zip("XYZ", ((0, 1), (0, 2), (1, 2)), strict=True)]  # fmt: skip
    params.append(("COMPASS_SCALE", fmt(1.0)))
    return params


def _thermal(fits: list, comments: list[str]) -> list[tuple[str, str]]:
    """``INS_TCAL1_*`` and ``INS_*1_CALTEMP`` of the temperature-dependent biases, if any."""
    terms: dict[str, Published] = {n: p for n, p, _ in fits if p.temperature is not None}
    if not terms:
        return []
    ranges = [(p.temperature.t_min, p.temperature.t_max) for p in terms.values()]
    if any(lo is None for lo, _ in ranges):
        t_ref = next(iter(terms.values())).temperature.t_ref
        lo, hi = t_ref - 30.0, t_ref + 30.0
    else:
        lo, hi = min(r[0] for r in ranges), max(r[1] for r in ranges)
    out = [("INS_TCAL1_ENABLE", "1"), ("INS_TCAL1_TMIN", fmt(lo)), ("INS_TCAL1_TMAX", fmt(hi))]
    for name, pub in terms.items():
        tt = pub.temperature
        if tt.tempco.shape[0] > 3:
            raise InputError(f"the {name} bias polynomial has degree {tt.tempco.shape[0]}: "
                             "ArduPilot holds at most 3")  # fmt: skip
        _, d = tt.about(_TCAL_REF_C)
        key, cal = ("ACC", "INS_ACC1_CALTEMP") if name == "accel" else ("GYR", "INS_GYR1_CALTEMP")
        for k in range(1, 4):
            for i, axis in enumerate("XYZ"):
                value = d[k - 1, i] * _TCAL_SCALE if k <= d.shape[0] else 0.0
                out.append((f"INS_TCAL1_{key}{k}_{axis}", fmt(value)))
        out.append((cal, fmt(tt.t_ref)))
        comments.append(f"{name}: temperature-dependent bias in INS_TCAL1_{key}k_* "
                        f"({tt.range_text()}), about ArduPilot's 35 C, x 1e6; the offsets hold "
                        f"at {cal} = {tt.t_ref:.2f} C")  # fmt: skip
    return out
