"""`imucal export` of a set of IMUs (issue 28): each IMU's calibration where the target holds
several, or the one ``--imu NAME`` picks.

- ``px4``: ``CAL_ACC0..3_*``, ``CAL_GYRO0..3_*`` (and ``TC_A0..3``/``TC_G0..3``), the reference
  the first; PX4 rotates each sensor by its own ``CAL_ACCn_ROT``/``CAL_GYROn_ROT`` (a board
  orientation from a fixed list), so the measured rotations are said, not written.  Each
  IMU's device id (``--device-id NAME=N``) goes in its own ``CAL_ACCn_ID``/``CAL_GYROn_ID``
  (and ``TC_An_ID``/``TC_Gn_ID``): PX4 gives a sensor the calibration whose ``CAL_ACCn_ID``
  holds its device id, searching n = 0..3 (PX4-Autopilot ``src/lib/sensor_calibration/
  Utilities.cpp``, ``FindCurrentCalibrationIndex``, ``MAX_SENSOR_COUNT = 4``; the names in
  ``src/modules/sensors/module.yaml``: ``CAL_ACC${i}_ID``, ``CAL_ACC${i}_[XYZ]OFF``,
  ``CAL_ACC${i}_[XYZ]SCALE``, ``CAL_GYRO${i}_ID``, ``CAL_GYRO${i}_[XYZ]OFF``), so an IMU
  without its id gets none of its values.  ``CAL_*_PRIO`` and ``CAL_*_ROT`` are left as the
  vehicle has them.
- ``ardupilot``: ``INS_ACCOFFS``/``INS_ACC2OFFS``/``INS_ACC3OFFS`` and their ``SCAL``, gyro
  (``INS_GYROFFS``, ``INS_GYR2OFFS``, ...), ``_ID`` (``--device-id NAME=N``), ``INS_TCAL1..3``,
  ``CALTEMP`` siblings.
- ``kalibr``: an IMU chain (``imu0``, ``imu1``, ...) as Kalibr's multi-IMU calibration writes
  it: each IMU's intrinsics, ``T_i_b`` (the body frame ``b`` is the reference's calibrated frame;
  ``T_i_b`` takes it into IMU i's Kalibr frame: ``C_i @ rotation_to_reference^T``) and
  ``time_offset`` (Kalibr's, as imucal's: added to the IMU's stamps for the reference's time;
  ``IccSensors.py``: ``tk = stamp + timeOffset``).  No translation is measured: zero.
- ``openvins``: the same chain in OpenVINS's ``kalibr_imu_chain.yaml``, the body frame the
  reference's IMU frame (``T_i_b`` identity for ``imu0``, as for one IMU).

Other formats hold one IMU: ``--imu NAME`` exports that one.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import numpy as np

from imucal_cli.errors import CalibrationFileError, InputError
from imucal_cli.formats.exporters import ExportOptions
from imucal_cli.formats.exporters.kalibr import frame_for, kalibr_block, kalibr_header
from imucal_cli.formats.exporters.openvins import openvins_block, openvins_header
from imucal_cli.model.calibration import Calibration

__all__ = ["SetMember", "export_set", "pick_imu", "set_members", "with_device_ids"]

#: How many IMUs each target holds.
TARGET_IMUS = {"px4": 4, "ardupilot": 3, "kalibr": 64, "openvins": 64}


@dataclass
class SetMember:
    """One IMU of a set's calibration: its name, its own calibration, its rotation into the
    reference's calibrated frame and its time offset (the reference: identity, 0)."""

    name: str
    calibration: Calibration
    rotation: np.ndarray | None
    time_offset_s: float | None


