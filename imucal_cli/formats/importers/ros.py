"""ROS recordings: ROS 1 bags and ROS 2 bags (``rosbags``, no ROS install) and MCAP files of
ROS 2 or ROS 1 messages (``mcap`` with ``mcap-ros2-support`` and ``mcap-ros1-support``).
``pip install 'imucal-cli[ros]'`` / ``[mcap]``.  A damaged file is one line and exit 2,
whatever the library raises (:func:`damaged_as_input_error`).

What is read:

- ``sensor_msgs/Imu`` on the topic given by ``topic``, or the only such topic; with several and
  no ``topic`` the reader refuses and lists them.  ``linear_acceleration`` (m/s^2) and
  ``angular_velocity`` (rad/s) as published; time from ``header.stamp`` (the driver's clock)
  when it is set and strictly increasing, else the time the message was recorded.
- ``sensor_msgs/MagneticField`` (tesla, stored in uT) and ``sensor_msgs/Temperature``
  (degrees C) when the recording holds one such topic (or one in the IMU topic's namespace):
  each IMU sample takes the latest field and temperature received at or before it (zero-order
  hold: no value is invented between messages); samples before the first are NaN.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from imucal_cli.errors import InputError

from .library import damaged_as_input_error, quiet
from .recording import STAMPS_KEPT, Recording, SeveralStreams, choose_time, increasing

__all__ = ["Channels", "choose_topic", "hold_latest", "read_mcap", "read_ros", "read_rosbag"]

IMU = "sensor_msgs/msg/Imu"
MAG = "sensor_msgs/msg/MagneticField"
TEMP = "sensor_msgs/msg/Temperature"


@dataclass
class Channels:
    """Samples of a topic-based log, before segmentation (format-neutral).

    Attributes
    ----------
    time : ndarray (N,)
        Seconds, strictly increasing.
    accel, gyro : ndarray (N, 3) or None
        As published.
    accel_units, gyro_units : str
    temperature : ndarray (N,) or None
        Degrees C.
    mag : ndarray (N, 3) or None
    mag_units : str or None
    notes : list of str
        What was chosen and what was left out, for the import summary.
    dropped : int
        Samples dropped (time not increasing, non-finite values).
    host_time : ndarray (N,) or None
        When the host received each sample, s of its clock, beside a ``time`` from the
        device's clock (``/raw/host_time``); None when there is no device time.
    unpaired : int
        Accelerometer and gyroscope samples with no partner of the other sensor (logs that
        carry the two in separate messages).
    warnings : list of str
        What the user should know (see :class:`~.recording.Recording`).
    """

    time: np.ndarray
    accel: np.ndarray | None
    gyro: np.ndarray | None
    accel_units: str
    gyro_units: str
    temperature: np.ndarray | None = None
    mag: np.ndarray | None = None
    mag_units: str | None = None
    notes: list[str] = field(default_factory=list)
    dropped: int = 0
    host_time: np.ndarray | None = None
    unpaired: int = 0
    warnings: list[str] = field(default_factory=list)


def _normal(msgtype: str) -> str:
    """``sensor_msgs/Imu`` (ROS 1) and ``sensor_msgs/msg/Imu`` (ROS 2) are one type."""
    pkg, _, name = msgtype.rpartition("/")
    pkg = pkg.removesuffix("/msg")
    return f"{pkg}/msg/{name}"


def choose_topic(topics: dict[str, str], wanted: str | None, source: str) -> str:
    """The ``sensor_msgs/Imu`` topic to read: ``wanted``, or the only one.

    Raises
    ------
    InputError
        ``wanted`` is not an Imu topic, or several and none chosen, or none at all; the message
        lists the Imu topics (and the others when there is none).
    """
    imu = sorted(t for t, ty in topics.items() if _normal(ty) == IMU)
    if wanted is not None:
        if wanted in imu:
            return wanted
        what = f"of type {topics[wanted]}" if wanted in topics else "not in the recording"
        raise InputError(f"{source}: --topic {wanted} is {what}; sensor_msgs/Imu topics: "
                         f"{', '.join(imu) or 'none'}")  # fmt: skip
    if len(imu) == 1:
        return imu[0]
    if not imu:
        others = ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items())) or "none"
        raise InputError(f"{source}: no sensor_msgs/Imu topic; topics: {others}")
    raise SeveralStreams(f"{source}: several sensor_msgs/Imu topics: {', '.join(imu)}; choose "
                         "one with --topic", imu)  # fmt: skip


def _companion(topics: dict[str, str], kind: str, imu_topic: str,
               wanted: str | None = None, source: str = "") -> tuple[str | None, str]:  # fmt: skip
    """The topic of ``kind`` to read with ``imu_topic``: ``wanted`` (``--mag-topic``), the only
    one, or the one sharing its namespace; with several elsewhere none, and a note naming
    them and the option."""
    found = sorted(t for t, ty in topics.items() if _normal(ty) == kind)
    if wanted is not None:
        if wanted not in found:
            raise InputError(f"{source}: --mag-topic {wanted} is not a "
                             f"{kind.rpartition('/')[2]} topic; they are: "
                             f"{', '.join(found) or 'none'}")  # fmt: skip
        return wanted, ""
    if len(found) == 1:
        return found[0], ""
    namespace = imu_topic.rpartition("/")[0]
    near = [t for t in found if t.rpartition("/")[0] == namespace]
    if len(near) == 1:
        return near[0], ""
    if found:
        option = "; choose one with --mag-topic" if kind == MAG else ""
        return None, (f"{kind.rpartition('/')[2]} topics {', '.join(found)} left out (none in "
                      f"{imu_topic}'s namespace){option}")  # fmt: skip
    return None, ""


def _stamp(msg: Any) -> float:
    """``header.stamp`` in s: ROS 2 ``sec``/``nanosec``, rosbags' ROS 1 ``sec``/``nanosec``,
    genpy's (mcap-ros1-support) ``secs``/``nsecs``."""
    stamp = msg.header.stamp
    sec = getattr(stamp, "sec", None)
    if sec is None:
        sec = getattr(stamp, "secs", 0)
    nanosec = getattr(stamp, "nanosec", None)
    if nanosec is None:
        nanosec = getattr(stamp, "nsec", None)
    if nanosec is None:
        nanosec = getattr(stamp, "nsecs", 0)
    return sec + nanosec * 1e-9


