"""Writing a complete session in one go: :func:`write_session` (a :class:`~.model.Session`,
its segments and calibrations, through :class:`~.writer.SessionWriter`).
"""

from __future__ import annotations

import os

import numpy as np

from imucal_cli.model.session import Session

from .imu_writer import ImuLayout
from .writer import SessionWriter


def write_session(
    path: str | os.PathLike, session: Session, *, overwrite: bool = False, inputs=()
) -> None:
    """Write a complete session file, including ``session.calibrations``.

    The file appears at ``path`` only when complete (see :mod:`imucal_cli.formats.output`).

    Parameters
    ----------
    path : str or path-like
        The file to create.
    session : Session
        What to write.  Segments are written in order of ``start`` and renamed
        ``0000``, ``0001``, ...; ``up``/``axis`` are stored scaled to unit length.
    overwrite : bool
        Replace an existing file instead of refusing.
    inputs : iterable of path-like
        Files never to replace (the command's inputs).

    Raises
    ------
    InputError
        The file exists or cannot be written, or the session breaks the format (SessionError).
    """
    accel, gyro, mag = session.accel, session.gyro, session.mag
    writer = SessionWriter(
        path,
        created=session.created,
        sensor=session.sensor,
        source=session.source,
        sample_rate_hz=session.sample_rate_hz,
        gravity=session.gravity,
        accel_units=session.accel_units,
        gyro_units=session.gyro_units,
        accel_channels=None if accel is None else np.shape(accel)[1],
        gyro_channels=None if gyro is None else np.shape(gyro)[1],
        mag_channels=None if mag is None else np.shape(mag)[1],
        mag_units=session.mag_units,
        magnetic_field_uT=session.magnetic_field_uT,
        temperature=session.temperature is not None,
        host_time=session.host_time is not None,
        overwrite=overwrite,
        inputs=inputs,
        imus={name: ImuLayout.of(imu) for name, imu in session.imus.items()},
        reference_name=session.reference_name,
    )
    with writer:
        writer.append(session.time, accel, gyro, session.temperature, mag,
                      host_time=session.host_time)  # fmt: skip
        for name, imu in session.imus.items():  # several IMUs (issue 28)
            writer.append_imu(name, imu.time, accel=imu.accel, gyro=imu.gyro, mag=imu.mag,
                              temperature=imu.temperature)  # fmt: skip
        for segment in sorted(session.segments, key=lambda s: s.start):
            writer.add_segment(
                segment.kind,
                segment.start,
                segment.stop,
                label=segment.label,
                up=segment.up,
                axis=segment.axis,
                angle_deg=segment.angle_deg,
                extra=segment.extra,
            )
        for name, text in session.calibrations.items():
            writer.add_calibration(name, text)
