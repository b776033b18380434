"""ROS recordings written by the libraries that write them in the field, for the importer's
tests and the reliability bench:

- ROS 1 messages in MCAP as ``mcap-ros1-support`` writes them (and ``mcap convert x.bag``):
  ``ros1msg`` schemas holding the message definition of ROS 1 Noetic (from rosbags' Noetic type
  store, with ``uint32 seq`` in the header), messages serialized by genpy (the copy that
  mcap-ros1-support vendors);
- ROS 2 messages in MCAP written by ``mcap``'s own writer, with or without a summary section
  (CDR from rosbags' Humble type store);
- ROS 1 and ROS 2 bags: ``tests/test_import_formats.py:write_bag`` (rosbags' writers).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

TOPIC, MAG_TOPIC, TEMP_TOPIC = "/imu/data", "/imu/mag", "/imu/temperature"


def imu_samples(n: int = 400, seed: int = 0, rate: float = 200.0):
    """Time (s since 1970), specific force (m/s^2) and rate (rad/s) of ``n`` samples."""
    rng = np.random.default_rng(seed)
    t = 1700000000.0 + np.arange(n) / rate
    return t, rng.normal(0, 3, (n, 3)) + [0, 0, 9.8], rng.normal(0, 0.5, (n, 3))


def _ros1_types():
    from mcap_ros1._vendor.genpy import dynamic
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    types = {}
    for name in ("sensor_msgs/Imu", "sensor_msgs/MagneticField", "sensor_msgs/Temperature"):
        pkg, _, msg = name.partition("/")
        text, _ = store.generate_msgdef(f"{pkg}/msg/{msg}", ros_version=1)
        types[name] = dynamic.generate_dynamic(name, text)[name]
    return types


def _stamp(msg, t: float) -> None:
    sec = int(t)
    msg.header.stamp.secs = sec
    msg.header.stamp.nsecs = int(round((t - sec) * 1e9))


def write_mcap_ros1(path: Path, data=None, mag: bool = True, temp: bool = True) -> tuple:
    """An MCAP of ROS 1 ``sensor_msgs/Imu`` (and MagneticField every 4th sample, Temperature
    every 50th), written by mcap-ros1-support's ``Writer``; received 3 ms after the stamp."""
    from mcap_ros1.writer import Writer

    types = _ros1_types()
    t, a, w = imu_samples() if data is None else data
    with open(path, "wb") as handle:
        writer = Writer(handle)
        for i in range(len(t)):
            log_ns = int(round((t[i] + 0.003) * 1e9))
            m = types["sensor_msgs/Imu"]()
            _stamp(m, t[i])
            m.header.frame_id = "imu"
            m.orientation.w = 1.0
            (m.linear_acceleration.x, m.linear_acceleration.y,
             m.linear_acceleration.z) = (float(v) for v in a[i])  # fmt: skip
            (m.angular_velocity.x, m.angular_velocity.y,
             m.angular_velocity.z) = (float(v) for v in w[i])  # fmt: skip
            writer.write_message(TOPIC, m, log_time=log_ns)
            if mag and i % 4 == 0:
                f = types["sensor_msgs/MagneticField"]()
                _stamp(f, t[i])
                f.magnetic_field.x, f.magnetic_field.y, f.magnetic_field.z = 20e-6, -5e-6, 40e-6
                writer.write_message(MAG_TOPIC, f, log_time=log_ns)
            if temp and i % 50 == 0:
                k = types["sensor_msgs/Temperature"]()
                _stamp(k, t[i])
                k.temperature = 25.0 + i / 100
                writer.write_message(TEMP_TOPIC, k, log_time=log_ns)
        writer.finish()
    return t, a, w


def write_mcap_ros2(path: Path, data=None, summary: bool = True) -> tuple:
    """An MCAP of ROS 2 ``sensor_msgs/msg/Imu`` written by ``mcap``'s ``Writer`` (CDR by
    rosbags); ``summary`` False: no summary section (no index, no statistics), which a valid
    MCAP may leave out."""
    from mcap.writer import IndexType, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    text, _ = store.generate_msgdef("sensor_msgs/msg/Imu", ros_version=2)
    t, a, w = imu_samples() if data is None else data
    options = {} if summary else dict(index_types=IndexType.NONE, repeat_channels=False,
                                       repeat_schemas=False, use_statistics=False,
                                       use_summary_offsets=False)  # fmt: skip
    with open(path, "wb") as handle:
        writer = Writer(handle, chunk_size=16384, **options)
        writer.start(profile="ros2", library="imucal tests")
        schema = writer.register_schema("sensor_msgs/msg/Imu", "ros2msg", text.encode())
        channel = writer.register_channel(TOPIC, "cdr", schema)
        Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
        V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
        for i in range(len(t)):
            sec = int(t[i])
            stamp = Time(sec, int(round((t[i] - sec) * 1e9)))
            msg = T["sensor_msgs/msg/Imu"](Header(stamp, "imu"), Q(0.0, 0.0, 0.0, 1.0),
                                           np.zeros(9), V3(*w[i]), np.zeros(9), V3(*a[i]),
                                           np.zeros(9))  # fmt: skip
            log_ns = int(round((t[i] + 0.003) * 1e9))
            writer.add_message(channel, log_ns, store.serialize_cdr(msg, "sensor_msgs/msg/Imu"),
                               log_ns)  # fmt: skip
        writer.finish()
    return t, a, w
