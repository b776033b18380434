"""What ``imucal calibrate`` says about a set of IMUs (issue 28): one line per IMU beside the
reference, its rotation and time offset with their std."""

from __future__ import annotations

import numpy as np

from imucal_cli.capture.imu_set import PortSet, PortsProtocol, SetLineProtocol, set_protocol
from imucal_cli.capture.serial_port import SerialSource
from imucal_cli.errors import InputError
from imucal_cli.formats.columns import ColumnSpec

from .console import make_console, print_json


def capture_set(ports: list[str], columns: str, time_unit: str, protocol: str):
    """The line protocol of a capture of several IMUs (one port with ``.N`` fields, or
    several ports), or None for one IMU; refuses what a set does not take.  A set resumed
    (``--resume``) must be the session's: the writer checks it when it reopens the file."""
    specs = set_protocol(columns, time_unit, len(ports))
    if specs is None and len(ports) == 1:
        return None
    if protocol != "lines":
        raise InputError("several IMUs are captured as lines of numbers (--protocol lines)")
    if len(set(ports)) != len(ports):
        raise InputError("--port names the same port twice")
    if specs is not None:
        return SetLineProtocol(specs)
    return ColumnSpec.parse(columns, time_unit)


def open_ports(ports: list[str], baud: int, spec: ColumnSpec):
    """Several ports as one source (the first the reference, the others read without
    waiting) and their protocol; a port that fails closes those already open."""
    sources = []
    try:
        for k, port in enumerate(ports):
            sources.append(SerialSource(port, baud, timeout_s=0.05 if k == 0 else 0.0))
    except BaseException:
        for s in sources:
            s.close()
        raise
    group = PortSet(sources)
    return group, PortsProtocol(group, spec)


def set_lines(cal) -> list[str]:
    """Lines for the ``imus`` of a calibration (none for one IMU)."""
    imus = cal.imus or {}
    if not imus:
        return []
    out = [f"set: {len(imus) + 1} IMUs; each one's rotation into the reference's calibrated "
           "frame and the time to add to its stamps"]
    for key, entry in imus.items():
        parts = []
        if entry.rotation_to_reference is not None:
            std = np.asarray(entry.rotation_std_deg, float)
            parts.append(f"rotated {entry.rotation_deg or 0.0:.3f} deg "
                         f"(std {', '.join(f'{s:.2g}' for s in std)} deg)"
                         + _labels_frame(cal, entry))  # fmt: skip
        if entry.time_offset_s is not None:
            raw = entry.set is not None and entry.set.offset_method is not None  # eq. T5
            parts.append(f"time offset {1e3 * entry.time_offset_s:+.3f} ± "
                         f"{1e3 * (entry.time_offset_std_s or 0.0):.3f} ms"
                         + (" (from the raw rates: a gyro not calibrated in full)" if raw
                            else ""))  # fmt: skip
        sensors = list(entry.sections())
        parts.append(f"calibrated: {', '.join(sensors) or 'nothing'}")
        out.append(f"  {key}: " + "; ".join(parts))
        out += [f"  {key}: warning: {w}" for w in entry.warnings or []]
    return out


def _labels_frame(cal, entry) -> str:
    """Words for a rotation near zero by construction: both accelerometers calibrated with
    labelled poses put their output in the frame of the labels, so each one's mounting
    rotation is inside its own matrix."""
    ours, theirs = cal.accel, entry.accel
    if ours is None or theirs is None or not ours.solver == theirs.solver == "labelled":
        return ""
    return (" (both accelerometers calibrated into the frame of the labels: each IMU's "
            "mounting is in its own matrix)")


def set_warnings(cal) -> list[str]:
    """Every warning of the other IMUs' sections and of their places in the set."""
    out = []
    for key, entry in (cal.imus or {}).items():
        for sensor, sec in entry.sections().items():
            out += [f"{key} {sensor}: {w}" for w in sec.warnings or []]
        out += [f"{key}: {w}" for w in entry.warnings or []]
    return out


def set_summary(summary, input_file, calibration, output, json_output: bool) -> None:
    """What ``imucal apply`` wrote of a set: JSON (``imucal-apply`` with ``imus``) or a line."""
    if json_output:
        print_json({"format": "imucal-apply", "format_version": 1, "output": str(output),
                    "output_format": summary.output_format, "input": str(input_file),
                    "calibration": str(calibration), "imus": summary.imus,
                    "samples": summary.samples, "sensors": summary.sensors,
                    "frame": summary.frame, "warnings": summary.warnings})  # fmt: skip
        return
    counts = ", ".join(f"{n} {k}" for n, k in summary.samples.items())
    make_console().print(f"calibrated {counts} samples ({', '.join(summary.sensors)}; "
                         f"{summary.frame} frame) from {input_file} with {calibration} -> "
                         f"{output} ({summary.output_format})", markup=False, highlight=False,
                         soft_wrap=True)  # fmt: skip
    for w in summary.warnings:
        make_console().print(f"warning: {w}", markup=False, highlight=False, soft_wrap=True)
