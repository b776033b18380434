"""Samples from a byte source: the source (a serial port), the protocol (text lines), blocks.

The capture pipeline has three replaceable parts:

- a **source** delivers bytes: :class:`~imucal_cli.capture.serial_port.SerialSource` reads a
  serial port with pyserial (a pseudo-terminal of ``imucal simulate --serve`` is one too).
  Anything with ``read() -> bytes`` (empty after a short wait with no data;
  :class:`DeviceGone` when the device disappears), ``close()``, ``describe() -> str`` and
  ``uri -> str`` can stand in for it.
- a **protocol** turns bytes into samples: :class:`LineProtocol` parses text lines of numbers,
  :class:`PrefixedLineProtocol` MotionCal's ``Raw:`` and i2cdevlib's ``a/g:`` lines (with the
  importer's own line parser), :class:`AutoLineProtocol` tells which of the two a device
  prints from its first lines, :class:`WitMotionProtocol` WitMotion's binary frames.  A
  protocol is one class with two members, ``feed(data, host_time) -> SampleBlock`` and
  ``stats``; it may say the raw ``units`` its format fixes.
- a :class:`SampleBlock` holds k samples as arrays, the unit that the recorder appends to the
  session and that user interfaces look at.
"""

from __future__ import annotations

import re

import numpy as np

from imucal_cli.capture.host_clock import HostClock
from imucal_cli.errors import InputError
from imucal_cli.formats.columns import ColumnSpec, SampleBlock
from imucal_cli.formats.importers.serial_lines import LINE_FORMATS, line_format, parse_line
from imucal_cli.formats.importers.text import BLANK, NUMBER
from imucal_cli.formats.importers.witmotion import WitMotionDecoder

__all__ = [
    "AutoLineProtocol",
    "DeviceGone",
    "LineProtocol",
    "PrefixedLineProtocol",
    "MAX_LINE_BYTES",
    "RESYNC_SAMPLES",
    "SampleBlock",
    "WitMotionProtocol",
]

MAX_LINE_BYTES = 4096
"""A partial line longer than this (no newline: binary data, wrong baud rate) is dropped and
counted as malformed, so garbage never grows memory."""

RESYNC_SAMPLES = 10
"""After this many consecutive samples whose device time is not after the last kept one, the
device clock is taken to have wrapped or restarted and the time base is shifted to continue."""


# --------------------------------------------------------------------------------------------
# Text lines
# --------------------------------------------------------------------------------------------

_SEPARATORS = bytes.maketrans(b",;\t", b"   ")


#: Two separators around an empty field: a comma or semicolon, blanks, another one; or two
#: tabs with only spaces between (issue 26: ``1,,3`` must not become the fields 1 and 3).
_EMPTY_FIELD = re.compile(rb"[,;][ \t]*[,;]|\t *\t")


def _lines_with_empty_fields(text: bytes) -> frozenset[int]:
    """Indices of the ``\n``-separated lines of ``text`` that hold an empty field."""
    found = [m.start() for m in _EMPTY_FIELD.finditer(text)]
    if not found:
        return frozenset()
    breaks = np.flatnonzero(np.frombuffer(text, np.uint8) == ord("\n"))
    return frozenset(np.searchsorted(breaks, found).tolist())


