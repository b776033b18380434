"""Basalt (VladyslavUsenko/basalt): a complete ``calibration.json`` (cereal JSON, under
``value0``), every key Basalt's loader reads (``basalt-headers``,
``serialization/headers_serialization.h``, ``serialize(Archive&, Calibration&)``):
``T_imu_cam``, ``intrinsics``, ``resolution`` (one entry per camera: none here), the IMU's
``calib_accel_bias`` (9) and ``calib_gyro_bias`` (12), ``imu_update_rate`` (Hz),
``accel_noise_std``, ``gyro_noise_std`` (3 each: continuous-time white noise, m/s^2/sqrt(Hz),
rad/s/sqrt(Hz); Basalt multiplies by sqrt(imu_update_rate) itself), ``accel_bias_std``,
``gyro_bias_std`` (3 each: bias random walk), ``cam_time_offset_ns`` and ``vignette``.  Add the
cameras (``basalt_calibrate`` writes them) to the same file; the IMU keys stand as they are.

Basalt's static IMU calibration (``calib_bias.hpp``, ``CalibAccelBias``/``CalibGyroBias``)::

    a = (I + S_a) @ p_a - b_a      S_a lower triangular: [s1 0 0; s2 s4 0; s3 s5 s6]
    w = (I + S_w) @ p_w - b_w      S_w full, column-major: [s1 s4 s7; s2 s5 s8; s3 s6 s9]

``calib_accel_bias = [b_a (3), s1..s6]``, ``calib_gyro_bias = [b_w (3), s1..s9]``; the bias is
subtracted **after** the matrix, in calibrated units (m/s^2, rad/s), and ``p`` is what the
driver publishes.  The lower-triangular ``S_a`` fixes Basalt's IMU frame the way Kalibr's is
fixed: ``(I + S_a) = C_i_b @ matrix``, ``b_a = (I + S_a) @ bias``.  Basalt has no g-sensitivity:
a gyro calibration that holds one is refused unless ``--drop g-sensitivity``, and the file
then says how large it was.
"""

from __future__ import annotations

import json
import math

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import Calibration
from imucal_cli.formats.exporters import (
    STANDARD_GRAVITY,
    ExportOptions,
    model_lines,
    provenance,
    published,
)
from imucal_cli.formats.exporters.kalibr import frame_comments, frame_for

__all__ = ["export_basalt"]


def export_basalt(cal: Calibration, opts: ExportOptions) -> str:
    """A complete Basalt ``calibration.json`` (module notes): the calibration and the noise.

    ``imucal_notes`` (a key Basalt's loader ignores) states the equations.

    Raises
    ------
    InputError
        No noise figures, or what the published calibration refuses (raw units without the
        driver's scale).
    """
    target = "Basalt"
    frame = frame_for(cal, opts, target)
    # Basalt's matrices map p to the i frame: (I + S) = inv(M) (Kalibr's M), up to the rotation.
    Da = np.tril(np.linalg.inv(frame.M_accel))
    Dw = frame.C_gyro_i.T @ np.linalg.inv(frame.M_gyro)
    accel = [*(Da @ frame.b_accel), *(Da - np.eye(3))[:, 0], Da[1, 1] - 1.0, Da[2, 1],
             Da[2, 2] - 1.0]  # fmt: skip
    gyro = [*(Dw @ frame.b_gyro), *(Dw - np.eye(3)).T.ravel()]
    notes = provenance(cal, "Basalt IMU calibration (calib_accel_bias, calib_gyro_bias)") + [
        "Basalt applies: a = (I + S_a) @ p_a - b_a, w = (I + S_w) @ p_w - b_w, p what the "
        "driver publishes (m/s^2, rad/s), a in m/s^2, w in rad/s.",
        "calib_accel_bias = [b_a (m/s^2, subtracted after the matrix), s1..s6 with S_a = "
        "[[s1,0,0],[s2,s4,0],[s3,s5,s6]]].",
        "calib_gyro_bias = [b_w (rad/s, after the matrix), s1..s9 with S_w column-major "
        "[[s1,s4,s7],[s2,s5,s8],[s3,s6,s9]]].",
        *model_lines(),
        *frame_comments(frame, cal, opts, target),
    ]
    gyro_pub = published(cal, "gyro", target, opts.scale)
    if gyro_pub is not None and gyro_pub.g_sensitivity is not None:
        worst = float(np.linalg.norm(gyro_pub.g_sensitivity, 2) * STANDARD_GRAVITY)
        notes.append(
            f"gyro g-sensitivity dropped (Basalt has none): up to {worst:.4g} rad/s "
            f"({math.degrees(worst):.4g} deg/s) at 1 g"
        )
    noise = opts.noise
    if noise is None or noise.accel is None or noise.gyro is None:
        raise InputError("a complete Basalt calibration holds the IMU's noise (accel_noise_std "
                         "... gyro_bias_std): pass --noise NOISE.json (from imucal noise SESSION "
                         "--json) with both sensors")  # fmt: skip
    rate = opts.rate_hz or noise.rate_hz
    notes += [f"noise from {noise.source}: continuous-time densities per axis (Allan deviation of "
              f"{noise.duration_s:.0f} s at {noise.rate_hz:.6g} Hz)",
              "no camera: T_imu_cam, intrinsics, resolution and vignette are empty; add the "
              "cameras (basalt_calibrate) to this file"]  # fmt: skip
    value0 = {
        "T_imu_cam": [],
        "intrinsics": [],
        "resolution": [],
        "calib_accel_bias": accel,
        "calib_gyro_bias": gyro,
        "imu_update_rate": float(rate),
        "accel_noise_std": _per_axis(noise.accel.white),
        "gyro_noise_std": _per_axis(noise.gyro.white),
        "accel_bias_std": _per_axis(noise.accel.random_walk),
        "gyro_bias_std": _per_axis(noise.gyro.random_walk),
        "cam_time_offset_ns": 0,
        "vignette": [],
        "imucal_notes": notes,
    }
    doc = {"value0": value0}
    return json.dumps(doc, indent=4, allow_nan=False) + "\n"


def _per_axis(values) -> list[float]:
    """Three numbers (Basalt's ``Eigen::Vector3d``); a redundant unit's noise is refused."""
    values = [float(v) for v in values]
    if len(values) != 3:
        raise InputError(f"the noise figures have {len(values)} axes; Basalt holds 3")
    return values
