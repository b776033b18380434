"""`imucal export`: a calibration (and noise figures) in the format a firmware, an estimator or
a calibration tool loads.  One exporter module per format in
:mod:`imucal_cli.formats.exporters`; this module chooses one (:data:`FORMATS`).

Every file states the equation the target applies, its direction (what is subtracted, before
or after which matrix) and the units.  Targets that hold less than imucal's model (PX4 and
ArduPilot: offset and diagonal scale) say what is lost, in degrees; a term the target cannot
hold (a temperature-dependent bias, a gyro g-sensitivity) is refused, never silently dropped
(a g-sensitivity is left out only with ``--drop g-sensitivity``, and the file says how large it
was).
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imucal_cli.errors import CalibrationFileError, ImucalWarning, InputError
from imucal_cli.formats.calibration import calibration_from_json
from imucal_cli.formats.exporters import STANDARD_GRAVITY, ExportOptions, check_raw_units
from imucal_cli.formats.exporters.ardupilot import export_ardupilot
from imucal_cli.formats.exporters.basalt import export_basalt
from imucal_cli.formats.exporters.c_header import export_c_header
from imucal_cli.formats.exporters.estimators import export_orbslam3, export_vins
from imucal_cli.formats.exporters.fusion import export_fusion
from imucal_cli.formats.exporters.imu_calib import export_yaml
from imucal_cli.formats.exporters.imucal_json import export_json
from imucal_cli.formats.exporters.kalibr import export_kalibr, export_kalibr_imu
from imucal_cli.formats.exporters.openvins import export_openvins
from imucal_cli.formats.exporters.px4 import export_px4
from imucal_cli.formats.exporters.ros_imu import export_ros_imu
from imucal_cli.formats.inputs import read_text_input
from imucal_cli.formats.noise import NOISE_FORMAT, NoiseFigures, noise_from_dict
from imucal_cli.formats.text import has_control
from imucal_cli.model.calibration import Calibration

from .export_set import export_set

__all__ = [
    "EXPORT_FORMATS",
    "FORMATS",
    "ExportFormat",
    "export",
    "export_c_header",
    "export_json",
    "export_yaml",
    "format_for_suffix",
    "load_input",
]


@dataclass(frozen=True)
class ExportFormat:
    """One target: its exporter, what it writes, and what it needs."""

    name: str
    write: Callable[[Calibration | None, ExportOptions], str]
    what: str
    needs_calibration: bool = True
    uses_prefix: bool = False
    holds_tempco: bool = False
    holds_g_sensitivity: bool = False


FORMATS: dict[str, ExportFormat] = {
    f.name: f
    for f in (
        ExportFormat("c-header", lambda c, o: export_c_header(c, prefix=o.prefix or "IMUCAL"),
                     "C99 constants and inline apply functions", uses_prefix=True,
                     holds_tempco=True, holds_g_sensitivity=True),
        ExportFormat("yaml", export_yaml, "ROS imu_calib: SM, bias (of the published m/s^2)"),
        ExportFormat("json", lambda c, o: export_json(c), "imucal's standard fields, one line",
                     holds_tempco=True, holds_g_sensitivity=True),
        ExportFormat("kalibr-imu", export_kalibr_imu,
                     "Kalibr imu.yaml: noise densities and random walks (needs --noise)",
                     needs_calibration=False),
        ExportFormat("kalibr", export_kalibr,
                     "Kalibr scale-misalignment intrinsics M, A, C_gyro_i and biases",
                     holds_g_sensitivity=True),
        ExportFormat("openvins", export_openvins,
                     "OpenVINS kalibr_imu_chain.yaml: Tw, Ta, R_IMUtoGYRO, R_IMUtoACC, Tg "
                     "(needs --noise)", holds_g_sensitivity=True),
        ExportFormat("basalt", export_basalt,
                     "Basalt calibration.json, complete: calib_accel_bias, calib_gyro_bias, "
                     "noise, rate, no camera (needs --noise)"),
        ExportFormat("px4", export_px4, "PX4 CAL_ACC0_*, CAL_GYRO0_* (offset, diagonal scale), "
                     "CAL_MAG0_* (offset, symmetric scale), TC_* (temperature)",
                     holds_tempco=True),
        ExportFormat("ardupilot", export_ardupilot,
                     "ArduPilot .parm INS_ACCOFFS_*, INS_ACCSCAL_*, INS_GYROFFS_*, INS_TCAL1_* "
                     "(temperature), COMPASS_OFS_*, COMPASS_DIA_*, COMPASS_ODI_*",
                     holds_tempco=True),
        ExportFormat("fusion", export_fusion,
                     "x-io Fusion: misalignment, sensitivity, offset per sensor; softIronMatrix, "
                     "hardIronOffset (C)",
                     uses_prefix=True),
        ExportFormat("vins", export_vins,
                     "VINS-Mono / VINS-Fusion IMU keys acc_n, gyr_n, acc_w, gyr_w, g_norm "
                     "(needs --noise)", needs_calibration=False),
        ExportFormat("orbslam3", export_orbslam3,
                     "ORB-SLAM3 settings IMU.NoiseGyro, NoiseAcc, GyroWalk, AccWalk, Frequency "
                     "(needs --noise)", needs_calibration=False),
        ExportFormat("ros-imu", export_ros_imu,
                     "sensor_msgs/Imu covariances from the noise (needs --noise)",
                     needs_calibration=False),
    )
}  # fmt: skip
EXPORT_FORMATS = tuple(FORMATS)

_SUFFIX_FORMATS = {".h": "c-header", ".yaml": "yaml", ".yml": "yaml", ".json": "json",
                   ".params": "px4", ".parm": "ardupilot"}  # fmt: skip


def format_for_suffix(path: str | os.PathLike) -> str | None:
    """The format a file name implies (``.h``, ``.yaml``, ``.json``, ``.params``, ``.parm``)."""
    return _SUFFIX_FORMATS.get(Path(path).suffix.lower())


def export(
    cal: Calibration | None, fmt: str, *, prefix: str | None = None,
    options: ExportOptions | None = None,
) -> str:  # fmt: skip
    """Dispatch to the exporter for ``fmt`` (one of :data:`EXPORT_FORMATS`).

    Raises
    ------
    InputError
        An unknown format, ``prefix`` with a format that has no C names, no calibration for a
        format that needs one, or what the exporter refuses.
    """
    if fmt not in FORMATS:
        raise InputError(f"--format {fmt!r}: use {', '.join(EXPORT_FORMATS)}")
    target = FORMATS[fmt]
    opts = options or ExportOptions()
    if prefix is not None:
        opts.prefix = prefix
    if opts.prefix is not None and not target.uses_prefix:
        raise InputError(f"--prefix applies to --format c-header or fusion only, not {fmt}")
    if cal is None and target.needs_calibration:
        raise InputError(f"--format {fmt} needs a calibration (imucal calibrate's JSON), "
                         "not only noise figures")  # fmt: skip
    if cal is not None and target.needs_calibration:
        check_raw_units(cal)  # units the file would state and convert by, every IMU's
    if cal is not None and target.needs_calibration and cal.imus:
        return export_set(cal, fmt, opts, _export_one)  # several IMUs (issue 28)
    return _export_one(cal, fmt, opts)


def _export_one(cal: Calibration | None, fmt: str, opts: ExportOptions) -> str:
    """One IMU's calibration (or the noise figures) in ``fmt``: its terms checked, written."""
    target = FORMATS[fmt]
    if cal is not None and target.needs_calibration and not target.holds_tempco:
        refuse_tempco(cal, fmt)
    if cal is not None and target.needs_calibration and not target.holds_g_sensitivity:
        refuse_g_sensitivity(cal, fmt, opts.drop)
    if cal is not None and target.needs_calibration:
        warn_assumed(cal, fmt)
    text = target.write(cal, opts)
    if has_control(text):  # belt and braces (issue 11.5): strings were cleaned when read
        raise InputError(f"the {fmt} export would hold control characters; refusing it")
    return text