def set_members(cal: Calibration, source: str = "calibration") -> list[SetMember]:
    """Every IMU of a calibration, the reference first (one member for one IMU).

    Raises
    ------
    CalibrationFileError
        An ``imus`` entry that is not an object of sections in the calibration format, or
        whose rotation is not a 3 x 3 rotation.
    """
    first = replace(cal, imus=None)
    out = [SetMember(cal.reference_name or "reference", first, np.eye(3), 0.0)]
    for name, entry in (cal.imus or {}).items():
        if not entry.sections():
            raise CalibrationFileError(f"{source}: imus.{name}: holds no 'accel', 'gyro' or "
                                       "'mag' calibration")  # fmt: skip
        member_cal = Calibration(created=cal.created, **entry.sections())
        rot = entry.rotation_to_reference
        R = None
        if rot is not None or "rotation_to_reference" in entry.unknown:
            try:
                R = np.asarray(entry.unknown.get("rotation_to_reference", rot), float)
            except (TypeError, ValueError):
                R = np.empty(0)
            if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) \
                    or np.linalg.det(R) < 0:  # fmt: skip
                raise CalibrationFileError(f"{source}: imus.{name}.rotation_to_reference is "
                                           "not a 3 x 3 rotation")  # fmt: skip
        offset = _time_offset(entry.unknown.get("time_offset_s", entry.time_offset_s),
                              f"{source}: imus.{name}")  # not a number: kept in unknown
        out.append(SetMember(str(name), member_cal, R, offset))
    return out


MAX_TIME_OFFSET_S = 3600.0
"""The largest time offset between two IMUs of a set a calibration may state, s (imucal
finds them within +-1 s; 1e300 or NaN shifted every time stamp ``apply --reference-frame``
wrote, exit 0)."""


def _time_offset(value, where: str) -> float | None:
    """``time_offset_s`` of an ``imus`` entry: None (not determined), or a number of seconds
    within :data:`MAX_TIME_OFFSET_S`."""
    if value is None:
        return None
    try:
        offset = float(value)
    except (TypeError, ValueError):
        offset = math.nan
    if not abs(offset) <= MAX_TIME_OFFSET_S:
        raise CalibrationFileError(f"{where}.time_offset_s must be null or a number of seconds "
                                   f"within +-{MAX_TIME_OFFSET_S:g}, got {value!r}")  # fmt: skip
    return offset


def _member_index(members: list[SetMember], name: str) -> int | None:
    """Where IMU ``name`` is in ``members``: its name, or ``reference`` for the first."""
    for k, m in enumerate(members):
        if m.name == name or (k == 0 and name == "reference"):
            return k
    return None


def pick_imu(cal: Calibration, name: str) -> Calibration:
    """The calibration of IMU ``name`` of a set (``--imu``); the reference's by its name or
    ``reference``."""
    members = set_members(cal)
    k = _member_index(members, name)
    if k is None:
        raise InputError(f"--imu {name}: the calibration's IMUs are "
                         f"{', '.join(m.name for m in members)}")  # fmt: skip
    return members[k].calibration


def with_device_ids(cal: Calibration, imu: str | None, opts: ExportOptions) -> ExportOptions:
    """``opts`` with the device id of what is exported: ``device_ids`` (``--device-id
    NAME=N``, checked against the set's names) become ``device_id`` when one IMU is exported
    (``--imu NAME``, or a calibration of one IMU), else stay per IMU for :func:`export_set`
    under the members' own names.

    Raises
    ------
    InputError
        A name the calibration does not have, one IMU named twice, or ``--device-id N``
        together with ``NAME=N``.
    """
    if not opts.device_ids:
        return opts
    if opts.device_id is not None:
        raise InputError("--device-id: give every id as NAME=N, or one N for one IMU, not both")
    members = set_members(cal)
    ids: dict[str, int] = {}
    for key, value in opts.device_ids.items():
        k = _member_index(members, key)
        if k is None:
            raise InputError(f"--device-id {key}={value}: the calibration's IMUs are "
                             f"{', '.join(m.name for m in members)}")  # fmt: skip
        if members[k].name in ids:
            raise InputError(f"--device-id names IMU {members[k].name} twice")
        ids[members[k].name] = value
    if imu is None and len(members) > 1:
        return replace(opts, device_ids=ids)
    k = 0 if imu is None else _member_index(members, imu)
    if k is None:
        raise InputError(f"--imu {imu}: the calibration's IMUs are "
                         f"{', '.join(m.name for m in members)}")  # fmt: skip
    return replace(opts, device_id=ids.get(members[k].name), device_ids={})