class LineProtocol:
    """Text lines of numbers, as Arduino and ESP32 sketches print them.

    A line is numbers separated by commas, semicolons, spaces or tabs (any mix; two separators
    around an empty field make it malformed), ended by
    ``\\n``, ``\\r\\n`` or ``\\r``; :class:`~imucal_cli.formats.columns.ColumnSpec` says which
    number is which channel.  Nothing in a line is ever fatal:

    - blank lines are ignored;
    - lines starting with ``#`` are comments (a sketch's banner): counted in ``comments``;
    - lines with the wrong number of fields, a field that is not a finite number, a partial
      line longer than :data:`MAX_LINE_BYTES`, and samples whose device time is not after the
      previous sample's (a glitch, or a clock that wrapped or restarted) are dropped and
      counted in ``malformed``.  The session format needs strictly increasing times, so such
      samples cannot be kept; after :data:`RESYNC_SAMPLES` such samples in a row the clock is
      taken to have wrapped or restarted and later samples are shifted to follow on.

    Without a ``t`` column the host clock stamps the lines
    (:class:`~imucal_cli.capture.host_clock.HostClock`: at the stream's rate, never after
    they arrived), strictly increasing whatever the batching.

    Parameters
    ----------
    columns : ColumnSpec
        The fields of a line.

    Attributes
    ----------
    stats : dict
        ``lines`` (complete non-blank lines), ``samples`` (kept), ``comments``, ``malformed``,
        and ``bytes`` (received).
    not_numbers : dict
        Per field name, the lines of the right length dropped because that field was not a
        finite number (``nan``, ``inf``: an axis the sketch could not read).
    """

    def __init__(self, columns: ColumnSpec) -> None:
        self.columns = columns
        self._skipped = frozenset(j for j, name in enumerate(columns.names) if name == "_")
        self.stats = {"lines": 0, "samples": 0, "comments": 0, "malformed": 0, "bytes": 0}
        self.not_numbers: dict[str, int] = {}
        self._partial = b""
        self._last_time: float | None = None  # last kept sample time, s
        self.host_clock = HostClock()  # stamps lines without a ``t`` column
        self._offset = 0.0  # added to device times after a wrap/restart
        self._behind = 0  # consecutive samples not after the last kept one
        self._dt = 0.0  # recent sample interval, s (for a resync)

    def set_origin(self, host_time: float) -> None:
        """When the stream could start (the port opened), host clock, s: the first lines,
        host-stamped, are spread from there to their arrival (not crowded before it)."""
        self.host_clock.set_origin(host_time)

    def feed(self, data: bytes, host_time: float) -> SampleBlock:
        """Parse the complete lines of ``data`` (after what was left over by the last call).

        Parameters
        ----------
        data : bytes
            Bytes as received; a trailing partial line is kept for the next call.
        host_time : float
            Host clock when ``data`` arrived, s (used without a ``t`` column).

        Returns
        -------
        SampleBlock
            The valid samples of the completed lines (possibly none).
        """
        stats = self.stats
        stats["bytes"] += len(data)
        text, self._partial = _complete_text(self._partial + data if self._partial else data,
                                             stats)  # fmt: skip
        if text is None:
            return SampleBlock.empty()
        empty = _lines_with_empty_fields(text)
        text = text.translate(_SEPARATORS)
        n_fields = self.columns.n_fields
        tokens: list[bytes] = []
        n_good = 0
        for k, line in enumerate(text.split(b"\n")):
            fields = line.split()
            if not fields:
                continue
            stats["lines"] += 1
            if fields[0][:1] == b"#":
                stats["comments"] += 1
            elif len(fields) != n_fields or k in empty:
                stats["malformed"] += 1
            else:
                if self._skipped:  # `_` fields may hold anything (a text tag): read as 0
                    fields = [b"0" if j in self._skipped else f for j, f in enumerate(fields)]
                tokens.extend(fields)
                n_good += 1
        if n_good == 0:
            return SampleBlock.empty()
        try:
            rows = np.array(tokens, dtype=np.float64).reshape(n_good, n_fields)
        except ValueError:  # some field is not a number: parse line by line
            rows = self._rows_one_by_one(tokens, n_fields)
        finite = np.isfinite(rows).all(axis=1)
        if not finite.all():
            stats["malformed"] += int((~finite).sum())
            for j, n in enumerate((~np.isfinite(rows[~finite])).sum(axis=0)):
                if n:
                    name = self.columns.names[j]
                    self.not_numbers[name] = self.not_numbers.get(name, 0) + int(n)
            rows = rows[finite]
        if rows.shape[0] == 0:
            return SampleBlock.empty()
        if self.columns.time is None:
            block = self.columns.to_block(rows, self._host_stamps(rows.shape[0], host_time))
        else:
            block = self.columns.to_block(rows)
            block.host_time = np.full(len(block), float(host_time))  # arrival, host clock
            keep = self._accept_device_times(block.time)
            if keep is not None:
                block = block.take(keep)
        if len(block):
            self._last_time = float(block.time[-1])
        stats["samples"] += len(block)
        return block

    # helpers ---------------------------------------------------------------------------------
    def _rows_one_by_one(self, tokens: list[bytes], n_fields: int) -> np.ndarray:
        rows = []
        for i in range(0, len(tokens), n_fields):
            try:
                rows.append([float(x) for x in tokens[i : i + n_fields]])
            except ValueError:
                self.stats["malformed"] += 1
        return np.array(rows, dtype=np.float64).reshape(-1, n_fields)

    def _host_stamps(self, k: int, host_time: float) -> np.ndarray:
        return self.host_clock.stamps(k, host_time, after=self._last_time)

    def _accept_device_times(self, t: np.ndarray) -> np.ndarray | None:
        """Shift ``t`` in place by the resync offset; return the mask of samples to keep, or
        None when every sample is kept."""
        if self._offset:
            t += self._offset
        last = -np.inf if self._last_time is None else self._last_time
        if t[0] > last and (t.size == 1 or bool((np.diff(t) > 0).all())):
            self._behind = 0
            if t.size > 1:
                self._dt = float(np.median(np.diff(t)))
            return None
        keep = np.zeros(t.size, dtype=bool)
        for i in range(t.size):
            if t[i] > last:
                keep[i], last, self._behind = True, float(t[i]), 0
                continue
            self._behind += 1
            if self._behind >= RESYNC_SAMPLES:  # wrapped or restarted: continue after `last`
                shift = last + (self._dt or 1e-3) - t[i]
                self._offset += shift
                t[i:] += shift
                keep[i], last, self._behind = True, float(t[i]), 0
        self.stats["malformed"] += int((~keep).sum())
        return keep


