"""The other IMUs of a set in the report (spec "Several IMUs"): each one's place in the set
(rotation into the reference's calibrated frame, time offset, each with its std) and its own
sections, drawn as the reference's are."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from imucal_cli.model.calibration import Calibration


def imus_report(cal: Calibration, section_report: Callable) -> dict[str, Any]:
    """``{name: {rotation_to_reference, rotation_deg, rotation_std_deg, time_offset_s,
    time_offset_std_s, left_out, warnings, sensors}}`` for every IMU but the reference
    (empty for one IMU); ``sensors`` as the report's own, from ``section_report``."""
    out = {}
    for name, entry in (cal.imus or {}).items():
        out[name] = {key: getattr(entry, key) for key in (
            "rotation_to_reference", "rotation_deg", "rotation_std_deg", "time_offset_s",
            "time_offset_std_s", "left_out", "warnings")}  # fmt: skip
        out[name]["sensors"] = {kind: section_report(kind, sec)
                                for kind, sec in entry.sections().items()}  # fmt: skip
    return out


def place_text(name: str, imu: dict[str, Any]) -> str:
    """One line: the IMU's rotation into the reference's calibrated frame (deg, std per axis)
    and the time offset added to its stamps (ms ± std)."""
    angle, std = imu.get("rotation_deg"), imu.get("rotation_std_deg")
    rot = "rotation not determined" if angle is None else f"rotated {angle:.3f} deg" + (
        f" (std {', '.join(f'{s:.2g}' for s in std)} deg)" if std else "")  # fmt: skip
    offset, ostd = imu.get("time_offset_s"), imu.get("time_offset_std_s")
    off = "time offset not determined" if offset is None else (
        f"time offset {1e3 * offset:+.3f}" + (f" ± {1e3 * ostd:.3f}" if ostd else "") + " ms")
    return f"{name}: {rot}; {off}"
