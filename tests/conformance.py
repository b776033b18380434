"""The formats page (``docs/formats.md``, issue 26.3): every format imucal reads or writes, the
library (and version) it was checked with, the tests that check it, what is carried and what
is not.  ``tests/test_formats_page.py`` checks that the page is this table rendered, that every
format registered (``formats.importers.FORMATS``, ``use.export.FORMATS``) has a row, that every
test named exists, and that the installed libraries are at least the versions named.

Regenerate the page after changing the table: ``python -m tests.conformance``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

PAGE = Path(__file__).resolve().parents[1] / "docs" / "formats.md"


@dataclass(frozen=True)
class Row:
    """One format and direction.

    ``fmt``: the ``--format`` name; ``what``: the file; ``checked``: ``(package, version)`` the
    tests read or wrote it with (a PyPI package, or a consumer's own sources or parser);
    ``tests``: ``file::function`` that check it; ``carried`` / ``lost``: what goes through and
    what does not."""

    direction: str
    fmt: str
    what: str
    checked: tuple[tuple[str, str], ...]
    tests: tuple[str, ...]
    carried: str
    lost: str


IMPORTS = (
    Row("import", "csv", "delimited text (commas, semicolons, blanks), header or --columns; "
        "EuRoC MAV / TUM-VI imu0/data.csv by its #timestamp [ns] header",
        (("numpy", "2.0"),),
        ("test_import.py::test_csv_round_trip_segments_and_calibrates_to_truth",
         "test_line_fields.py::test_csv_counts_an_empty_field_as_malformed",
         "test_line_fields.py::test_semicolons_separate_fields_in_import",
         "test_import_euroc.py::test_euroc_and_tum_vi_imu_files_are_recognised",
         "test_imu_set_import.py::test_csv_with_several_triads_per_line",
         "test_cut_last_line.py::test_csv_cut_inside_its_last_number_drops_that_line"),
        "t, accel, gyro, mag, temperature as written; EuRoC's time unit and SI units; several "
        "IMUs' triads per line (.N fields, t.N their own time)",
        "a line with an empty field, a CR inside, or a non-number: left out, counted; a last "
        "line without its line break (the writer stopped mid-line): dropped, warned"),
    Row("import", "imu_tk", "imu_tk's accelerometer and gyroscope files (t x y z)",
        (("numpy", "2.0"),),
        ("test_import.py::test_imu_tk_pair",
         "test_line_fields.py::test_imu_tk_counts_an_empty_field_or_inner_cr_as_malformed",
         "test_cut_last_line.py::test_imu_tk_pair_with_its_gyro_file_cut"),
        "samples at the times present in both files",
        "samples of one file only (counted as unmatched); a last line without its line break: "
        "dropped, warned"),
    Row("import", "ros", "ROS 1 bag, ROS 2 bag (sqlite3 or MCAP storage): sensor_msgs/Imu, "
        "MagneticField, Temperature",
        (("rosbags", "0.11"),),
        ("test_import_formats.py::test_bags_read_back",
         "test_import_stamps.py::test_one_repeated_header_stamp_keeps_the_device_time",
         "test_import_ros.py::test_damaged_recordings_give_one_line_or_the_file_own_values",
         "test_import_px4.py::test_mag_topic_picks_a_ros_magnetometer_outside_the_imu_namespace",
         "test_imu_set_import.py::test_ros_imu_topics_become_one_session"),
        "linear_acceleration (m/s^2), angular_velocity (rad/s), header.stamp (receive time when "
        "unset or mostly out of order), magnetic field (T -> uT) and temperature held per "
        "sample; several Imu topics into one session",
        "orientation and the covariances; a damaged bag has no checksum: a hit value is read "
        "as it stands"),
    Row("import", "ros", "MCAP of ROS 2 (CDR) or ROS 1 (ros1msg) messages, with or without a "
        "summary section",
        (("mcap", "1.6"), ("mcap-ros2-support", "0.5"), ("mcap-ros1-support", "0.9")),
        ("test_import_ros.py::test_mcap_of_ros1_messages_is_read",
         "test_import_ros.py::test_mcap_without_a_summary_is_read",
         "test_import_ros.py::test_an_impossible_length_is_damaged_not_out_of_memory"),
        "as the bags; chunk CRCs checked",
        "messages of other encodings (refused by name)"),
    Row("import", "ulog", "PX4 ULog: sensor_accel_fifo/sensor_gyro_fifo, sensor_accel/"
        "sensor_gyro, vehicle_imu, sensor_combined, sensor_mag",
        (("pyulog", "1.3"),),
        ("test_import_px4.py::test_fifo_topics_read_at_full_rate_with_their_scale",
         "test_import_px4.py::test_vehicle_imu_and_sensor_combined_are_read_and_said_calibrated",
         "test_import_px4.py::test_a_1_hz_log_is_imported_with_a_warning_and_unpaired_samples_said",
         "test_import_px4.py::test_mag_topic_picks_the_ulog_magnetometer",
         "test_import_formats.py::test_ulog_instances",
         "test_imu_set_import.py::test_ulog_instances_become_one_session_and_calibrate_as_a_set"),
        "FIFO samples times scale (m/s^2, rad/s) at full rate; device_id; temperature; sensor_mag "
        "(gauss) held per sample; every instance of several IMUs into one session",
        "PX4's own calibration in vehicle_imu and sensor_combined (a calibration of them is what "
        "remains); clipping counters"),
    Row("import", "mavlink", "MAVLink telemetry log (.tlog): RAW_IMU, SCALED_IMU(2,3), "
        "HIGHRES_IMU",
        (("pymavlink", "2.4"),),
        ("test_import_mavlink.py::test_telemetry_log_streams_units_and_choice",
         "test_import_mavlink.py::test_telemetry_log_receive_stamps_are_the_host_time",
         "test_import_stamps.py::test_one_repeated_time_usec_keeps_the_device_time_and_host_time",
         "test_imu_set_import.py::test_telemetry_raw_imu_and_scaled_imu2_3_become_one_session"),
        "accel, gyro, mag, temperature in each message's units; the receive stamps as "
        "/raw/host_time; one stream per IMU of several into one session",
        "ArduPilot's RAW_IMU holds its calibrated values (said in the notes)"),
    Row("import", "mavlink", "ArduPilot DataFlash (.bin, and text .log): IMU, ACC/GYR, MAG, "
        "ISBH/ISBD batch samples",
        (("pymavlink", "2.4"),),
        ("test_import_mavlink.py::test_dataflash_imu_instances_mag_and_temperature",
         "test_import_mavlink.py::test_dataflash_acc_and_gyr_paired_by_sample_time",
         "test_import_ardupilot.py::test_batch_samples_paired_where_they_overlap",
         "test_import_ardupilot.py::test_batches_that_do_not_overlap_give_the_accelerometer_alone",
         "test_import_ardupilot.py::test_a_text_log_reads_as_its_binary_log",
         "test_imu_set_import.py::test_dataflash_imu_instances_become_one_session",
         "test_cut_last_line.py::test_dataflash_text_log_cut_in_the_last_gyro_value"),
        "m/s^2, rad/s, mGauss -> gauss, T; batch samples int16 / mul at SampleUS + k / smp_rate; "
        "IMU instances of several IMUs into one session",
        "ArduPilot's own offsets and scales in IMU/ACC/GYR (said); ISBD arrays in text logs; "
        "a gyro whose batches do not overlap the accelerometer's; a text log's last line without "
        "its line break: dropped, warned"),
    Row("import", "lines", "MotionCal Raw: and i2cdevlib a/g:, a/g/m: serial lines",
        (("numpy", "2.0"),),
        ("test_import_formats.py::test_motioncal_and_i2cdevlib_lines",
         "test_line_fields.py::test_prefixed_lines_count_an_empty_field_as_malformed",
         "test_cut_last_line.py::test_motioncal_lines_cut_in_the_last_count"),
        "raw counts, time = line of the format / --rate (a malformed line leaves its gap)",
        # the format has no time: lines merged by damage (a lost line break) cannot be told
        "other lines (Uni:, Cal1:, banners); a line with an empty field (counted); no time of "
        "its own: lines merged by a lost line break shift the later times; a last line without "
        "its line break: dropped, warned"),
    Row("import", "witmotion", "WitMotion 0x55 frames (0x50 time, 0x51 accel, 0x52 gyro, 0x54 "
        "mag)",
        (("numpy", "2.0"),),
        ("test_import_formats.py::test_witmotion_file",
         "test_import_stamps.py::test_witmotion_keeps_the_gyro_when_one_frame_is_missing"),
        "int16 counts, temperature, device time or --rate",
        "frames of other types; a sample whose 0x52 frame is lost (counted, warned)"),
)  # fmt: skip

EXPORTS = (
    Row("export", "c-header", "C99 constants and inline apply functions",
        (("gcc", "12"),),
        ("test_export.py::test_header_compiles_and_applies_like_numpy_float32",
         "test_export.py::test_header_carries_the_gyro_g_sensitivity"),
        "matrix, bias, bias_tempco, g_sensitivity, mag; any channel count",
        "float32 rounding (9 significant digits)"),
    Row("export", "json", "imucal's standard fields", (("json", "stdlib"),),
        ("test_export.py::test_json_standard_fields_round_trip",),
        "every term of the spec", "the solvers' extra fields"),
    Row("export", "yaml", "ROS imu_calib SM, bias (the published m/s^2)", (("PyYAML", "6.0"),),
        ("test_export.py::test_yaml_imu_calib_layout",
         "test_export.py::test_yaml_honours_the_scale_and_refuses_counts_without_it"),
        "accel (and gyro under gyro:) for the driver's values (--accel-scale for counts)",
        "g_sensitivity, bias_tempco: refused (g-sensitivity only with --drop)"),
    Row("export", "kalibr-imu", "Kalibr imu.yaml noise", (("PyYAML", "6.0"),),
        ("test_export_targets.py::test_kalibr_imu_noise_file",),
        "the four noise densities (worst axis), rate, topic", "per-axis noise (in comments)"),
    Row("export", "kalibr", "Kalibr scale-misalignment intrinsics", (("PyYAML", "6.0"),),
        ("test_export_targets.py::test_kalibr_reader_reproduces_apply",
         "test_imu_set_use.py::test_imu_chain_puts_each_imu_where_the_reference_sees_it"),
        "M, A (g-sensitivity), C_gyro_i, biases; several IMUs: a chain with T_i_b, time_offset",
        "bias_tempco (refused); the IMUs' translations (zero)"),
    Row("export", "openvins", "OpenVINS kalibr_imu_chain.yaml", (("PyYAML", "6.0"),),
        ("test_export_targets.py::test_openvins_reader_reproduces_apply",
         "test_imu_set_use.py::test_imu_chain_puts_each_imu_where_the_reference_sees_it"),
        "Tw, Ta, R_IMUtoGYRO, Tg, noise, biases; several IMUs: a chain with T_i_b, time_offset",
        "bias_tempco (refused); the IMUs' translations (zero)"),
    Row("export", "basalt", "Basalt calibration.json, complete (no camera)",
        (("basalt-headers schema", "headers_serialization.h"),),
        ("test_export_targets.py::test_basalt_reader_reproduces_apply",
         "test_export_estimators.py::test_basalt_calibration_is_complete"),
        "calib_accel_bias, calib_gyro_bias, rate, per-axis noise",
        "g_sensitivity (refused unless --drop), bias_tempco (refused)"),
    Row("export", "px4", "PX4 .params CAL_ACC0/GYRO0/MAG0, TC_*", (("QGC .params", "text"),),
        ("test_export_targets.py::test_offset_scale_targets_exact_without_misalignment",
         "test_mag_export.py::test_px4_and_ardupilot_apply_the_symmetric_part_exactly",
         "test_imu_set_use.py::test_px4_parameters_per_imu",
         "test_imu_set_use.py::test_px4_set_each_imu_at_its_instance_with_its_own_device_id"),
        "offsets, accel diagonal scale, mag offset and symmetric scale, temperature terms; "
        "several IMUs as CAL_ACC0..3, CAL_GYRO0..3, each with its own device id "
        "(--device-id NAME=N)",
        "misalignment (in degrees in the file), gyro scale, g_sensitivity (refused unless "
        "--drop)"),
    Row("export", "ardupilot", "ArduPilot .parm INS_*, COMPASS_*", (("ArduPilot .parm", "text"),),
        ("test_export_targets.py::test_offset_scale_targets_exact_without_misalignment",
         "test_mag_export.py::test_px4_and_ardupilot_apply_the_symmetric_part_exactly",
         "test_imu_set_use.py::test_ardupilot_parameters_per_imu_read_by_pymavlink"),
        "offsets, accel diagonal scale, temperature terms, COMPASS_OFS/DIA/ODI; several IMUs as "
        "INS_ACC/ACC2/ACC3 and INS_GYR/GYR2/GYR3",
        "misalignment (in degrees in the file), gyro scale, g_sensitivity (refused unless "
        "--drop)"),
    Row("export", "fusion", "x-io Fusion C constants: 1.3 (flat FusionMatrix) by default, 1.2 "
        "with --fusion-version 1.2",
        (("Fusion sources", "1.3.2"), ("Fusion sources", "1.2.9"), ("gcc", "12")),
        ("test_fusion_export.py::test_compiled_against_fusion_gives_what_imucal_apply_gives",
         "test_fusion_export.py::test_magnetometer_compiled_against_fusion_gives_what_imucal_"
         "apply_gives",
         "test_fusion_export.py::test_a_file_for_the_other_layout_does_not_compile"),
        "misalignment, sensitivity, offset (g, deg/s); softIronMatrix, hardIronOffset",
        "g_sensitivity (refused unless --drop), bias_tempco (refused)"),
    Row("export", "vins", "VINS-Mono / VINS-Fusion IMU keys",
        (("opencv-python-headless", "4.8"),),
        ("test_export_estimators.py::test_vins_config_reads_as_vins_reads_it",),
        "acc_n, gyr_n, acc_w, gyr_w (worst axis), g_norm, imu_topic",
        "the calibration itself (VINS models none: apply it upstream)"),
    Row("export", "orbslam3", "ORB-SLAM3 settings IMU keys",
        (("opencv-python-headless", "4.8"),),
        ("test_export_estimators.py::test_orbslam3_settings_read_as_orbslam3_reads_them",),
        "IMU.NoiseGyro, NoiseAcc, GyroWalk, AccWalk (worst axis), Frequency",
        "the calibration (apply it upstream); IMU.T_b_c1 is the camera's"),
    Row("export", "ros-imu", "sensor_msgs/Imu covariances", (("PyYAML", "6.0"),),
        ("test_export_targets.py::test_ros_imu_covariance_is_the_per_sample_variance",),
        "per-sample variances from the noise", "the calibration (apply it upstream)"),
)  # fmt: skip

ROWS = IMPORTS + EXPORTS


def _versions(checked) -> str:
    return ", ".join(f"{name} {version}" for name, version in checked)


def _tests(tests) -> str:
    return "<br>".join(f"`{t}`" for t in tests)


def render() -> str:
    """The page, from :data:`ROWS`."""
    out = [
        "# Formats: what imucal reads and writes, and how each was checked",
        "",
        "Generated from `tests/conformance.py` (`python -m tests.conformance`); "
        "`tests/test_formats_page.py` fails when this page and the table differ, when a format "
        "has no row, or when a test named here does not exist. Each format is checked with the "
        "library that writes or reads it in the field (versions: at least these), never with a "
        "stub; the tests are in `tests/`.",
        "",
        "Every reader gives a damaged file as one line (`imucal: error: ...`, exit 2); "
        "`python -m bench --only reliability` mutates files of every format and counts "
        "tracebacks, wrong exits and silently wrong rows.",
        "",
    ]
    for title, rows in (("Import (`imucal import --format`)", IMPORTS),
                        ("Export (`imucal export --format`)", EXPORTS)):  # fmt: skip
        out += [f"## {title}", "",
                "| format | file | checked with | carried | not carried | tests |",
                "|---|---|---|---|---|---|"]  # fmt: skip
        for r in rows:
            out.append(f"| `{r.fmt}` | {r.what} | {_versions(r.checked)} | {r.carried} | "
                       f"{r.lost} | {_tests(r.tests)} |")  # fmt: skip
        out.append("")
    return "\n".join(out)


if __name__ == "__main__":
    PAGE.parent.mkdir(exist_ok=True)
    PAGE.write_text(render())
    print(f"wrote {PAGE}")
