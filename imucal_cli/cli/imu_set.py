"""What ``imucal calibrate`` says about a set of IMUs (issue 28): one line per IMU beside the
reference, its rotation and time offset with their std."""

from __future__ import annotations

import numpy as np


def set_lines(cal) -> list[str]:
    """Lines for the ``imus`` of a calibration (none for one IMU)."""
    imus = cal.extra.get("imus") or {}
    if not imus:
        return []
    out = [f"set: {len(imus) + 1} IMUs; each one's rotation into the reference's calibrated "
           "frame and the time to add to its stamps"]
    for key, entry in imus.items():
        parts = []
        if entry.get("rotation_to_reference") is not None:
            std = np.asarray(entry["rotation_std_deg"], float)
            parts.append(f"rotated {entry.get('rotation_deg') or 0.0:.3f} deg "
                         f"(std {', '.join(f'{s:.2g}' for s in std)} deg)")
        if entry.get("time_offset_s") is not None:
            parts.append(f"time offset {1e3 * entry['time_offset_s']:+.3f} ± "
                         f"{1e3 * entry['time_offset_std_s']:.3f} ms")
        sensors = [s for s in ("accel", "gyro", "mag") if s in entry]
        parts.append(f"calibrated: {', '.join(sensors) or 'nothing'}")
        out.append(f"  {key}: " + "; ".join(parts))
        out += [f"  {key}: warning: {w}" for w in entry.get("warnings", [])]
    return out


def set_warnings(cal) -> list[str]:
    """Every warning of the other IMUs' sections and of their places in the set."""
    out = []
    for key, entry in (cal.extra.get("imus") or {}).items():
        for sensor in ("accel", "gyro", "mag"):
            out += [f"{key} {sensor}: {w}" for w in (entry.get(sensor) or {}).get("warnings", [])]
        out += [f"{key}: {w}" for w in entry.get("warnings", [])]
    return out
