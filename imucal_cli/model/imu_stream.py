"""One IMU of a set beside the reference (``/imus/<name>`` of a session with several IMUs,
``shared/spec/session-format.md``, section "Several IMUs"): its own stream, exactly as it sent
it, on the same clock as ``/raw/time`` but at its own sample times and rate."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The name of the reference IMU (``/raw``) when the recorder gives it none.
REFERENCE_NAME = "reference"

#: The datasets of an ``/imus/<name>`` group: 0 for one value per sample ``(N,)``, k for
#: ``(N, >=k)`` channels (the same as ``/raw``'s).
IMU_CHANNELS: dict[str, int] = {"time": 0, "accel": 3, "gyro": 3, "mag": 3, "temperature": 0}

#: The group's attributes (the per-IMU ones of the root).
IMU_TEXT_ATTRS = ("sensor", "accel_units", "gyro_units", "mag_units")


@dataclass
class ImuStream:
    """The samples of one IMU of a set that is not the reference.

    Attributes
    ----------
    time : ndarray, shape (N,)
        Sample times, s, strictly increasing, on the clock of the reference's ``/raw/time``.
    accel, gyro : ndarray, shape (N, >=3), or None
        Raw channels in ``accel_units`` / ``gyro_units``.
    mag : ndarray, shape (N, >=3), or None
        Raw magnetometer channels in ``mag_units``.
    temperature : ndarray, shape (N,), or None
        Degrees C.
    sensor : str or None
        Free text: part and serial number.
    accel_units, gyro_units, mag_units : str or None
        Units of the raw channels as recorded.
    sample_rate_hz : float or None
        Nominal rate, Hz (the real one is what ``time`` says).
    """

    time: np.ndarray
    accel: np.ndarray | None = None
    gyro: np.ndarray | None = None
    mag: np.ndarray | None = None
    temperature: np.ndarray | None = None
    sensor: str | None = None
    accel_units: str | None = None
    gyro_units: str | None = None
    mag_units: str | None = None
    sample_rate_hz: float | None = None

    def channels(self) -> dict[str, np.ndarray]:
        """The datasets present, ``{name: array}`` in :data:`IMU_CHANNELS` order."""
        return {k: getattr(self, k) for k in IMU_CHANNELS if getattr(self, k) is not None}

    def attrs(self) -> dict[str, str | float]:
        """The group's attributes that are set."""
        out: dict[str, str | float] = {k: getattr(self, k) for k in IMU_TEXT_ATTRS
                                       if getattr(self, k) is not None}  # fmt: skip
        if self.sample_rate_hz is not None:
            out["sample_rate_hz"] = float(self.sample_rate_hz)
        return out
