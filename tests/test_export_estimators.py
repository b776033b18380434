"""Issue 26.2: exports for VINS-Mono / VINS-Fusion and ORB-SLAM3 (read as the estimators read
them: OpenCV's FileStorage, ``opencv-python-headless``, each key as their parameter code takes
it: ``fsSettings["acc_n"]`` as a real, ``imu_topic`` as a string, ``imu`` as an int; ORB-SLAM3's
``Settings.cc`` ``IMU.*`` reals) and a complete Basalt calibration (every key of Basalt's cereal
loader, ``basalt-headers`` ``headers_serialization.h``, of the type it reads)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from imucal_cli.errors import InputError
from imucal_cli.formats.exporters import ExportOptions
from imucal_cli.use.export import export

from .cli_helpers import assert_one_line_error, run
from .test_export_targets import ACCEL_SCALE, cal, noise, noise_doc  # noqa: F401 - fixtures

cv2 = pytest.importorskip("cv2")


def file_storage(text: str, tmp_path):
    path = tmp_path / "config.yaml"
    path.write_text(text)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert fs.isOpened()
    return fs


def test_vins_config_reads_as_vins_reads_it(noise, tmp_path, cal):  # noqa: F811
    text = export(cal, "vins", options=ExportOptions(noise=noise, topic="/imu0"))
    fs = file_storage(text, tmp_path)
    assert int(fs.getNode("imu").real()) == 1  # USE_IMU = fsSettings["imu"]
    assert fs.getNode("imu_topic").string() == "/imu0"  # fsSettings["imu_topic"] >> IMU_TOPIC
    want = {"acc_n": max(noise.accel.white), "gyr_n": max(noise.gyro.white),
            "acc_w": max(noise.accel.random_walk), "gyr_w": max(noise.gyro.random_walk)}
    for key, value in want.items():  # ACC_N = fsSettings["acc_n"] ...
        node = fs.getNode(key)
        assert node.isReal(), key
        assert node.real() == pytest.approx(value, rel=1e-15)
    assert fs.getNode("g_norm").real() == pytest.approx(9.80665)


def test_orbslam3_settings_read_as_orbslam3_reads_them(noise, tmp_path):  # noqa: F811
    text = export(None, "orbslam3", options=ExportOptions(noise=noise, rate_hz=400.0))
    fs = file_storage(text, tmp_path)
    want = {"IMU.NoiseGyro": max(noise.gyro.white), "IMU.NoiseAcc": max(noise.accel.white),
            "IMU.GyroWalk": max(noise.gyro.random_walk),
            "IMU.AccWalk": max(noise.accel.random_walk), "IMU.Frequency": 400.0}  # fmt: skip
    for key, value in want.items():  # readParameter<float>(fSettings, "IMU.NoiseGyro", found)
        node = fs.getNode(key)
        assert not node.empty() and node.isReal(), key
        assert node.real() == pytest.approx(value, rel=1e-7)


def test_noise_configs_need_the_noise(tmp_path, cal):  # noqa: F811
    for fmt in ("vins", "orbslam3"):
        with pytest.raises(InputError, match="--noise"):
            export(cal, fmt, options=ExportOptions())
    path = tmp_path / "noise.json"
    path.write_text(json.dumps(noise_doc()))
    proc = run("export", path, "--format", "vins")
    assert proc.returncode == 0 and "acc_n:" in proc.stdout
    assert_one_line_error(run("export", path, "--format", "basalt"), "needs a calibration")


#: Basalt's loader, ``serialize(Archive&, basalt::Calibration&)``: each name and what cereal
#: reads into it (a list of the given length, or of any length, a number, an integer).
BASALT_SCHEMA = {
    "T_imu_cam": list, "intrinsics": list, "resolution": list,
    "calib_accel_bias": 9, "calib_gyro_bias": 12, "imu_update_rate": float,
    "accel_noise_std": 3, "gyro_noise_std": 3, "accel_bias_std": 3, "gyro_bias_std": 3,
    "cam_time_offset_ns": int, "vignette": list,
}  # fmt: skip


def read_basalt(text: str) -> dict:
    """What Basalt's cereal JSONInputArchive reads from ``value0``: every name of
    :data:`BASALT_SCHEMA`, each of its type (cereal throws on a missing name)."""
    value0 = json.loads(text)["value0"]
    for name, kind in BASALT_SCHEMA.items():
        assert name in value0, name
        v = value0[name]
        if kind is list:
            assert isinstance(v, list), name
        elif kind is int:
            assert isinstance(v, int) and not isinstance(v, bool), name
        elif kind is float:
            assert isinstance(v, int | float) and np.isfinite(v), name
        else:
            assert isinstance(v, list) and len(v) == kind, name
            assert all(isinstance(x, int | float) and np.isfinite(x) for x in v), name
    return value0


def test_basalt_calibration_is_complete(cal, noise):  # noqa: F811
    opts = ExportOptions(scale={"accel": ACCEL_SCALE}, noise=noise, rate_hz=200.0,
                         drop=frozenset({"g-sensitivity"}))  # fmt: skip
    value0 = read_basalt(export(cal, "basalt", options=opts))
    np.testing.assert_allclose(value0["accel_noise_std"], noise.accel.white, rtol=1e-15)
    np.testing.assert_allclose(value0["gyro_bias_std"], noise.gyro.random_walk, rtol=1e-15)
    assert value0["imu_update_rate"] == 200.0 and value0["T_imu_cam"] == []
    with pytest.raises(InputError, match="pass --noise"):
        export(cal, "basalt", options=ExportOptions(scale={"accel": ACCEL_SCALE},
                                                    drop=frozenset({"g-sensitivity"})))
