"""Statistics of many segments of one array at once: their rows stacked end to end and reduced
by segmented sums (``numpy.add.reduceat``), instead of a Python loop over the segments.

Used for the still periods and turns of a session (hundreds in an hour) and the tokens of a text
file.
"""

from __future__ import annotations

import numpy as np

#: Rows gathered at a time by :func:`moments_in_chunks` (temporaries of about 1.5 MB, reused
#: from chunk to chunk: the whole still data at once took fresh pages, 8 ms more in a process).
CHUNK_ROWS = 1 << 16


def moments_in_chunks(x: np.ndarray, start: np.ndarray, stop: np.ndarray, *,
                      matrix: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`segment_moments` of the segments ``x[start:stop]``, the rows of consecutive
    segments gathered (:func:`stacked_rows`) about :data:`CHUNK_ROWS` at a time (a longer
    segment alone).

    Returns
    -------
    mean, ss : ndarray (S, c), (S, c or d)
    """
    counts = np.asarray(stop, np.int64) - np.asarray(start, np.int64)
    ends = np.cumsum(counts)
    means, sss, i = [], [], 0
    while i < len(counts):
        j = max(i + 1, int(np.searchsorted(ends, ends[i] - counts[i] + CHUNK_ROWS, "right")))
        rows, c = stacked_rows(start[i:j], stop[i:j])
        mean, ss = segment_moments(x.take(rows, axis=0), c, matrix=matrix)
        means.append(mean)
        sss.append(ss)
        i = j
    if not means:
        return segment_moments(np.zeros((0, x.shape[1])), counts, matrix=matrix)
    return np.concatenate(means), np.concatenate(sss)


def stacked_rows(start, stop) -> tuple[np.ndarray, np.ndarray]:
    """The rows of segments ``[start, stop)`` stacked end to end (for ``take``), and each
    segment's length.

    Raises
    ------
    ValueError
        A segment is empty (``stop <= start``).
    """
    start, stop = np.asarray(start, np.int64), np.asarray(stop, np.int64)
    counts = stop - start
    if np.any(counts <= 0):
        raise ValueError("every segment needs at least one sample")
    offsets = np.cumsum(counts) - counts
    return np.arange(int(counts.sum())) + np.repeat(start - offsets, counts), counts


def segment_moments(x: np.ndarray, counts: np.ndarray, *, deviations: bool = True,
                    matrix: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Mean and sum of squared deviations from it of each segment of ``x``, per column, for
    segments stacked end to end (:func:`stacked_rows`): two segmented sums
    (:func:`numpy.add.reduceat`), the second of the deviations from each segment's own mean
    (the two-pass variance).

    Parameters
    ----------
    x : ndarray (N, c)
        The segments' rows, the first ``counts[0]`` rows the first segment's, and so on.
    counts : ndarray of int (S,)
        Each segment's length, at least 1; they sum to ``N``.
    deviations : bool
        Also the sums of squared deviations (else ``ss`` is None).
    matrix : ndarray (d, c), optional
        The squared deviations of ``x @ matrix.T + const`` instead (an affine map of the
        rows: ``(x - mean) @ matrix.T``), ``ss`` of shape (S, d).

    Returns
    -------
    mean, ss : ndarray (S, c), (S, c or d)
        Each segment's ``mean(axis=0)`` and ``((rows - mean) ** 2).sum(axis=0)``.
    """
    x = np.asarray(x, float)
    d_out = x.shape[1] if matrix is None else matrix.shape[0]
    if len(counts) == 0:
        return np.zeros((0, x.shape[1])), np.zeros((0, d_out)) if deviations else None
    offsets = np.cumsum(counts) - counts
    mean = np.add.reduceat(x, offsets, axis=0) / counts[:, None]
    if not deviations:
        return mean, None
    d = x - np.repeat(mean, counts, axis=0)
    if matrix is not None:
        d = d @ matrix.T
    np.multiply(d, d, out=d)
    return mean, np.add.reduceat(d, offsets, axis=0)
