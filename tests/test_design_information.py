"""Issue 27: the Fisher information of a design at a fit (solvers/design_information.py)
against the bounds the solvers already state, and against the scatter of real fits."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imucal_cli.estimators.accel.crb import labelled_crb
from imucal_cli.estimators.accel.labelled_model import design_jacobian
from imucal_cli.estimators.gyro.full import Rotations, Stills, full_information
from imucal_cli.planning import information as di
from imucal_cli.simulate.motion import Timeline
from imucal_cli.simulate.sensor import draw_part

G = 9.80665
RATE = 100.0
FACES = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], float)


def part(seed: int = 3):
    imu, _, _ = draw_part(seed, "counts", 0.01, 0.005)
    a, g = imu.accel.truth({}), imu.gyro.truth({})
    fit = di.Fit(a.matrix, a.bias, g.matrix, g.bias, G)
    noise = di.Noise(0.01 * np.linalg.norm(imu.accel.S, axis=1).mean(),
                     0.005 * np.linalg.norm(imu.gyro.S, axis=1).mean(), RATE)  # fmt: skip
    return imu, fit, noise


def test_pose_jacobians_are_the_labelled_models():
    _, fit, _ = part()
    u = Rotation.random(7, random_state=1).apply([0, 0, 1.0])
    Gt, Gd = di.pose_jacobians(fit, u)
    Gt0, Gd0 = design_jacobian(fit.accel_matrix, u, G)
    assert Gt == pytest.approx(Gt0, rel=1e-5, abs=1e-9 * np.abs(Gt0).max())
    # the direction's basis may differ: the same plane (its projector)
    assert Gd @ np.linalg.pinv(Gd) == pytest.approx(Gd0 @ np.linalg.pinv(Gd0), abs=1e-6)


@pytest.mark.parametrize("placement", [2.0, 0.5])
def test_accel_std_is_the_labelled_bound(placement):
    """Six faces with labels: the terms' std are the Cramer-Rao bound of the labelled design
    (solvers/crb.py), to the arithmetic."""
    _, fit, noise = part()
    poses = [di.Pose(u, 200, placement) for u in FACES]
    std = di.accel_terms(fit, di.accel_information(fit, poses, noise))
    crb = np.sqrt(np.diag(labelled_crb(fit.accel_matrix, fit.accel_bias, FACES, G,
                                       np.tile(np.eye(3) * noise.accel_raw**2 / 200, (6, 1, 1)),
                                       placement)))  # fmt: skip
    gains = np.linalg.norm(np.linalg.inv(fit.accel_matrix), axis=1)
    assert std.gain == pytest.approx(crb[3:6] / gains, rel=1e-4)
    assert std.bias == pytest.approx(crb[:3] / gains, rel=1e-4)
    assert std.misalignment_deg == pytest.approx(crb[6:9], rel=1e-4)


def test_six_faces_without_labels_determine_no_accelerometer():
    """Gravity magnitude alone: 6 directions for 9 parameters."""
    _, fit, noise = part()
    poses = [di.Pose(u, 200) for u in FACES]
    assert di.accel_terms(fit, di.accel_information(fit, poses, noise)) is None
    edges = [FACES[i] + FACES[j] for i in range(6) for j in range(i + 1, 6)
             if abs(FACES[i] @ FACES[j]) < 0.5]  # the 12 edges of qureshi18
    eighteen = [di.Pose(u / np.linalg.norm(u), 200) for u in [*FACES, *edges]]
    assert di.accel_terms(fit, di.accel_information(fit, eighteen, noise)) is not None


def chain(imu, axes, angles, hold_n=100, move_n=150):
    """Exact (noise-free) samples of still poses and turns about body axes between them."""
    tl = Timeline(RATE, G, Rotation.identity())
    stills = [tl.hold(hold_n)]
    for ax, ang in zip(axes, angles, strict=True):
        tl.smooth_turn(np.asarray(ax, float), ang, move_n)
        stills.append(tl.hold(hold_n))
    force, rate = tl.arrays()
    raw_a = force @ imu.accel.S.T + imu.accel.b
    raw_g = rate @ imu.gyro.S.T + imu.gyro.b
    return stills, raw_a, raw_g


def test_gyro_information_is_the_full_models():
    """The turns' information in closed form against the full model's own (its residuals'
    Jacobian through its noise model, solvers/gyro_full.py) on exact turns: the same but for
    what the closed form leaves out, the correlation of two turns through the still pose they
    share (its direction's noise, a few % of a turn's at 1 s holds) and a turn's profile."""
    imu, fit, noise = part()
    axes = [[1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 1], [0, 1, 0], [1, 0, 0], [0, 1, 0],
            [0, 0, 1]]  # fmt: skip
    angles = [np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi, np.pi / 4, -np.pi / 2,
              np.pi / 2]  # fmt: skip
    stills, raw_a, raw_g = chain(imu, axes, angles)
    t = np.arange(len(raw_a)) / RATE
    ups = [fit.accel_matrix @ (raw_a[a:b].mean(0) - fit.accel_bias) for a, b in stills]
    poses = [di.Pose(u / np.linalg.norm(u), b - a) for u, (a, b) in zip(ups, stills,
                                                                       strict=True)]
    turns = [di.Turn(k, k + 1, np.asarray(ax, float), ang, 151 / RATE)
             for k, (ax, ang) in enumerate(zip(axes, angles, strict=True))]  # fmt: skip
    mine, _ = di.gyro_information(fit, poses, turns, noise)
    rot = Rotations([t[stills[k][1] - 15: stills[k + 1][0] + 15] for k in range(len(turns))],
                    [raw_g[stills[k][1] - 15: stills[k + 1][0] + 15] for k in range(len(turns))],
                    np.arange(len(turns)), np.arange(1, len(turns) + 1))  # fmt: skip
    still = Stills(np.array([G * p.up for p in poses]),
                   np.sqrt(di._direction_sigma2(fit, np.array([p.n for p in poses]), noise)),
                   np.array([raw_g[a:b].mean(0) for a, b in stills]),
                   np.full(len(stills), noise.gyro_raw / np.sqrt(100)))  # fmt: skip
    ref = full_information(np.r_[fit.gyro_bias, fit.gyro_matrix.ravel()], rot, still,
                           noise.gyro_raw)  # fmt: skip
    ratio = np.sqrt(np.diag(np.linalg.inv(mine)) / np.diag(np.linalg.inv(ref)))
    assert ratio == pytest.approx(np.ones(12), abs=0.1), ratio


