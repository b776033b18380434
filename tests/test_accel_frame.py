"""The accelerometer calibration's error without its frame's rotation
(:mod:`imucal_cli.estimators.accel.frame`): a gyro calibrated against the accelerometer's
gravity reports in the accelerometer's frame and turns with it, so its std carry the bending
of the accelerometer's axes, not the turn of the frame the accelerometer's own section
states."""

from __future__ import annotations

import numpy as np

from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.estimators.accel.frame import frame_free

RNG = np.random.default_rng(5)
A = np.eye(3) + 0.02 * RNG.standard_normal((3, 3))


def _skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _cov(errors):
    E = np.array(errors)
    return E.T @ E / len(E)


def test_a_turn_of_the_frame_is_taken_out_and_a_bending_kept():
    phis = 1e-3 * RNG.standard_normal((50, 3))
    turns = [np.r_[np.zeros(3), (_skew(p) @ A).ravel()] for p in phis]
    assert np.abs(frame_free(_cov(turns), A)).max() < 1e-12 * np.abs(_cov(turns)).max()
    bends = []
    for _ in range(50):  # symmetric dA A^-1 and a bias: no rotation in them
        S = 1e-3 * RNG.standard_normal((3, 3))
        bends.append(np.r_[RNG.standard_normal(3), ((S + S.T) @ A).ravel()])
    np.testing.assert_allclose(frame_free(_cov(bends), A), _cov(bends), atol=1e-15)
    C = _cov(turns) + _cov(bends)
    np.testing.assert_allclose(frame_free(frame_free(C, A), A), frame_free(C, A), atol=1e-15)


def test_further_terms_are_left_as_they_are():
    C = np.diag(np.r_[np.ones(12), 7.0, 9.0])
    out = frame_free(C, A)
    assert out.shape == (14, 14) and out[12, 12] == 7.0 and out[13, 13] == 9.0


def _off_diagonal_std(cal) -> np.ndarray:
    std = {p.name: p.std for p in cal.gyro.parameters}
    return np.array([std[f"m_{a}{b}"] for a in "xyz" for b in "xyz" if a != b])


def test_the_gyro_std_leave_the_frame_to_the_accelerometer(monkeypatch):
    """qureshi18 with the 12-parameter accelerometer (a full matrix turned onto the labels:
    its frame as good as the poses sit, tenths of a degree) and the full gyro model, which
    the turns between still periods determine in that frame: the gyro's axes are std'd
    against the accelerometer's frame, without its turn (with it, its calibrated rates were
    stated to 0.86 %, now 0.004 %); the bias untouched. (A gyro held to the labels by turns
    of known angle keeps the frame's part: tests/test_known_*.)"""
    from imucal_cli.calibrate.gyro import full
    from imucal_cli.formats.config import config_from_dict
    from imucal_cli.simulate.play import simulate_plan

    session, _ = simulate_plan("qureshi18", seed=1, created="2026-01-01T00:00:00Z")
    cfg = config_from_dict({"accel": {"gravity": {"model": "12"}}})
    cal = calibrate_session(session, cfg)
    assert "labelled" in cal.accel.gauge, cal.accel.gauge
    monkeypatch.setattr(full, "frame_free", lambda C, A: np.asarray(C, float))
    with_frame = calibrate_session(session, cfg)
    ratio = _off_diagonal_std(with_frame) / _off_diagonal_std(cal)
    assert ratio.min() > 3, ratio
    assert with_frame.gyro.rate_std.total > 10 * cal.gyro.rate_std.total
    bias = np.array([p.std for p in cal.gyro.parameters][:3])
    np.testing.assert_allclose(bias, [p.std for p in with_frame.gyro.parameters][:3], rtol=0.02)


def test_labelled_known_axes_carry_the_frame_not_all_of_it(tmp_path):
    """The known-angle gyro on captured Ferraris sessions (labelled axes, the face moves
    measured by gravity): each labelled axis carries the accelerometer frame's turn in the
    fit's noise model, the gravity-measured turns the bending only. The off-diagonal entries'
    RMS error/std over 10 seeds (60 values) was 0.59 with the frame's whole turn counted in
    their std (over-conservative: the captured Ferraris row of bench trust-gyro at 97.1 %),
    1.10 now (96.3 % over 50 seeds)."""
    from bench.captured import as_captured, ferraris_plan
    from bench.trust_gyro import CREATED, _truth_x
    from imucal_cli.formats.config import Config
    from imucal_cli.simulate.play import simulate_plan

    plan = str(ferraris_plan(tmp_path))
    z = []
    for seed in range(300, 310):
        session, truth = simulate_plan(plan, seed=seed, created=CREATED)
        cal = calibrate_session(as_captured(session, plan), Config())
        assert cal.gyro is not None and cal.gyro.solver == "gyro-known"
        est = np.array([p.value for p in cal.gyro.parameters[:12]])
        std = np.array([p.std for p in cal.gyro.parameters[:12]])
        z.append(((est - _truth_x(cal, truth)[:12]) / std)[[4, 5, 6, 8, 9, 10]])
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.75 < rms < 1.4, rms  # 60 values: the RMS within about 10 % of its expectation
