"""HDF5 session files: validating reader, appending writer, calibration storage (a package).

Implements the session format of ``shared/spec/session-format.md``, version 1:

- :func:`read_session` opens any file that follows the format (written by this package or by
  another tool), validates it and returns a :class:`Session`.  Every problem a user can fix
  raises :class:`~imucal_cli.errors.SessionError` with a one-line message that names the file.
- :class:`SessionWriter` records a session while it is captured: chunked, resizable ``/raw``
  datasets written at least once per ``flush_interval_s`` in HDF5 SWMR mode, so that a reader
  can open the file while it is written and a writer killed with ``kill -9`` leaves a readable
  file that misses at most the last ``flush_interval_s`` of samples.
- :func:`write_session` writes a complete :class:`Session` in one go (through the writer).
- :func:`store_calibration` appends a calibration JSON under ``/calibrations``.

SWMR and segments
-----------------
HDF5 does not support creating groups or attributes while a file is in SWMR write mode, so the
writer keeps segments in memory and writes the ``/segments/NNNN`` groups when it is closed.
Until then each segment is also logged, SWMR-safely, as one JSON object per row of the
fixed-length string dataset ``/capture_log/segments`` (an extra dataset the format allows).
A clean :meth:`SessionWriter.close` removes the log.  When a writer was killed, the file has
no segment groups but still holds the log, and :func:`read_session` reads the segments from it.

A file whose SWMR writer was killed keeps the HDF5 "open for writing" flag.  Plain HDF5 readers
(``h5py.File(path)``, ``h5dump``) refuse such a file until the flag is cleared.  The writer
records its process (``/capture_log`` attributes); :func:`read_session` (through
:func:`open_for_reading`) clears the flag of a file whose capture is gone, with a warning, and
reads a file still being written in SWMR mode (few metadata read attempts, so a damaged file
fails at once), every ``/raw`` dataset up to the shortest one and up to the last time written.

Safety (issue 11): the superblock is checked before HDF5 opens a file (truncated: one line at
once); links, external storage and virtual datasets are refused; dataset sizes are bounded by
the file's; ``/raw`` datasets carry Fletcher32 checksums and NaN fill; outputs are written
through :mod:`imucal_cli.formats.output`.

Modules: :mod:`.model` (``Session``, ``Segment``, constants, attribute values), :mod:`.h5open`
(opening a file for reading), :mod:`.superblock`, :mod:`.reader`, :mod:`.writer` (the samples),
:mod:`.resume` (a capture's session continued), :mod:`.disk` (its room, a failed write),
:mod:`.complete` (``write_session``),
:mod:`.segments` (the segments and calibrations a writer keeps until it closes, and their log),
:mod:`.store`, :mod:`.stream` (a session read block by block: ``open_samples``); several IMUs
(issue 28): :mod:`.imu_stream` (``ImuStream``), :mod:`.imus` (reading ``/imus``, one IMU of a
set as a session), :mod:`.imu_writer` (``/imus`` beside ``/raw``).  Import the
public names from here (``from imucal_cli.formats.session import
read_session``).
"""

from __future__ import annotations

from imucal_cli.model.imu_stream import REFERENCE_NAME, ImuStream
from imucal_cli.model.session import (
    FORMAT,
    FORMAT_VERSION,
    GRAVITY_DEFAULT,
    MAG_UNITS,
    SEGMENT_KINDS,
    TURN_ANGLE_RULE,
    UT_PER_MAG_UNIT,
    Segment,
    Session,
    as_float,
    as_int,
    as_str,
    as_turn_angle,
    as_unit_vector,
    one_line,
    show,
    utc_now_iso,
)

from .complete import write_session
from .h5open import check_session_file, open_for_reading
from .imu_writer import ImuLayout
from .imus import imu_session, map_segments, set_names
from .reader import read_session
from .relabel import ROOT_LABELS, rewrite_labels
from .store import store_calibration
from .stream import SessionSamples, open_samples, samples_of
from .writer import SessionWriter

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "GRAVITY_DEFAULT",
    "ImuLayout",
    "ImuStream",
    "REFERENCE_NAME",
    "MAG_UNITS",
    "ROOT_LABELS",
    "SEGMENT_KINDS",
    "TURN_ANGLE_RULE",
    "Segment",
    "Session",
    "SessionSamples",
    "SessionWriter",
    "as_float",
    "as_int",
    "as_str",
    "as_turn_angle",
    "as_unit_vector",
    "check_session_file",
    "imu_session",
    "map_segments",
    "one_line",
    "open_for_reading",
    "open_samples",
    "read_session",
    "rewrite_labels",
    "samples_of",
    "set_names",
    "show",
    "store_calibration",
    "UT_PER_MAG_UNIT",
    "utc_now_iso",
    "write_session",
]