# --------------------------------------------------------------------------------------------
# MotionCal and i2cdevlib lines
# --------------------------------------------------------------------------------------------

_COUNTERS = ("lines", "samples", "comments", "malformed", "bytes")


def _complete_text(buffer: bytes, stats: dict) -> tuple[bytes | None, bytes]:
    """The complete lines of ``buffer`` (ended by ``\n``, ``\r\n`` or ``\r``) as one text
    with ``\n`` between them (None when there is no line end), and the partial line left
    (dropped, and counted malformed, past :data:`MAX_LINE_BYTES`)."""
    cut = max(buffer.rfind(b"\n"), buffer.rfind(b"\r"))
    partial = buffer[cut + 1 :]
    if len(partial) > MAX_LINE_BYTES:
        stats["malformed"] += 1
        partial = b""
    if cut < 0:
        return None, partial
    return buffer[:cut].replace(b"\r", b"\n"), partial


def _complete_lines(buffer: bytes, stats: dict) -> tuple[list[bytes], bytes]:
    """:func:`_complete_text`, split into its lines (none without a line end)."""
    text, partial = _complete_text(buffer, stats)
    return ([] if text is None else text.split(b"\n")), partial


class PrefixedLineProtocol:
    """MotionCal's ``Raw:ax,ay,az,gx,gy,gz,mx,my,mz`` and i2cdevlib's ``a/g:`` / ``a/g/m:``
    lines (:data:`~imucal_cli.formats.importers.serial_lines.LINE_FORMATS`), each read by the
    importer's :func:`~imucal_cli.formats.importers.serial_lines.parse_line`, so that a line
    means the same live and from a file.

    The format is that of the first line with a known prefix among ``formats``; the values
    are raw counts (accel, gyro, and the magnetometer where the format has one).  Other lines
    (MotionCal's ``Uni:`` and ``Cal1:``, a sketch's banner, another format's lines) are counted
    as ``comments``; lines of the format without its numbers as ``malformed``.  The lines
    carry no time: the host clock stamps them as for text lines without ``t``.

    Attributes
    ----------
    fmt : str or None
        The format seen (None before the first line of one).
    stats : dict
        As :class:`LineProtocol`'s.
    """

    def __init__(self, formats: tuple[str, ...] = tuple(LINE_FORMATS)) -> None:
        unknown = [f for f in formats if f not in LINE_FORMATS]
        if unknown or not formats:
            raise InputError(f"unknown line format {unknown}: use {', '.join(LINE_FORMATS)}")
        self.formats = tuple(formats)
        self.fmt: str | None = None
        self.stats = dict.fromkeys(_COUNTERS, 0)
        self._partial = b""
        self.host_clock = HostClock()

    def set_origin(self, host_time: float) -> None:
        """When the stream could start (the port opened), host clock, s: the first lines,
        host-stamped, are spread from there to their arrival (not crowded before it)."""
        self.host_clock.set_origin(host_time)

    @property
    def units(self) -> dict[str, str]:
        """The raw units the format fixes: counts (the magnetometer's only where it has one)."""
        units = {"accel_units": "counts", "gyro_units": "counts"}
        if self.fmt is not None and LINE_FORMATS[self.fmt][1] == 9:
            units["mag_units"] = "counts"
        return units

    def feed(self, data: bytes, host_time: float) -> SampleBlock:
        """Parse the complete lines of ``data``; return their samples (host-clock times)."""
        stats = self.stats
        stats["bytes"] += len(data)
        lines, self._partial = _complete_lines(self._partial + data, stats)
        rows = []
        for raw in lines:
            text = raw.decode("utf-8", errors="replace")
            if not text.strip(BLANK):
                continue
            stats["lines"] += 1
            fmt = line_format(text, self.formats)
            if fmt is None or fmt != (self.fmt or fmt):
                stats["comments"] += 1
                continue
            self.fmt = fmt
            values = parse_line(fmt, text)
            if values is None:
                stats["malformed"] += 1
            else:
                rows.append(values)
        if not rows:
            return SampleBlock.empty()
        values = np.array(rows, dtype=np.float64)
        time = self.host_clock.stamps(len(rows), host_time)
        stats["samples"] += len(rows)
        return SampleBlock(time=time, accel=values[:, 0:3], gyro=values[:, 3:6],
                           mag=values[:, 6:9] if values.shape[1] == 9 else None)  # fmt: skip


