"""Issue 26.2: the IMU files of the EuRoC MAV and TUM-VI datasets (``mav0/imu0/data.csv``) are
recognised by their header line (a comment: ``#timestamp [ns],w_RS_S_x [rad s^-1],...,a_RS_S_x
[m s^-2],...``, as the datasets publish it): time in ns, gyro before accel, units stated."""

from __future__ import annotations

import numpy as np

from imucal_cli.formats.importers import read_recording
from imucal_cli.formats.session import read_session

from .cli_helpers import run

HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
          "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")  # fmt: skip


def write_euroc(path, n=2000, crlf=False):
    rng = np.random.default_rng(0)
    t = 1403636579758555392 + np.arange(n, dtype=np.int64) * 5_000_000  # 200 Hz, as EuRoC
    w = rng.normal(0, 0.01, (n, 3))
    a = rng.normal(0, 0.05, (n, 3)) + [9.8, 0, 0]
    end = "\r\n" if crlf else "\n"
    lines = [HEADER] + [f"{t[i]}," + ",".join(repr(float(v)) for v in (*w[i], *a[i]))
                        for i in range(n)]  # fmt: skip
    path.write_text(end.join(lines) + end)
    return t, w, a


def test_euroc_and_tum_vi_imu_files_are_recognised(tmp_path):
    path = tmp_path / "data.csv"
    t, w, a = write_euroc(path, crlf=True)  # TUM-VI's files end lines with CR LF
    rec = read_recording([path], None)
    np.testing.assert_array_equal(rec.gyro, w)
    np.testing.assert_array_equal(rec.accel, a)
    np.testing.assert_allclose(rec.time, t * 1e-9, rtol=0, atol=1e-6)  # float64 of 1.4e9 s
    assert (rec.accel_units, rec.gyro_units) == ("m/s^2", "rad/s")
    assert 199.9 < rec.rate_hz < 200.1
    out = tmp_path / "s.h5"
    proc = run("import", path, "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert "EuRoC / TUM-VI IMU file: time in ns" in proc.stdout
    s = read_session(out)
    assert (s.accel_units, s.gyro_units) == ("m/s^2", "rad/s")
