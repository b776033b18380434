"""The content hash of a session (issue 29.1): what was measured, not how the file is laid out.

SHA-256 over every ``/raw`` channel in name order: for each, a header ``name:rows,columns\\n``
then its samples as little-endian float64, read block by block (:func:`~.stream.open_samples`,
constant memory).  Storing a calibration in the session, relabelling a segment or repacking
the file leave it unchanged; changing one sample changes it.  The registry records it with each
calibration and the certificate prints it, so that a calibration can be traced to its data.
"""

from __future__ import annotations

import hashlib
import os

import numpy as np

from .stream import open_samples

__all__ = ["DIGEST_NAME", "session_digest"]

DIGEST_NAME = "sha256 of /raw (float64 LE, channels in name order)"
"""How the hash is made, in a few words (shown beside it)."""


def session_digest(path: str | os.PathLike) -> str:
    """The hex SHA-256 of a session file's ``/raw`` channels (see the module notes).

    Raises
    ------
    SessionError
        The file is not a readable session.
    """
    digest = hashlib.sha256()
    with open_samples(path) as samples:
        for name in sorted(samples.channels):
            width = samples.channels[name]
            digest.update(f"{name}:{samples.n},{width}\n".encode())
            if samples.n == 0:
                continue
            for (block,) in samples.blocks((name,), 0, samples.n):
                digest.update(np.ascontiguousarray(block, dtype="<f8").tobytes())
    return digest.hexdigest()