def test_axes_std_is_the_delta_method():
    _, fit, _ = part()
    M = fit.gyro_matrix
    rng = np.random.default_rng(0)
    A = rng.standard_normal((9, 9)) * 1e-4 * np.abs(M).max()
    cov = A @ A.T

    def f(x):
        S = np.linalg.inv(x.reshape(3, 3))
        n = np.linalg.norm(S, axis=1)
        s = S / n[:, None]
        return np.r_[n, np.degrees(np.arccos([s[0] @ s[1], s[0] @ s[2], s[1] @ s[2]]))]

    h = 1e-7 * np.abs(M).max()
    J = np.array([(f(M.ravel() + h * e) - f(M.ravel() - h * e)) / (2 * h) for e in np.eye(9)]).T
    want = np.sqrt(np.diag(J @ cov @ J.T))
    gains, gain_std, angle_std = di.axes_std(M, cov)
    assert gains == pytest.approx(f(M.ravel())[:3])
    assert np.r_[gain_std, angle_std] == pytest.approx(want, rel=1e-5)


@pytest.mark.slow
def test_predicted_std_is_the_scatter_of_fits():
    """Monte Carlo: one design (a part's 14 holds and 13 turns as the person made them), the
    noise drawn anew 100 times and every fit made as ``imucal calibrate`` makes it; each
    term's scatter against the std the information predicts at the truth (the first order's,
    the accelerometer calibration's part of the gyro's included): within the sampling error
    of 100 draws (a std is known to 1/sqrt(2 * 100) = 7 %, three of them) and the first
    order's nonlinearity (10 %)."""
    from bench.adaptive import design_of_session, terms_of
    from bench.person import follow
    from imucal_cli.calibrate.session import calibrate_session
    from imucal_cli.formats.config import Config

    out = follow(7, max_s=120, min_hold_s=0.5, keep=True)
    fit, poses, turns, noise, redo = design_of_session(out)
    predicted = di.design_std(fit, poses, turns, noise)
    errors = []
    for k in range(100):
        cal = calibrate_session(redo(1000 + k), Config())
        errors.append(terms_of(cal, out.truth)[0])
    spread = np.std(errors, axis=0)
    want = np.r_[predicted.accel.bias, predicted.accel.gain, predicted.accel.misalignment_deg,
                 predicted.gyro.bias, predicted.gyro.gain, predicted.gyro.misalignment_deg]
    assert spread / want == pytest.approx(np.ones(18), abs=3 * 0.07 + 0.1)
