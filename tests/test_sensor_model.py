"""The shared sensor model of the virtual IMU (simulate/sensor.py) and the motion timeline."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imucal_cli.simulate.motion import Timeline, smootherstep, up_to_vertical
from imucal_cli.simulate.sensor import G0, ChannelGroup, random_imu


def _group(**kw) -> ChannelGroup:
    S = np.array([[2.0, 0.1, 0.0], [0.0, 3.0, 0.2], [0.1, 0.0, 4.0], [1.0, 1.0, 1.0]])
    base = dict(name="accel", input_unit="m/s^2", units="counts", S=S, b=np.arange(4.0))
    return ChannelGroup(**{**base, **kw})


def test_raw_is_quantised_clipped_sensitivity_times_input_plus_bias_and_noise():
    g = _group(quantise=True, limits=(-5.0, 40.0))
    x = np.array([[1.0, 2.0, 3.0], [100.0, 0.0, 0.0], [-10.0, 0.0, 0.0]])
    n_in = np.full((3, 3), 0.25)
    n_out = np.full((3, 4), 0.4)
    want = np.clip(np.rint((x + n_in) @ g.S.T + g.b + n_out), -5.0, 40.0)
    np.testing.assert_array_equal(g.raw(x, n_in, n_out), want)
    assert g.raw(x)[1, 0] == 40.0 and g.raw(x)[2, 0] == -5.0  # saturates at the ADC range
    assert g.channels == 4


def test_only_declared_noise_is_drawn_in_input_then_output_order():
    rng = np.random.default_rng(1)
    n_in, n_out = _group(noise_in=np.full(3, 0.5), noise_out=2.0).draw_noise(rng, 5)
    ref = np.random.default_rng(1)
    np.testing.assert_array_equal(n_in, ref.standard_normal((5, 3)) * 0.5)
    np.testing.assert_array_equal(n_out, ref.standard_normal((5, 4)) * 2.0)
    assert _group().draw_noise(np.random.default_rng(1), 5) == (None, None)


def test_truth_inverts_the_model_in_si_units_for_redundant_and_g_inputs():
    g = _group(input_unit="g")  # counts per g, 4 channels
    cal = g.truth({})
    f = np.array([[0.1, -0.2, 0.97]])  # in g
    np.testing.assert_allclose(cal.apply(g.raw(f)), G0 * f, rtol=1e-12)
    assert cal.units == "m/s^2" and cal.matrix.shape == (3, 4)


def test_imu_reads_groups_by_name_and_samples_in_group_order():
    imu = random_imu(np.random.default_rng(3), "counts", accel_noise=0.02, gyro_noise=0.001)
    assert imu.accel is imu.group("accel") and imu.accel_S is imu.accel.S
    assert imu.gyro_noise is imu.gyro.noise_in and imu.quantise
    assert imu.accel_bias_g is imu.accel.datasheet["bias_g"]
    with pytest.raises(AttributeError):
        _ = imu.mag_S
    x = np.zeros((50, 3))
    raw = imu.sample({"accel": x, "gyro": x}, np.random.default_rng(9))
    ref = np.random.default_rng(9)
    accel_n, gyro_n = ref.standard_normal((50, 3)) * 0.02, ref.standard_normal((50, 3)) * 0.001
    np.testing.assert_array_equal(raw["accel"], imu.accel_raw(x, accel_n))
    np.testing.assert_array_equal(raw["gyro"], imu.gyro_raw(x, gyro_n))


def test_session_and_truth_round_trip_the_motion():
    imu = random_imu(np.random.default_rng(4), "m/s^2", accel_noise=0.0, gyro_noise=0.0)
    tl = Timeline(100.0, G0, up_to_vertical(np.array([1.0, 0.0, 0.0])))
    tl.segment("static", tl.hold(20), "face +X up", up=[1.0, 0.0, 0.0])
    tl.segment("rotation", tl.smooth_turn(np.array([1.0, 0.0, 0.0]), np.pi / 2, 80), "turn")
    force, rate = tl.arrays()
    opt = {"plan": "test", "seed": 4, "rate_hz": 100.0, "gravity": G0}
    session, truth = imu.session_and_truth(
        {"accel": force, "gyro": rate}, tl.segments, noise_seed=np.random.SeedSequence(0),
        options=opt, sensor="unit test", extras={"gyro": {"design": "unit test"}},
    )  # fmt: skip
    np.testing.assert_allclose(
        truth.accel.apply(session.accel[:20]), G0 * np.eye(3)[[0] * 20], atol=1e-12
    )
    np.testing.assert_allclose(truth.gyro.apply(session.gyro), rate, atol=1e-12)
    # the turn integrates to its angle: smootherstep rate over the interior samples
    assert np.sum(rate[20:, 0]) / 100.0 == pytest.approx(np.pi / 2, rel=1e-6)
    assert truth.gyro.design == "unit test" and truth.simulator == opt
    assert [s.name for s in session.segments] == ["0000", "0001"]


def test_timeline_turn_ends_at_the_turned_attitude():
    tl = Timeline(50.0, G0, Rotation.identity())
    tl.smooth_turn(np.array([0.0, 1.0, 0.0]), np.pi, 40)
    tl.hold(5)
    force, _ = tl.arrays()
    np.testing.assert_allclose(force[-1], [0.0, 0.0, -G0], atol=1e-9)  # upside down
    s, ds = smootherstep(9, 1.0)
    assert s[0] > 0 and s[-1] < 1 and ds.sum() * 0.1 == pytest.approx(1.0, rel=1e-3)
