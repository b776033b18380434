"""Capturing several IMUs at once (issue 28): one port whose lines carry several triads
(``--columns t,ax,...,gz,ax.1,...``), or several ports (``--port A --port B``), one IMU each.

Both give the recorder a :class:`SetBlock`: the reference's samples (``/raw``) and each other
IMU's (``/imus/<name>``), each at its own times, never resampled:

- one port: every line is read once per IMU, with that IMU's fields
  (:func:`imucal_cli.formats.set_columns.split_columns`: the others' are skipped); an IMU
  without its own ``t.N`` takes the line's ``t``;
- several ports (:class:`PortSet`, :class:`PortsProtocol`): the first port is the reference
  and drives the reads; the others are read without waiting at each read.  Each device's
  stamps are its own clock's: an IMU's are put on the reference's clock by the host's arrival
  time of its first sample (its time minus that of the reference's first sample, on the host
  clock); the calibration then measures what remains (a latency of milliseconds) as the
  IMU's time offset.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.columns import ColumnSpec, SampleBlock
from imucal_cli.formats.session import ImuLayout
from imucal_cli.formats.set_columns import imu_number_name, split_columns

from .stream import DeviceGone, LineProtocol

__all__ = ["PortSet", "PortsProtocol", "SetBlock", "SetLineProtocol", "set_protocol"]


@dataclass
class SetBlock(SampleBlock):
    """The reference's samples and ``others``: each other IMU's block of the same read."""

    others: dict[str, SampleBlock] = field(default_factory=dict)

    def take(self, mask: np.ndarray) -> SetBlock:
        """The reference's samples where ``mask`` selects; the other IMUs' up to the last
        reference sample kept (a nearly full disk)."""
        ref = SampleBlock.take(self, mask)
        last = float(ref.time[-1]) if len(ref) else -np.inf
        others = {k: b.take(b.time <= last) for k, b in self.others.items()}
        return SetBlock(ref.time, ref.accel, ref.gyro, ref.temperature, ref.mag, ref.host_time,
                        others)  # fmt: skip


def _layout(spec: ColumnSpec, sensor: str | None = None) -> ImuLayout:
    return ImuLayout(accel=len(spec.accel) or None, gyro=len(spec.gyro) or None,
                     mag=len(spec.mag) or None, temperature=spec.temperature is not None,
                     attrs={} if sensor is None else {"sensor": sensor})  # fmt: skip


class _Protocols:
    """What a capture asks of a set's line protocols: the first one's line counts, and one
    time origin for all."""

    _protocols: list[LineProtocol]

    @property
    def stats(self) -> dict:
        return self._protocols[0].stats

    def set_origin(self, host_time: float) -> None:
        for p in self._protocols:
            p.set_origin(host_time)


class SetLineProtocol(_Protocols):
    """Lines carrying several IMUs' triads (module notes): one :class:`LineProtocol` per IMU
    over the same bytes; ``stats`` are the reference's (every line is every IMU's)."""

    def __init__(self, specs: dict[int, ColumnSpec]) -> None:
        self.names = [imu_number_name(k) for k in specs]
        self._protocols = [LineProtocol(spec) for spec in specs.values()]
        self._specs = list(specs.values())
        self.columns = self._specs[0]

    def imu_layouts(self) -> dict[str, ImuLayout]:
        """The other IMUs' datasets (:class:`~imucal_cli.formats.session.ImuLayout`)."""
        return {n: _layout(s) for n, s in zip(self.names[1:], self._specs[1:], strict=True)}

    @property
    def host_clock(self):
        """The reference's :class:`~imucal_cli.capture.host_clock.HostClock` when no IMU has
        a time field (each has the line's host stamp, so the end of the capture re-times them
        together: :meth:`~imucal_cli.formats.session.SessionWriter.retime`); None when one
        has its own ``t.N`` (its stamps are not the line's)."""
        if any(spec.time is not None for spec in self._specs):
            return None
        return getattr(self._protocols[0], "host_clock", None)

    def feed(self, data: bytes, host_time: float) -> SetBlock:
        blocks = [p.feed(data, host_time) for p in self._protocols]
        ref = blocks[0]
        return SetBlock(ref.time, ref.accel, ref.gyro, ref.temperature, ref.mag, ref.host_time,
                        dict(zip(self.names[1:], blocks[1:], strict=True)))  # fmt: skip


