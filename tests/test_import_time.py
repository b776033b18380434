"""Issue 10.5 on import: a sample rate no IMU has is refused, and a time stamp unit that is off
by a factor is named with the --time-unit that fits (never a silent 0.1 Hz IMU)."""

from __future__ import annotations

import numpy as np
import pytest

from imucal_cli.errors import InputError
from imucal_cli.formats.importers import check_sample_rate, read_recording
from tests.cli_helpers import assert_one_line_error, run


def write_stamped(path, step: float, n: int = 400):
    t = np.arange(n) * step
    rows = np.column_stack([t, np.zeros(n), np.zeros(n), np.full(n, 9.8)])
    path.write_text("\n".join(",".join(f"{v:.9g}" for v in r) for r in rows) + "\n")
    return path


@pytest.mark.parametrize(
    ("step", "unit", "words"),
    [
        (10.0, "s", ["0.1 Hz", "milliseconds", "--time-unit ms (100 Hz)"]),  # ms read as s
        (10_000.0, "s", ["0.0001 Hz", "--time-unit us (100 Hz)"]),  # us read as s
        (0.01, "ms", ["1e+05 Hz", "--time-unit s (100 Hz)"]),  # s read as ms
        (2500.0, "us", ["400 Hz", ""]),  # fine: 2.5 ms steps
        (1e7, "s", ["1e-07 Hz", "nanoseconds", "--time-unit ns (100 Hz)"]),  # ROS stamps
        (2.5e6, "ns", ["400 Hz", ""]),  # fine: nanoseconds, as capture reads them
    ],
)
def test_a_unit_factor_off_is_named(tmp_path, step, unit, words):
    path = write_stamped(tmp_path / "r.csv", step)
    if not words[-1]:
        rec = read_recording([path], "csv", "t,ax,ay,az", time_unit=unit)
        assert rec.rate_hz == pytest.approx(400.0)
        return
    with pytest.raises(InputError) as err:
        read_recording([path], "csv", "t,ax,ay,az", time_unit=unit)
    for w in words:
        assert w in str(err.value), str(err.value)


def test_cli_ms_stamps_without_time_unit_exit_2(tmp_path):
    path = write_stamped(tmp_path / "ms.csv", 10.0, n=2000)
    proc = run("import", path, "--columns", "t,ax,ay,az", "-o", tmp_path / "o.h5")
    assert_one_line_error(proc, "ms.csv", "--time-unit ms")
    assert not (tmp_path / "o.h5").exists()


def test_implausible_rates_without_a_fitting_unit(tmp_path):
    path = write_stamped(tmp_path / "slow.csv", 3.0)  # 0.33 Hz; ms gives 333 Hz: fits
    with pytest.raises(InputError, match="--time-unit ms"):
        read_recording([path], "csv", "t,ax,ay,az")
    with pytest.raises(InputError, match="check the t column"):
        check_sample_rate(1e-12, "s", "x.csv")  # no unit (down to ns) makes that an IMU
    with pytest.raises(InputError, match="--rate 0.5 Hz is implausible"):
        read_recording([path], "csv", "_,ax,ay,az", rate_hz=0.5)


def test_rate_that_contradicts_the_stamps(tmp_path):
    path = write_stamped(tmp_path / "r.csv", 0.01)
    with pytest.raises(InputError, match="100 Hz but --rate says 50 Hz"):
        read_recording([path], "csv", "t,ax,ay,az", rate_hz=50.0)
    rec = read_recording([path], "csv", "t,ax,ay,az", rate_hz=101.0)  # within 10 %
    assert rec.rate_hz == 101.0