def warn_assumed(cal: Calibration, fmt: str) -> None:
    """An export cannot say which terms are assumed (issue 27.3: a section with ``partial``):
    it holds the whole model, so the user is told which terms are the prior's, not measured
    (:class:`ImucalWarning`)."""
    for name, sec in cal.sections().items():
        part = sec.partial
        if part is not None and part.assumed:
            warnings.warn(f"the {name} calibration is partial: {', '.join(part.assumed)} are "
                          f"assumed (the prior's values, not measured), and the {fmt} export "
                          "holds them as any other term", ImucalWarning, stacklevel=2)  # fmt: skip


def refuse_tempco(cal: Calibration, fmt: str) -> None:
    """Refuse to export a temperature-dependent bias to a format that cannot hold it (the
    formats page: a reader that cannot apply a term refuses rather than ignores it)."""
    names = [n for n in ("accel", "gyro")
             if getattr(cal, n) is not None and getattr(cal, n).temperature_terms is not None]
    if names:
        holders = ", ".join(f.name for f in FORMATS.values() if f.holds_tempco)
        raise InputError(
            f"the {' and '.join(names)} calibration has a temperature-dependent bias "
            f"(bias_tempco) that --format {fmt} cannot hold: export to {holders}, or calibrate "
            "again with [temperature] model = \"off\" for a bias at one temperature"
        )


def refuse_g_sensitivity(cal: Calibration, fmt: str, drop: frozenset[str]) -> None:
    """Refuse a gyro ``g_sensitivity`` that ``fmt`` cannot hold, unless the user accepts to
    lose it (``--drop g-sensitivity``; the file then says how large it was).  The formats
    page: a reader that cannot apply a term refuses rather than ignores it (issue 26: the
    imu_calib YAML and the C header ignored it, 0.0225 rad/s off ``imucal apply``)."""
    gs = None if cal.gyro is None else cal.gyro.g_term
    if gs is None or "g-sensitivity" in drop:
        return
    worst = float(np.linalg.norm(cal.gyro.matrix @ gs, 2) * STANDARD_GRAVITY)
    holders = ", ".join(f.name for f in FORMATS.values() if f.holds_g_sensitivity)
    raise InputError(
        f"the gyro calibration has a g_sensitivity (up to {worst:.3g} rad/s at 1 g) that "
        f"--format {fmt} cannot hold: export to {holders}, or pass --drop g-sensitivity to "
        "export without it"
    )


def load_input(path: str | os.PathLike) -> tuple[Calibration | None, NoiseFigures | None]:
    """The export's input: a calibration, or a noise file (``imucal noise --json``).

    Raises
    ------
    CalibrationFileError, InputError
        Neither, or a file that does not follow its format.
    """
    src = str(path)
    text = read_text_input(path, what="calibration file", error=CalibrationFileError)
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError):
        doc = None  # calibration_from_json gives the one-line reason
    if isinstance(doc, dict) and doc.get("format") == NOISE_FORMAT:
        return None, noise_from_dict(doc, src)
    return calibration_from_json(text, src), None
