"""OpenVINS (rpng/open_vins): ``kalibr_imu_chain.yaml`` with the IMU intrinsics.

OpenVINS reads ``imu0`` from this file (``VioManagerOptions.h``: OpenCV ``FileStorage``, so the
first line is ``%YAML:1.0``): the four noise keys, ``rostopic``, ``update_rate``, ``model``, and
the intrinsics ``Tw``, ``R_IMUtoGYRO``, ``Ta``, ``R_IMUtoACC``, ``Tg`` (every key must be
present or it refuses to start).  Its model (docs, "Analytical Propagation")::

    w_I = R_IMUtoGYRO^T @ inv(Tw) @ (p_w - Tg @ a_I - b_w)
    a_I = R_IMUtoACC^T @ inv(Ta) @ (p_a - b_a)

``p`` what the driver publishes (m/s^2, rad/s), ``a_I`` the specific force in the IMU frame.
With ``model: kalibr`` ``Tw`` and ``Ta`` are lower triangular and ``R_IMUtoACC`` is the
identity: exactly Kalibr's numbers (``Ta = M_accel``, ``Tw = M_gyro``, ``R_IMUtoGYRO =
C_gyro_i``, ``Tg = A @ C_gyro_i``).  OpenVINS estimates the biases online from zero; imucal's
fixed biases are given as ``accelerometer_bias``/``gyroscope_bias`` for a driver that removes
them before publishing (then publish ``p - b``).
"""

from __future__ import annotations

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.exporters import ExportOptions, provenance
from imucal_cli.formats.exporters.kalibr import (
    frame_comments,
    frame_for,
    noise_lines,
    yaml_matrix,
    yaml_vector,
)
from imucal_cli.model.calibration import Calibration

__all__ = ["export_openvins", "openvins_block", "openvins_header"]


def export_openvins(cal: Calibration, opts: ExportOptions) -> str:
    """OpenVINS's ``kalibr_imu_chain.yaml`` (``model: kalibr``) from a calibration and noise.

    Raises
    ------
    InputError
        No noise figures: OpenVINS refuses a chain file without its noise keys.
    """
    target = "OpenVINS"
    if opts.noise is None:
        raise InputError("OpenVINS needs the noise keys in kalibr_imu_chain.yaml: pass --noise "
                         "NOISE.json (from imucal noise SESSION --json)")  # fmt: skip
    frame = frame_for(cal, opts, target)
    lines = openvins_header(cal) + [
        *("# " + line for line in frame_comments(frame, cal, opts, target)),
        "",
    ]
    lines += openvins_block(frame, opts)
    return "\n".join(lines) + "\n"


def openvins_header(cal: Calibration) -> list[str]:
    """The first lines of the chain file: the YAML version, provenance and the model."""
    lines = ["%YAML:1.0"]
    lines += ["# " + line for line in provenance(cal, "OpenVINS kalibr_imu_chain.yaml, model "
                                                 "kalibr")]  # fmt: skip
    return lines + [
        "# OpenVINS's model, p what the driver publishes (m/s^2, rad/s), I the IMU frame:",
        "#   a_I = R_IMUtoACC^T @ inv(Ta) @ (p_a - b_a)",
        "#   w_I = R_IMUtoGYRO^T @ inv(Tw) @ (p_w - Tg @ a_I - b_w)",
        "# Tw, Ta lower triangular (model kalibr); Tg in (rad/s)/(m/s^2). OpenVINS estimates",
        "# b_a, b_w online; imucal's fixed biases are accelerometer_bias, gyroscope_bias below.",
    ]


def openvins_block(frame, opts: ExportOptions, name: str = "imu0",
                   T_i_b: np.ndarray | None = None, time_offset: float = 0.0,
                   topic: str | None = None) -> list[str]:  # fmt: skip
    """One IMU's entry of the chain (``T_i_b`` 4 x 4, identity by default; ``time_offset``
    s)."""
    lines = [
        f"{name}:",
        "  T_i_b:",
        *yaml_matrix(np.eye(4) if T_i_b is None else T_i_b, "    "),
    ]
    lines += noise_lines(opts.noise, "  ", opts.rate_hz or opts.noise.rate_hz)
    lines += [
        f"  rostopic: {topic or opts.topic}",
        f"  time_offset: {repr(float(time_offset)) if time_offset else '0.0'}",
        '  model: "kalibr"',
        "  Tw:",
        *yaml_matrix(frame.M_gyro, "    "),
        "  R_IMUtoGYRO:",
        *yaml_matrix(frame.C_gyro_i, "    "),
        "  Ta:",
        *yaml_matrix(frame.M_accel, "    "),
        "  R_IMUtoACC:",
        *yaml_matrix(np.eye(3), "    "),
        "  Tg:",
        *yaml_matrix(frame.Tg, "    "),
        f"  accelerometer_bias: {yaml_vector(frame.b_accel)}",
        f"  gyroscope_bias: {yaml_vector(frame.b_gyro)}",
    ]
    return lines