def export_set(cal: Calibration, fmt: str, opts: ExportOptions, export_one) -> str:
    """The set in ``fmt`` (module notes); ``export_one(cal, fmt, opts)`` exports one IMU.

    Raises
    ------
    InputError
        A format that holds one IMU, more IMUs than the target holds, ``--device-id`` (one id
        for several devices), or an IMU whose place in the set is not known (chains).
    """
    members = set_members(cal)
    if fmt not in TARGET_IMUS:
        raise InputError(f"--format {fmt} holds one IMU and the calibration has "
                         f"{len(members)}: pick one with --imu NAME "
                         f"({', '.join(m.name for m in members)})")  # fmt: skip
    if len(members) > TARGET_IMUS[fmt]:
        raise InputError(f"--format {fmt} holds {TARGET_IMUS[fmt]} IMUs, the calibration has "
                         f"{len(members)}: export them with --imu NAME")  # fmt: skip
    if opts.device_id is not None:
        raise InputError("--device-id N names one device: with several IMUs give each one's "
                         f"as NAME=N ({', '.join(f'{m.name}=N' for m in members)}), or "
                         "export one with --imu NAME --device-id N")  # fmt: skip
    if fmt in ("px4", "ardupilot"):
        return _parameters(members, fmt, opts, export_one)
    return _chain(members, fmt, opts)


def _px4_names(k: int):
    return [("CAL_ACC0_", f"CAL_ACC{k}_"), ("CAL_GYRO0_", f"CAL_GYRO{k}_"),
            ("TC_A0_", f"TC_A{k}_"), ("TC_G0_", f"TC_G{k}_")]  # fmt: skip


def _ardupilot_names(k: int):
    n = k + 1
    if n == 1:
        return []
    return [("INS_ACCOFFS_", f"INS_ACC{n}OFFS_"), ("INS_ACCSCAL_", f"INS_ACC{n}SCAL_"),
            ("INS_GYROFFS_", f"INS_GYR{n}OFFS_"), ("INS_ACC_ID", f"INS_ACC{n}_ID"),
            ("INS_GYR_ID", f"INS_GYR{n}_ID"), ("INS_TCAL1_", f"INS_TCAL{n}_"),
            ("INS_ACC1_CALTEMP", f"INS_ACC{n}_CALTEMP"),
            ("INS_GYR1_CALTEMP", f"INS_GYR{n}_CALTEMP")]  # fmt: skip


def _param_name(line: str, fmt: str) -> str:
    return line.split("\t")[2] if fmt == "px4" else line.split(",")[0]


def _parameters(members: list[SetMember], fmt: str, opts: ExportOptions, export_one) -> str:
    """Each IMU's parameters under its own names; the compass of the reference's file only."""
    comments: list[str] = []
    params: dict[str, str] = {}
    header = None
    for k, m in enumerate(members):  # each IMU at instance k, with its own device id
        one = replace(opts, device_id=opts.device_ids.get(m.name), device_ids={})
        text = export_one(m.calibration, fmt, one)
        names = _px4_names(k) if fmt == "px4" else _ardupilot_names(k)
        for line in text.splitlines():
            if line.startswith("# Vehicle-Id"):
                header = line
                continue
            if line.startswith("#"):
                for old, new in names:  # the single file's names, as this IMU's
                    line = line.replace(old.rstrip("_"), new.rstrip("_"))
                line = line.replace("(no --device-id)", f"(no --device-id {m.name}=N)")
                comments.append(line if k == 0 else f"# [{m.name}] {line[2:]}")
                continue
            name = _param_name(line, fmt)
            if k and (name.startswith(("CAL_MAG", "COMPASS_"))):
                continue  # the magnetometers are not the IMUs': the reference's file only
            for old, new in names:
                if name.startswith(old):
                    line = line.replace(old, new, 1)
                    name = new + name[len(old):]
            params.setdefault(name, line)
        if k:
            comments.append(_place_comment(m, fmt, k))
    lines = comments + ([header] if header else []) + list(params.values())
    return "\n".join(lines) + "\n"


