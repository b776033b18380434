"""Calling the reader libraries (rosbags, mcap, pyulog, pymavlink): they print what they skip
and raise their own exception types on a damaged file.  Library code never prints (errors are
one line, ``--json`` owns stdout), and a damaged file is a one-line :class:`InputError` with
exit 2, never a traceback (issue 26)."""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
from collections.abc import Iterable, Iterator

from imucal_cli.errors import InputError

__all__ = ["damaged_as_input_error", "one_line_reason", "quiet"]


def one_line_reason(exc: BaseException, limit: int = 160) -> str:
    """An exception as a few words on one line: its type and message."""
    text = " ".join(str(exc).split())[:limit]
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def damaged_as_input_error(items: Iterable, source: str) -> Iterator:
    """``items`` as they come; whatever a reader library raises while it reads a damaged file
    (rosbags' ``ReaderError``, an ``AssertionError``, sqlite's ``CorruptError``, a
    ``UnicodeDecodeError``, ``struct.error``, a message type without its fields, an impossible
    allocation from a flipped length) becomes the one-line :class:`InputError` (exit 2)."""
    try:
        yield from items
    except InputError:
        raise
    except MemoryError:
        raise InputError(f"{source}: damaged (a record asks for more memory than there is: a "
                         "length field damaged?)") from None  # fmt: skip
    except Exception as exc:  # noqa: BLE001 - each library raises its own types
        raise InputError(f"{source}: damaged, a message cannot be read "
                         f"({one_line_reason(exc)})") from None  # fmt: skip


@contextlib.contextmanager
def quiet():
    """Silence a library that prints what it skips, in Python and (compiled code: pymavlink's
    DataFlash indexer) on file descriptor 2; restored on the way out."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with tempfile.TemporaryFile() as sink:
            os.dup2(sink.fileno(), 2)
            with contextlib.redirect_stdout(io.StringIO()), \
                    contextlib.redirect_stderr(io.StringIO()):  # fmt: skip
                yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