class AutoLineProtocol:
    """Text lines, either kind: MotionCal or i2cdevlib lines when a line with their prefix
    comes first (:class:`PrefixedLineProtocol`), else lines of numbers as ``columns`` says
    (:class:`LineProtocol`).  ``imucal capture``'s default ``--protocol lines``.

    The first bytes are held until one line has a known prefix, or two lines are numbers
    only (the first may be cut: the port opened mid-line), or :data:`DECIDE_LINES` other
    lines (a banner; a wrong baud rate) or :data:`DECIDE_BYTES` came; then the chosen protocol
    reads them all, so its counters cover every byte.

    Parameters
    ----------
    columns : ColumnSpec
        The fields of a line of numbers.
    on_choice : callable, optional
        Called once with what was recognised, for the user.
    """

    DECIDE_LINES = 20
    DECIDE_BYTES = 4 * MAX_LINE_BYTES

    def __init__(self, columns: ColumnSpec, on_choice=None) -> None:
        self._columns = columns
        self._on_choice = on_choice
        self._chosen: LineProtocol | PrefixedLineProtocol | None = None
        self._held = bytearray()
        self._own = dict.fromkeys(_COUNTERS, 0)
        self._origin: float | None = None

    def set_origin(self, host_time: float) -> None:
        """As :meth:`LineProtocol.set_origin` (passed on to the protocol chosen)."""
        self._origin = float(host_time)

    @property
    def stats(self) -> dict:
        return self._own if self._chosen is None else self._chosen.stats

    @property
    def not_numbers(self) -> dict[str, int]:
        """As :attr:`LineProtocol.not_numbers` (empty for the other kinds)."""
        return getattr(self._chosen, "not_numbers", {})

    @property
    def columns(self) -> ColumnSpec | None:
        """The ``--columns`` spec while lines of numbers are read (or not yet told apart)."""
        return self._columns if not isinstance(self._chosen, PrefixedLineProtocol) else None

    @property
    def units(self) -> dict[str, str]:
        return getattr(self._chosen, "units", {})

    @property
    def host_clock(self):
        """The chosen protocol's :class:`~imucal_cli.capture.host_clock.HostClock` (None
        before the choice)."""
        return getattr(self._chosen, "host_clock", None)

    def feed(self, data: bytes, host_time: float) -> SampleBlock:
        """As the chosen protocol's ``feed`` (nothing while the first lines are told apart)."""
        if self._chosen is not None:
            return self._chosen.feed(data, host_time)
        self._held += data
        self._own["bytes"] += len(data)
        kind = self._decide(bytes(self._held))
        if kind is None:
            return SampleBlock.empty()
        if kind == "numbers":
            self._chosen = LineProtocol(self._columns)
        else:
            self._chosen = PrefixedLineProtocol()
        held, self._held = bytes(self._held), bytearray()
        if self._origin is not None:
            self._chosen.set_origin(self._origin)
        block = self._chosen.feed(held, host_time)
        if self._on_choice is not None and kind != "numbers":
            self._on_choice(f"recognised {LINE_FORMATS[kind][2]} lines (host-clock time; "
                            "--columns not used)")  # fmt: skip
        return block

    def _decide(self, held: bytes) -> str | None:
        """``"numbers"``, a :data:`LINE_FORMATS` name, or None (not yet told apart)."""
        lines, _ = _complete_lines(held, dict.fromkeys(_COUNTERS, 0))
        numeric = other = 0
        for raw in lines:
            text = raw.decode("utf-8", errors="replace").strip(BLANK)
            if not text or text.startswith("#"):
                continue
            fmt = line_format(text)
            if fmt is not None:
                return fmt
            fields = text.replace(",", " ").replace(";", " ").split()
            if all(NUMBER.match(f) for f in fields):
                numeric += 1
                if numeric >= 2:
                    return "numbers"
            else:
                other += 1
        if other >= self.DECIDE_LINES or len(held) > self.DECIDE_BYTES:
            return "numbers"  # LineProtocol counts what it cannot read
        return None