class PortSet:
    """Several serial ports read as one source (module notes): :meth:`read` waits on the
    first (the reference) and takes what waits on the others (:meth:`taken`)."""

    def __init__(self, sources: list) -> None:
        self.sources = sources
        self.opened_at = getattr(sources[0], "opened_at", None)
        self._waiting: list[bytearray] = [bytearray() for _ in sources[1:]]

    @property
    def uri(self) -> str:
        return ",".join(s.uri for s in self.sources)

    def describe(self) -> str:
        return " and ".join(s.describe() for s in self.sources)

    @property
    def reading_backlog(self) -> bool:
        """Whether the reference port is reading a backlog (:class:`SerialSource`)."""
        return bool(getattr(self.sources[0], "reading_backlog", False))

    def take_backlog(self) -> bytes:
        """Every port's backlog still held (:meth:`SerialSource.take_backlog`): the others'
        to be taken as their bytes are, the reference's returned."""
        for k, source in enumerate(self.sources[1:]):
            self._waiting[k] += getattr(source, "take_backlog", bytes)()
        return getattr(self.sources[0], "take_backlog", bytes)()

    def read(self) -> bytes:
        """The reference's bytes (waiting up to its timeout), after the others' waiting bytes
        were taken; raises :class:`DeviceGone` naming the port when any one is gone."""
        for k, source in enumerate(self.sources[1:]):
            try:
                self._waiting[k] += source.read()
            except DeviceGone as exc:
                raise DeviceGone(f"{source.describe()}: {exc}") from None
        return self.sources[0].read()

    def taken(self, k: int) -> bytes:
        """What other port ``k`` (1, 2, ...) sent since the last call."""
        data, self._waiting[k - 1] = bytes(self._waiting[k - 1]), bytearray()
        return data

    def close(self) -> None:
        for s in self.sources:
            s.close()


class PortsProtocol(_Protocols):
    """The lines of a :class:`PortSet`, one IMU per port, each port's lines as ``spec`` says;
    each other IMU's time put on the reference's clock (module notes)."""

    def __init__(self, ports: PortSet, spec: ColumnSpec) -> None:
        self._ports = ports
        self._protocols = [LineProtocol(spec) for _ in ports.sources]
        self.names = ["reference"] + [f"imu{k}" for k in range(1, len(ports.sources))]
        self.columns = spec
        self._first_host: list[float | None] = [None] * len(ports.sources)
        self._first_time: list[float | None] = [None] * len(ports.sources)
        self._held: dict[str, list[SampleBlock]] = {n: [] for n in self.names[1:]}
        self._first_kept = [True] * len(ports.sources)  # the port's first read is in the file

    def imu_layouts(self) -> dict[str, ImuLayout]:
        return {n: _layout(self.columns, s.uri)
                for n, s in zip(self.names[1:], self._ports.sources[1:], strict=True)}  # fmt: skip

    @property
    def host_clock(self):
        """The reference port's :class:`~imucal_cli.capture.host_clock.HostClock` (lines
        without a time field), or None."""
        return None if self.columns.time is not None else self._protocols[0].host_clock

    def other_clocks(self) -> dict[str, tuple]:
        """Each other port's host clock, the shift its stamps were given onto the reference's
        clock (s), and whether its first read is in the session (lines without a time field;
        a port that sent nothing is left out): each port's stamps have their own jitter and
        are re-timed on their own (:meth:`~imucal_cli.capture.writing.SessionWrites.
        _retime_host_stamps`)."""
        if self.columns.time is not None or self._first_time[0] is None:
            return {}
        out = {}
        for k, name in enumerate(self.names[1:], start=1):
            if self._first_time[k] is not None:
                out[name] = (self._protocols[k].host_clock, self._shift(k), self._first_kept[k])
        return out

    def _on_reference_clock(self, k: int, block: SampleBlock, host_time: float) -> SampleBlock:
        if not len(block):
            return block
        if self._first_time[k] is None:
            self._first_time[k], self._first_host[k] = float(block.time[0]), host_time
        if k == 0 or self._first_time[0] is None:
            return block
        block.time = block.time + self._shift(k)
        return block

    def _shift(self, k: int) -> float:
        """What port ``k``'s times are given to be on the reference's clock, s: the arrival
        of its first sample after the reference's, less their time stamps' difference."""
        return (self._first_host[k] - self._first_host[0]) \
            - (self._first_time[k] - self._first_time[0])  # fmt: skip

    def feed(self, data: bytes, host_time: float) -> SetBlock:
        """The reference's block; the other IMUs' blocks held until a read that has one (the
        recorder appends what comes with the reference's samples)."""
        ref = self._on_reference_clock(0, self._protocols[0].feed(data, host_time), host_time)
        for k in range(1, len(self._protocols)):
            block = self._protocols[k].feed(self._ports.taken(k), host_time)
            if len(block) and self._first_time[0] is not None:  # before: no clock to use
                self._held[self.names[k]].append(self._on_reference_clock(k, block, host_time))
            elif len(block):
                self._first_kept[k] = False
        others = {}
        if len(ref):
            others = {n: SampleBlock.concatenate(b) for n, b in self._held.items() if b}
            self._held = {n: [] for n in self._held}
        return SetBlock(ref.time, ref.accel, ref.gyro, ref.temperature, ref.mag, ref.host_time,
                        others)  # fmt: skip


def set_protocol(columns: str, time_unit: str, n_ports: int):
    """The ``--columns`` specs of a capture of several IMUs: ``(specs per IMU number, or
    None for one IMU per line)``; refuses suffixed fields with several ports."""
    specs = split_columns(columns)
    if specs is not None and n_ports > 1:
        raise InputError("--columns with .N fields (several IMUs per line) reads one --port; "
                         "with several ports each port carries one IMU")  # fmt: skip
    if specs is None:
        return None
    return {k: ColumnSpec.parse(v, time_unit) for k, v in specs.items()}