def hold_latest(times: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The latest of ``values`` received at or before each of ``at`` (NaN before the first)."""
    order = np.argsort(times, kind="stable")
    times, values = times[order], values[order]
    idx = np.searchsorted(times, at, side="right") - 1
    out = np.full((len(at), *values.shape[1:]), np.nan)
    ok = idx >= 0
    out[ok] = values[idx[ok]]
    return out


def _vector(v: Any) -> tuple[float, float, float]:
    return (v.x, v.y, v.z)


def build(
    topics: dict[str, str],
    messages: Callable[[list[str]], Iterable[tuple[str, int, Any]]],
    wanted: str | None,
    source: str,
    mag_wanted: str | None = None,
) -> Channels:
    """Channels from a log given its ``topics`` (name -> type) and ``messages(topics)``, an
    iterator of ``(topic, log_time_ns, decoded message)``."""
    imu_topic = choose_topic(topics, wanted, source)
    notes = [f"sensor_msgs/Imu from {imu_topic}"]
    mag_topic, mag_note = _companion(topics, MAG, imu_topic, mag_wanted, source)
    temp_topic, temp_note = _companion(topics, TEMP, imu_topic)
    notes += [n for n in (mag_note, temp_note) if n]
    read = [t for t in (imu_topic, mag_topic, temp_topic) if t is not None]
    imu_rows, stamps, logged = [], [], []
    mag_t, mag_v, temp_t, temp_v = [], [], [], []
    def fields():  # a damaged schema makes a type without these fields: damaged too
        for topic, log_ns, msg in messages(read):
            if topic == imu_topic:
                yield topic, log_ns, (*_vector(msg.linear_acceleration),
                                      *_vector(msg.angular_velocity)), _stamp(msg)  # fmt: skip
            elif topic == mag_topic:
                yield topic, log_ns, _vector(msg.magnetic_field), _stamp(msg)
            elif topic == temp_topic:
                yield topic, log_ns, float(msg.temperature), _stamp(msg)

    with quiet():  # mcap-ros2-support prints the schema lines it cannot parse
        for topic, log_ns, values, stamp in damaged_as_input_error(fields(), source):
            if topic == imu_topic:
                imu_rows.append(values)
                stamps.append(stamp)
                logged.append(log_ns * 1e-9)
            elif topic == mag_topic:
                mag_t.append(stamp or log_ns * 1e-9)
                mag_v.append(values)
            else:
                temp_t.append(stamp or log_ns * 1e-9)
                temp_v.append(values)
    if not imu_rows:
        raise InputError(f"{source}: topic {imu_topic} holds no messages")
    rows = np.asarray(imu_rows, np.float64)
    stamps_a, logged_a = np.asarray(stamps), np.asarray(logged)
    finite = np.isfinite(rows).all(axis=1)
    time, use_stamp, out_of_order = choose_time(stamps_a, logged_a, finite)
    notes.append(("time from header.stamp" + (f" ({out_of_order} messages whose stamp did not "
                                              "follow the previous one left out)"
                                              if out_of_order else "")) if use_stamp else
                 "time from the recording's receive time (header.stamp unset, or not increasing "
                 f"for {100 * STAMPS_KEPT:g} % of the messages)")  # fmt: skip
    keep = increasing(time, finite)  # drop samples whose time does not follow the last kept one
    dropped = int((~keep).sum())
    time, rows = time[keep], rows[keep]
    ch = Channels(time=time, accel=rows[:, :3], gyro=rows[:, 3:], accel_units="m/s^2",
                  gyro_units="rad/s", notes=notes, dropped=dropped)  # fmt: skip
    if mag_v:
        ch.mag = hold_latest(np.asarray(mag_t), np.asarray(mag_v) * 1e6, time)  # T -> uT
        ch.mag_units = "uT"
        notes.append(f"sensor_msgs/MagneticField from {mag_topic} (tesla -> uT), latest per sample")
    if temp_v:
        ch.temperature = hold_latest(np.asarray(temp_t), np.asarray(temp_v, float), time)
        notes.append(f"sensor_msgs/Temperature from {temp_topic}, latest per sample")
    return ch


def _missing(extra: str, module: str) -> InputError:
    return InputError(f"reading this file needs {module}: pip install 'imucal-cli[{extra}]'")


def read_rosbag(path: str | os.PathLike, topic: str | None = None,
                mag_topic: str | None = None) -> Channels:  # fmt: skip
    """A ROS 1 bag (``.bag``) or a ROS 2 bag (a directory with ``metadata.yaml``), read with
    ``rosbags``.

    Raises
    ------
    InputError
        ``rosbags`` not installed (names the extra), an unreadable bag, or the topic choice.
    """
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise _missing("ros", "rosbags") from None
    src = str(path)
    try:
        reader = AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags raises its own error types
        raise InputError(f"{src}: not a readable ROS bag ({' '.join(str(exc).split())})") from None
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}

        def messages(wanted: list[str]) -> Iterator[tuple[str, int, Any]]:
            conns = [c for c in reader.connections if c.topic in wanted]
            for conn, log_ns, raw in reader.messages(connections=conns):
                yield conn.topic, log_ns, reader.deserialize(raw, conn.msgtype)

        return build(topics, messages, topic, src, mag_topic)
    finally:
        try:
            reader.close()
        except Exception:  # noqa: BLE001, S110 - closing a damaged bag: the error is said above
            pass


#: MCAP message encodings read, and the package whose decoder reads each.
MCAP_DECODERS = {"cdr": ("mcap_ros2.decoder", "mcap-ros2-support"),
                 "ros1": ("mcap_ros1.decoder", "mcap-ros1-support")}  # fmt: skip


def _decoder_factories() -> dict[str, Any]:
    """MCAP decoders of ROS 2 (CDR, ``mcap-ros2-support``) and ROS 1 messages (``ros1msg``
    schemas, what ``mcap convert x.bag`` and ``mcap-ros1-support`` write), by encoding: the
    ones installed."""
    factories = {}
    for encoding, (module, _) in MCAP_DECODERS.items():
        try:
            factories[encoding] = importlib.import_module(module).DecoderFactory()
        except ImportError:
            pass
    return factories


def _mcap_readers(handle, factories: list):
    """``(seeking, passes)``: ``seeking`` the reader of a file with a summary section (None
    without one), and ``passes()`` a reader of every message from the start (a fresh stream
    reader per pass for a file without a summary, a valid MCAP that ends without one).  Both
    check the chunk CRCs and bound a record by the file's size: a damaged length is refused,
    never an allocation of gigabytes."""
    from mcap.reader import NonSeekingReader, SeekingReader

    size = os.fstat(handle.fileno()).st_size
    options = dict(validate_crcs=True, decoder_factories=factories, record_size_limit=size)
    seeking = SeekingReader(handle, **options)
    if seeking.get_summary() is not None:
        return seeking, lambda: seeking

    def passes():
        handle.seek(0)
        return NonSeekingReader(handle, **options)

    return None, passes


def _mcap_topics(seeking, passes, src: str) -> dict[str, tuple[str, str]]:
    """Topic -> (schema name, message encoding): from the summary section, or, for a file
    without one, from the channels its messages use."""
    if seeking is not None:
        summary = seeking.get_summary()
        schemas = summary.schemas
        return {ch.topic: (schemas[ch.schema_id].name, ch.message_encoding)
                for ch in summary.channels.values() if ch.schema_id in schemas}  # fmt: skip
    topics: dict[str, tuple[str, str]] = {}
    for schema, channel, _ in damaged_as_input_error(passes().iter_messages(), src):
        if schema is not None and channel.topic not in topics:
            topics[channel.topic] = (schema.name, channel.message_encoding)
    return topics


def read_mcap(path: str | os.PathLike, topic: str | None = None,
              mag_topic: str | None = None) -> Channels:  # fmt: skip
    """An MCAP file of ROS 2 (``ros2msg`` schemas, CDR) or ROS 1 messages (``ros1msg``), read
    with ``mcap`` and ``mcap-ros2-support`` / ``mcap-ros1-support``; with or without a
    summary section; chunk CRCs checked (a damaged chunk is refused, never read as numbers).

    Raises
    ------
    InputError
        The libraries not installed (names the extra), an unreadable or damaged file, a
        message encoding no decoder reads, or the topic choice.
    """
    try:
        import mcap.reader  # noqa: F401
    except ImportError:
        raise _missing("mcap", "mcap and mcap-ros2-support") from None
    factories = _decoder_factories()
    src = str(path)
    try:
        handle = open(path, "rb")
    except OSError as exc:
        raise InputError(f"{src}: cannot read ({exc.strerror or exc})") from None
    with handle:
        try:
            seeking, passes = _mcap_readers(handle, list(factories.values()))
            found = _mcap_topics(seeking, passes, src)
        except InputError:
            raise
        except MemoryError:
            raise InputError(f"{src}: damaged MCAP file (a record asks for more memory than "
                             "there is)") from None  # fmt: skip
        except Exception as exc:  # noqa: BLE001 - mcap raises its own error types
            raise InputError(f"{src}: not a readable MCAP file "
                             f"({' '.join(str(exc).split())[:160]})") from None  # fmt: skip
        topics = {name: schema for name, (schema, _) in found.items()}
        encodings = {name: enc for name, (_, enc) in found.items()}

        def messages(wanted: list[str]) -> Iterator[tuple[str, int, Any]]:
            for name in wanted:
                encoding = encodings.get(name)
                if encoding in factories:
                    continue
                if encoding in MCAP_DECODERS:
                    raise _missing("mcap", MCAP_DECODERS[encoding][1])
                raise InputError(f"{src}: topic {name} has message encoding {encoding!r}; "
                                 "ROS 2 (cdr) and ROS 1 (ros1) messages are read")  # fmt: skip
            for _, channel, message, decoded in passes().iter_decoded_messages(topics=wanted):
                yield channel.topic, message.log_time, decoded

        return build(topics, messages, topic, src, mag_topic)


def read_ros(path: str | os.PathLike, topic: str | None = None,
             mag_topic: str | None = None) -> Channels:  # fmt: skip
    """A ``.mcap`` file with :func:`read_mcap`, anything else (``.bag``, a ROS 2 bag folder)
    with :func:`read_rosbag`."""
    p = Path(path)
    if p.suffix.lower() == ".mcap" and p.is_file():
        return read_mcap(p, topic, mag_topic)
    return read_rosbag(p, topic, mag_topic)


# --------------------------------------------------------------------------------------------
# The importer interface (``imucal import --format ros``)
# --------------------------------------------------------------------------------------------

NAME = "ros"
FILES = "one ROS 1 bag (.bag), ROS 2 bag (its folder) or MCAP file (.mcap)"


def one_file(paths, options, name: str, files: str) -> Path:
    """The single path of a format that reads one file and has named channels.

    Raises
    ------
    InputError
        Not one path, or a ``--columns`` spec.
    """
    if len(paths) != 1:
        raise InputError(f"--format {name} takes {files}; got {len(paths)} paths")
    if options.columns is not None:
        raise InputError(f"--columns does not apply to --format {name} (its channels are named)")
    return Path(paths[0])


def to_recording(ch: Channels, paths, stats, columns: list[str] | None = None):
    """A :class:`~.recording.Recording` of ``ch`` (the importers' common return)."""
    stats.samples = len(ch.time)
    stats.dropped += ch.dropped
    stats.unpaired += ch.unpaired
    return Recording(
        time=ch.time, accel=ch.accel, gyro=ch.gyro, temperature=ch.temperature,
        rate_hz=float("nan"), names=[Path(p).name for p in paths],
        columns=columns or ["t", "ax", "ay", "az", "gx", "gy", "gz"], stats=stats,
        accel_units=ch.accel_units, gyro_units=ch.gyro_units, mag=ch.mag,
        mag_units=ch.mag_units, notes=list(ch.notes), host_time=ch.host_time,
        warnings=list(ch.warnings),
    )  # fmt: skip


def read(paths, options, stats):
    """``imucal import --format ros``: :func:`read_ros` of the one path, ``--topic``."""
    path = one_file(paths, options, NAME, FILES)
    return to_recording(read_ros(path, options.topic, options.mag_topic), paths, stats)