def _place_comment(m: SetMember, fmt: str, k: int) -> str:
    where = (f"CAL_ACC{k}_*, CAL_GYRO{k}_*" if fmt == "px4" else
             f"INS_ACC{k + 1}OFFS_*, INS_ACC{k + 1}SCAL_*, INS_GYR{k + 1}OFFS_*")  # fmt: skip
    if m.rotation is None:
        return f"# [{m.name}] in {where}; its place in the set was not measured"
    angle = float(np.degrees(np.arccos(np.clip((np.trace(m.rotation) - 1) / 2, -1, 1))))
    rot = "CAL_ACCn_ROT" if fmt == "px4" else "AHRS_ORIENTATION and the driver's"
    return (f"# [{m.name}] in {where}; measured {angle:.3f} deg from the reference and "
            f"{1e3 * (m.time_offset_s or 0.0):+.3f} ms: not written ({rot} rotation is a "
            "fixed list of orientations)")  # fmt: skip


def _chain(members: list[SetMember], fmt: str, opts: ExportOptions) -> str:
    """Kalibr's or OpenVINS's IMU chain (module notes)."""
    if fmt == "openvins" and opts.noise is None:
        raise InputError("OpenVINS needs the noise keys in kalibr_imu_chain.yaml: pass --noise "
                         "NOISE.json (from imucal noise SESSION --json)")  # fmt: skip
    target = "Kalibr" if fmt == "kalibr" else "OpenVINS"
    ref = members[0].calibration
    frames = [frame_for(m.calibration, opts, target) for m in members]
    missing = [m.name for m in members if m.rotation is None or m.time_offset_s is None]
    if missing:
        raise InputError(f"{', '.join(missing)}: the calibration does not give its rotation and "
                         f"time offset to the reference: a {target} chain needs them")
    lines = kalibr_header(ref) if fmt == "kalibr" else openvins_header(ref)
    lines += [f"# an IMU chain of {len(members)}: {', '.join(m.name for m in members)}; the "
              "body frame b is the reference's " + ("calibrated frame (imucal's)"
                                                    if fmt == "kalibr" else "IMU frame"),
              "# T_i_b takes it into each IMU's frame (no translation measured: zero); "
              "time_offset is added to each IMU's stamps for the reference's time"]  # fmt: skip
    for k, (m, frame) in enumerate(zip(members, frames, strict=True)):
        C_b = frame.C_i_b @ m.rotation.T  # the reference's calibrated frame -> IMU k's
        if fmt == "openvins":
            C_b = C_b @ frames[0].C_i_b.T  # from the reference's IMU frame
        T = np.block([[C_b, np.zeros((3, 1))], [np.zeros((1, 3)), 1.0]])
        topic = opts.topic if k == 0 else _topic(opts.topic, k)
        block = kalibr_block if fmt == "kalibr" else openvins_block
        lines += [f"# {m.name}"] + block(frame, opts, f"imu{k}", T, m.time_offset_s or 0.0,
                                         topic)  # fmt: skip
    return "\n".join(lines) + "\n"


def _topic(topic: str, k: int) -> str:
    """The k-th IMU's topic: ``/imu0`` -> ``/imu1``; else ``<topic>_<k>``."""
    m = re.fullmatch(r"(.*?)(\d+)", topic)
    return f"{m.group(1)}{k}" if m else f"{topic}_{k}"