# --------------------------------------------------------------------------------------------
# The source
# --------------------------------------------------------------------------------------------


class DeviceGone(Exception):
    """The source cannot be read any more (unplugged, closed pseudo-terminal)."""


# --------------------------------------------------------------------------------------------
# WitMotion's binary frames
# --------------------------------------------------------------------------------------------


class WitMotionProtocol:
    """WitMotion's binary protocol (WT901, JY901, HWT905 ...): 11-byte ``0x55`` frames,
    decoded by :class:`~imucal_cli.formats.importers.witmotion.WitMotionDecoder`.

    A sample is an acceleration frame (0x51: int16 counts and the temperature) with the
    angular-velocity frame (0x52) that follows it; the raw counts are kept (``counts``; the
    nominal scale is 16 g and 2000 deg/s per 32768).  The frames carry no sample time, so the
    host clock stamps the samples as for text lines without ``t``.  A sample completes when the
    next acceleration frame arrives.

    Attributes
    ----------
    stats : dict
        ``lines`` (good frames), ``samples`` (kept), ``comments`` (frames of other types:
        angles, quaternions ...), ``malformed`` (checksum failures, bytes skipped to
        resynchronise, samples without an angular-velocity frame), ``bytes``.
    """

    def __init__(self) -> None:
        self._decoder = WitMotionDecoder()
        self.stats = {"lines": 0, "samples": 0, "comments": 0, "malformed": 0, "bytes": 0}
        self._incomplete = 0
        self.host_clock = HostClock()

    def set_origin(self, host_time: float) -> None:
        """When the stream could start (the port opened), host clock, s: the first lines,
        host-stamped, are spread from there to their arrival (not crowded before it)."""
        self.host_clock.set_origin(host_time)

    def feed(self, data: bytes, host_time: float) -> SampleBlock:
        """Decode the frames of ``data``; return the samples they complete."""
        dec = self._decoder
        done = dec.feed(data)
        full = [s for s in done if s.gyro is not None]
        self._incomplete += len(done) - len(full)
        self.stats.update(lines=dec.stats["frames"], comments=dec.stats["skipped"],
                          malformed=dec.stats["malformed"] + self._incomplete,
                          bytes=dec.stats["bytes"])  # fmt: skip
        if not full:
            return SampleBlock.empty()
        time = self.host_clock.stamps(len(full), host_time)
        self.stats["samples"] += len(full)
        return SampleBlock(
            time=time,
            accel=np.array([s.accel for s in full], np.float64),
            gyro=np.array([s.gyro for s in full], np.float64),
            temperature=np.array([s.temperature for s in full], np.float64),
        )
