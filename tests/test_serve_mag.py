"""``imucal simulate --serve --mag`` (issue 24.1/24.7): the virtual port streams a pose plan
with a magnetometer as ``imucal simulate --mag`` writes it: the same part, samples and truth.
(Through ``imucal capture`` and ``imucal calibrate``: ``bench live``'s ``six --mag`` row.)"""

from __future__ import annotations

import numpy as np

from imucal_cli.capture.stream import LineProtocol
from imucal_cli.formats.columns import ColumnSpec
from imucal_cli.simulate.device import _plan_lines
from imucal_cli.simulate.magnetometer import simulate_mag

from .cli_helpers import assert_one_line_error, run

MAG = {"field_uT": 48.0, "inclination_deg": 60.0, "mag_units": "counts", "mag_noise": 0.4,
       "layout": "ak8963", "field_known": True, "tumble_s": 4.0}  # fmt: skip


def test_served_lines_are_the_written_session():
    lines, schedule, fields = _plan_lines(
        "six", "lines", seed=2, rate_hz=100.0, hold_s=4.0, units="counts", move_s=1.5,
        plan_options={"mag": MAG, "accel_noise": 0.01, "jitter_deg": 2.0, "still_s": 5.0},
        temperature=True, loop=False, step=False, next_pose=None, say=lambda _: None,
    )  # fmt: skip
    assert fields == "t,ax,ay,az,gx,gy,gz,mx,my,mz,temp"
    protocol = LineProtocol(ColumnSpec.parse(fields))
    block = protocol.feed(b"".join(lines), 0.0)
    written, truth = simulate_mag("six", 2, hold_s=4.0, rate_hz=100.0, units="counts")
    assert protocol.stats["malformed"] == 0 and len(block.time) == len(written.time)
    np.testing.assert_allclose(block.time, written.time, atol=5e-5)  # printed to 0.1 ms
    for name in ("accel", "gyro", "mag"):  # integer counts: exactly
        np.testing.assert_array_equal(getattr(block, name), getattr(written, name))
    assert truth.mag is not None and len(schedule.holds) == 6


def test_serve_mag_refusals(tmp_path):
    assert_one_line_error(run("simulate", "--serve", "--mag", "--plan", "qureshi-axes"),
                          "--mag simulates pose plans", "written or served")  # fmt: skip
    assert_one_line_error(run("simulate", "--serve", "--mag", "--protocol", "motioncal",
                              "--plan", "six"), "prints its own magnetometer")  # fmt: skip
