"""`imucal apply` to a session of several IMUs (issue 28): each IMU calibrated with its own
sections, optionally expressed in the reference's frame and time.

For IMU k of the set (the reference's sections at the top level of the calibration, the others
in ``imus``)::

    calibrated_k = matrix_k @ (raw_k - bias_k)                   # its own frame, its own stamps
    in the reference's: R_k @ calibrated_k at t_k + time_offset_k  (--reference-frame)

with ``R_k`` its ``rotation_to_reference``.  Each IMU keeps its own samples: none is
resampled.  The session is read whole (a set is minutes of recording).

Output (HDF5, ``imucal-calibrated`` version 1, as for one IMU): ``/calibrated/time``, ``accel``,
``gyro`` (``mag``) of the reference, and for each other IMU ``/calibrated_imus/<name>/`` the
same datasets; root attributes as for one IMU plus ``imus`` (every name, the reference's first)
and ``frame`` (``"own"`` or ``"reference"``).  ``--imu NAME``: that IMU alone, as one IMU's
output (HDF5 or CSV).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from imucal_cli import __version__
from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import calibration_to_json
from imucal_cli.formats.output import check_output, h5_image, safe_output
from imucal_cli.formats.session import imu_session, read_session, set_names, utc_now_iso
from imucal_cli.model.calibration import MODEL_EQUATION, Calibration
from imucal_cli.model.imu_stream import REFERENCE_NAME
from imucal_cli.use.apply import other_unit

from .export_set import SetMember, set_members

__all__ = ["SetApplySummary", "apply_set"]

_SENSORS = ("accel", "gyro", "mag")


@dataclass
class SetApplySummary:
    """What :func:`apply_set` wrote: the format, IMUs, samples per IMU, sensors, frame."""

    output_format: str
    imus: list[str]
    samples: dict[str, int] = field(default_factory=dict)
    sensors: list[str] = field(default_factory=list)
    frame: str = "own"
    warnings: list[str] = field(default_factory=list)


def _member_for(members: list[SetMember], name: str, reference: str) -> SetMember:
    for k, m in enumerate(members):
        if m.name == name or (k == 0 and name == reference):
            return m
    raise InputError(f"the calibration has no IMU {name!r} (it has "
                     f"{', '.join(m.name for m in members)})")  # fmt: skip


def _calibrated(member: SetMember, session, reference_frame: bool) -> dict[str, np.ndarray]:
    """One IMU's calibrated samples (and times), in its frame or the reference's."""
    cal = member.calibration
    out = {"time": np.asarray(session.time, float)}
    accel = None
    for name in _SENSORS:
        sec = getattr(cal, name)
        if sec is None:
            continue
        raw = getattr(session, name)
        if raw is None or raw.shape[1] != sec.bias.shape[0]:
            raise InputError(f"IMU {session.reference_name}: the {name} calibration takes "
                             f"{sec.bias.shape[0]} channels, the session has "
                             f"{'none' if raw is None else raw.shape[1]}")  # fmt: skip
        values = sec.apply(raw, accel=accel, temperature=session.temperature)
        if name == "accel":
            accel = values
        out[name] = values
    scale = cal.gyro.sample_clock_scale if cal.gyro is not None else None
    if scale is not None:
        out["time"] = out["time"][0] + (out["time"] - out["time"][0]) / scale
    if reference_frame:
        if member.rotation is None or member.time_offset_s is None:
            raise InputError(f"IMU {member.name}: the calibration does not give its rotation "
                             "and time offset to the reference (--reference-frame)")  # fmt: skip
        for name in _SENSORS:
            if name in out:
                out[name] = out[name] @ member.rotation.T
        out["time"] = out["time"] + member.time_offset_s
    return out


def apply_set(cal: Calibration, input_path: str | os.PathLike, output_path: str | os.PathLike,
              *, cal_source: str, imu: str | None = None, reference_frame: bool = False,
              fmt: str | None = None, overwrite: bool = False) -> SetApplySummary:  # fmt: skip
    """Calibrate every IMU of a session of several IMUs, or IMU ``imu`` (module notes).

    Raises
    ------
    InputError
        An IMU the calibration or the session does not have, a sensor missing or with other
        channels, ``--reference-frame`` without the IMU's place, an output that exists.
    """
    input_path, output_path = Path(input_path), Path(output_path)
    fmt = fmt or ("csv" if output_path.suffix.lower() == ".csv" else "h5")
    check_output(output_path, force=overwrite, inputs=[input_path])
    session = read_session(input_path)
    members = set_members(cal, cal_source)
    if imu == REFERENCE_NAME and imu not in set_names(session):
        imu = session.reference_name  # ``reference`` names the reference, as for export
    names = [imu] if imu is not None else set_names(session)
    if fmt == "csv" and len(names) > 1:
        raise InputError("a CSV holds one IMU: pass --imu NAME, or write .h5")
    data, warnings = {}, []
    for name in names:
        member = _member_for(members, name, session.reference_name)
        sub = imu_session(session, name) if name in set_names(session) else None
        if sub is None:
            raise InputError(f"{input_path}: no IMU {name!r} (IMUs: "
                             f"{', '.join(set_names(session))})")  # fmt: skip
        data[name] = _calibrated(member, sub, reference_frame and name != session.reference_name)
        warnings += other_unit(member.calibration.sensor, sub.sensor, f"{cal_source} ({name})",
                               f"{input_path} ({name})")  # fmt: skip
    summary = SetApplySummary(fmt, names, {n: len(d["time"]) for n, d in data.items()},
                              [s for s in _SENSORS if s in data[names[0]]],
                              "reference" if reference_frame else "own", warnings)  # fmt: skip
    if fmt == "csv":
        _write_csv(output_path, data[names[0]], cal_source, overwrite, input_path)
    else:
        _write_h5(output_path, data, names, cal, cal_source, summary, overwrite, input_path)
    return summary


def _write_h5(path: Path, data: dict, names: list[str], cal: Calibration, cal_source: str,
              summary: SetApplySummary, overwrite: bool, input_path: Path) -> None:  # fmt: skip
    with h5_image(path, force=overwrite, inputs=[input_path]) as f:  # a full disk: one line
        f.attrs.update({"format": "imucal-calibrated", "format_version": 1,
                        "created": utc_now_iso(), "model": MODEL_EQUATION,
                        "source": str(input_path), "calibration": cal_source,
                        "calibration_json": calibration_to_json(cal),
                        "calibration_created": cal.created, "toolkit_version": __version__,
                        "frame": summary.frame})  # fmt: skip
        f.attrs["imus"] = np.array(names, dtype=h5py.string_dtype())
        for k, name in enumerate(names):
            group = f.require_group("calibrated" if k == 0 else f"calibrated_imus/{name}")
            for key, values in data[name].items():
                ds = group.create_dataset(key, data=values)
                ds.attrs["units"] = {"time": "s", "accel": "m/s^2", "gyro": "rad/s"}.get(key, "uT")


def _write_csv(path: Path, data: dict, cal_source: str, overwrite: bool,
               input_path: Path) -> None:  # fmt: skip
    cols = ["t"] + [f"{s[0]}{a}" for s in _SENSORS if s in data for a in "xyz"]
    table = np.column_stack([data["time"]] + [data[s] for s in _SENSORS if s in data])
    with safe_output(path, force=overwrite, inputs=[input_path]) as out, out.open("w") as f:
        f.write(",".join(cols) + "\n")
        f.write(f"# {MODEL_EQUATION}; calibration {cal_source}; s, m/s^2, rad/s, uT\n")
        for row in table:
            f.write(repr(float(row[0])) + "," + ",".join(f"{v:.10g}" for v in row[1:]) + "\n")
