"""Magnetometer solver (estimators/mag/magnetometer.py), its Cramér-Rao bound and the sphere
figures."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import block_diag
from scipy.spatial.transform import Rotation

from imucal_cli.design.sphere_quality import (
    N_REGIONS,
    gaps_pct,
    region_centres,
    region_counts,
    region_index,
    sphere_quality,
    suggest_direction,
)
from imucal_cli.errors import DesignError
from imucal_cli.estimators.mag.crb import magnetometer_crb
from imucal_cli.estimators.mag.magnetometer import (
    MagData,
    fit_magnetometer,
    fit_plain_ellipsoid,
    held_out_residuals,
    polar,
)

F = 48.0  # uT
INC = np.radians(62.0)
FIELD_WORLD = F * np.array([np.cos(INC), 0.0, -np.sin(INC)])
# An MPU-9250's AK8963: x and y swapped, z reversed relative to the accelerometer (a rotation).
AK8963 = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


class Design:
    """A simulated magnetometer, its readings and the truth (raw = W^-1 h + b + noise)."""

    def __init__(self, seed, n_samples=1500, n_poses=16, sigma=2.5, hold=100, mount=AK8963,
                 up_sigma=2e-3, noise=True, attitudes=None):  # fmt: skip
        rng = np.random.default_rng(seed)
        gain = 6.7  # counts per uT
        soft = np.eye(3) + rng.uniform(-0.08, 0.08, (3, 3))
        tilt = Rotation.from_rotvec(rng.normal(0, np.radians(1.5), 3)).as_matrix()
        self.Winv = gain * soft @ (tilt @ mount).T  # raw per uT, field in accel frame
        self.W = np.linalg.inv(self.Winv)
        self.b = rng.uniform(-300, 300, 3)
        self.S = sigma**2 * np.eye(3)
        if attitudes is None:
            attitudes = Rotation.random(n_samples, random_state=rng)
        self.dirs = attitudes.inv().apply(FIELD_WORLD) / F
        poses = Rotation.random(n_poses, random_state=rng)
        self.pose_dirs = poses.inv().apply(FIELD_WORLD) / F
        self.up = poses.inv().apply([0.0, 0.0, 1.0])
        self.s = -np.sin(INC)
        self.pose_cov = np.broadcast_to(self.S / hold, (n_poses, 3, 3)).copy()
        self.up_cov = np.broadcast_to(up_sigma**2 / hold * np.eye(3), (n_poses, 3, 3)).copy()
        k = 1.0 if noise else 0.0
        samples = F * self.dirs @ self.Winv.T + self.b
        samples += k * rng.normal(0, sigma, samples.shape)
        means = F * self.pose_dirs @ self.Winv.T + self.b
        means += k * rng.normal(0, sigma / np.sqrt(hold), means.shape)
        up_meas = self.up + k * rng.normal(0, up_sigma / np.sqrt(hold), self.up.shape)
        up_meas /= np.linalg.norm(up_meas, axis=1, keepdims=True)
        self.data = MagData(samples, means, self.S, self.pose_cov, up_meas, self.up_cov)

    @property
    def truth(self):
        return np.r_[self.b, self.W.ravel(), self.s]

    def crb(self, aligned=True):
        if aligned:
            return magnetometer_crb(
                self.W, F, self.dirs, self.S, pose_up=self.up, pose_dirs=self.pose_dirs,
                pose_cov=self.pose_cov, up_cov=self.up_cov,
            )  # fmt: skip
        R, P = polar(self.W)
        return magnetometer_crb(
            P, F, self.dirs @ R, self.S, pose_dirs=self.pose_dirs @ R, pose_cov=self.pose_cov,
            aligned=False,
        )  # fmt: skip


def test_fit_finds_hard_soft_iron_and_the_rotation_to_the_accelerometer():
    d = Design(1)
    res = fit_magnetometer(d.data, F)
    assert res.aligned and res.weighting == "noise"
    z = (res.params - d.truth) / res.std
    assert np.all(np.abs(z) < 4.5), z
    # the swapped AK8963 axes are found: the output is in the accelerometer frame
    h_true = F * d.pose_dirs
    h_est = res.calibrate(F * d.pose_dirs @ d.Winv.T + d.b)
    cos = np.sum(h_true * h_est, 1) / F / np.linalg.norm(h_est, axis=1)
    assert np.degrees(np.max(np.arccos(np.clip(cos, -1, 1)))) < 0.3
    assert abs(res.inclination_deg - np.degrees(INC)) < 5 * res.inclination_std_deg
    assert np.allclose(res.rotation, polar(res.matrix)[0])
    assert 0.8 < res.chi2 / res.dof < 1.2 and res.noise_scale == 1.0


def test_stated_covariance_is_the_cramer_rao_bound():
    """At noise-free truth, the fit's information equals the bound of the design."""
    d = Design(2, noise=False)
    res = fit_magnetometer(d.data, F)
    ratio = np.sqrt(np.diag(res.cov) / np.diag(d.crb()))
    assert np.allclose(ratio, 1.0, atol=2e-3), ratio
    d0 = Design(3, noise=False)
    d0.data = MagData(d0.data.samples, d0.data.pose_mean, d0.S, d0.pose_cov)  # no up
    res0 = fit_magnetometer(d0.data, F)
    assert not res0.aligned
    ratio0 = np.sqrt(np.diag(res0.cov) / np.diag(d0.crb(aligned=False)))
    assert np.allclose(ratio0, 1.0, atol=2e-3), ratio0


def test_crb_matches_fisher_information_with_explicit_nuisance_parameters():
    """The per-reading elimination equals the full Fisher matrix (finite differences) with
    every sample's direction and every pose's attitude as parameters."""
    d = Design(4, n_samples=40, n_poses=8, noise=False)
    S = np.diag([4.0, 9.0, 2.0])
    pose_cov = np.broadcast_to(S / 30, (8, 3, 3))
    ua = 1e-6
    s, c = d.s, np.sqrt(1 - d.s**2)

    def mean(x):
        b, W, s_ = x[:3], x[3:12].reshape(3, 3), x[12]
        Wi = np.linalg.inv(W)
        out, i = [], 13
        for v in d.dirs:
            T = np.linalg.svd(np.eye(3) - np.outer(v, v))[0][:, :2]
            vv = v + T @ x[i : i + 2]
            out.append(Wi @ (F * vv / np.linalg.norm(vv)) + b)
            i += 2
        for u0, v0 in zip(d.up, d.pose_dirs, strict=True):
            R = Rotation.from_rotvec(x[i : i + 3]).as_matrix()
            i += 3
            u, w = R @ u0, R @ ((v0 - s * u0) / c)
            out.append(Wi @ (F * (s_ * u + np.sqrt(1 - s_**2) * w)) + b)
            T = np.linalg.svd(np.eye(3) - np.outer(u0, u0))[0][:, :2]
            out.append(T.T @ u)
        return np.concatenate(out)

    x0 = np.r_[d.truth, np.zeros(2 * 40 + 3 * 8)]
    J = np.empty((len(mean(x0)), len(x0)))
    for j in range(len(x0)):
        e = np.zeros(len(x0))
        e[j] = 1e-6 * max(1.0, abs(x0[j]))
        J[:, j] = (mean(x0 + e) - mean(x0 - e)) / (2 * e[j])
    L = block_diag(*([np.linalg.inv(S)] * 40 + [np.linalg.inv(pose_cov[0]), np.eye(2) / ua] * 8))
    full = np.linalg.inv(J.T @ L @ J)[:13, :13]
    crb = magnetometer_crb(d.W, F, d.dirs, S, pose_up=d.up, pose_dirs=d.pose_dirs,
                           pose_cov=pose_cov, up_cov=np.broadcast_to(ua * np.eye(3), (8, 3, 3)))
    assert np.allclose(np.sqrt(np.diag(crb) / np.diag(full)), 1.0, atol=1e-4)


@pytest.mark.slow
def test_95_percent_intervals_cover_the_truth():
    inside, total, nees = 0, 0, []
    for seed in range(24):
        d = Design(100 + seed, n_samples=400, n_poses=10)
        res = fit_magnetometer(d.data, F)
        z = (res.params - d.truth) / res.std
        inside += int(np.sum(np.abs(z) < 1.96))
        total += len(z)
        e = res.params - d.truth
        nees.append(e @ np.linalg.solve(d.crb(), e) / len(e))
    # 312 intervals, correlated within a seed: +-4.5 % is about 3 standard errors
    assert 0.905 <= inside / total <= 0.99, inside / total
    # errors at the bound: mean normalised error near 1 (chi^2(13)/13 over 24 seeds: sd 0.08)
    assert 0.75 < np.mean(nees) < 1.3, np.mean(nees)


def test_without_up_directions_the_matrix_is_symmetric_and_the_field_unknown_gives_unit_output():
    d = Design(5)
    data = MagData(d.data.samples, np.empty((0, 3)), d.S)
    res = fit_magnetometer(data, 1.0)
    assert not res.aligned and res.inclination_deg is None
    assert np.allclose(res.matrix, res.matrix.T)
    assert any("0 static poses" in n for n in res.notes)
    mags = np.linalg.norm(res.calibrate(d.data.samples), axis=1)
    assert abs(mags.mean() - 1.0) < 1e-3
    # hard iron does not depend on the gauge
    assert np.all(np.abs(res.bias - d.b) < 5 * res.std[:3])


def test_poses_sharing_one_gravity_direction_cannot_fix_the_rotation():
    d = Design(6)
    flat = np.tile([0.0, 0.0, 1.0], (len(d.up), 1))
    data = MagData(d.data.samples, d.data.pose_mean, d.S, d.pose_cov, flat, d.up_cov)
    res = fit_magnetometer(data, F)
    assert not res.aligned
    assert any("share one gravity direction" in n for n in res.notes)


def test_readings_in_one_plane_are_refused_with_advice():
    yaw = Rotation.from_euler("z", np.linspace(0, 2 * np.pi, 800, endpoint=False)[:, None])
    d = Design(7, attitudes=yaw, n_poses=0)
    data = MagData(d.data.samples, np.empty((0, 3)), d.S)
    with pytest.raises(DesignError, match="every direction"):
        fit_magnetometer(data, F)


def test_too_few_or_identical_readings_are_refused():
    with pytest.raises(DesignError, match="9 parameters"):
        fit_magnetometer(MagData(np.ones((5, 3)), np.empty((0, 3))), F)
    with pytest.raises(DesignError, match="stuck"):
        fit_magnetometer(MagData(np.ones((50, 3)), np.empty((0, 3))), F)


def test_plain_ellipsoid_fit_is_symmetric_and_worse_than_the_ml_fit():
    d = Design(8, sigma=6.0)
    plain = fit_plain_ellipsoid(d.data, F)
    assert np.allclose(plain.matrix, plain.matrix.T) and not plain.aligned
    assert np.linalg.norm(plain.bias - d.b) < 10.0  # counts, hard iron close
    ml = fit_magnetometer(d.data, F)
    assert np.linalg.norm(ml.bias - d.b) < np.linalg.norm(plain.bias - d.b) + 1.0


def test_held_out_residuals_are_about_the_noise():
    d = Design(9)
    folds_s = (np.arange(len(d.data.samples)) // 100) % 2
    folds_p = np.arange(len(d.data.pose_mean)) % 2
    held = held_out_residuals(d.data, folds_s, folds_p, F)
    assert np.isfinite(held).all()
    res = fit_magnetometer(d.data, F)
    rms_in = np.sqrt(np.mean(res.residuals[: len(d.data.samples)] ** 2))
    rms_out = np.sqrt(np.mean(held[: len(d.data.samples)] ** 2))
    assert rms_in < rms_out < 1.2 * rms_in
    # the noise in uT: sigma / gain
    assert 0.5 * 2.5 / 6.7 < rms_out < 2.0 * 2.5 / 6.7


# ---------------------------------------------------------------------------- sphere figures


def test_regions_have_equal_area_and_their_centres_lie_inside():
    rng = np.random.default_rng(0)
    v = rng.normal(size=(200_000, 3))
    counts = region_counts(v)
    assert counts.shape == (N_REGIONS,)
    assert np.all(np.abs(counts / 2000 - 1) < 0.1)  # 2000 expected each, sd 45
    assert np.array_equal(region_index(region_centres()), np.arange(N_REGIONS))


def test_gaps_variance_and_wobble():
    assert gaps_pct(np.zeros(100)) == 100.0
    assert gaps_pct(np.r_[np.ones(10), np.full(5, 2), np.full(85, 3)]) == pytest.approx(2.05)
    rng = np.random.default_rng(1)
    v = rng.normal(size=(20_000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    q = sphere_quality(50 * v)
    assert q.gaps_pct == 0 and q.covered_fraction == 1.0
    assert q.variance_pct < 1e-9 and q.wobble_pct < 0.5
    off = sphere_quality(50 * v + [6.0, 0, 0])  # 12 % off centre
    assert off.wobble_pct > 3.0 and off.variance_pct > 3.0
    half = sphere_quality(50 * v[v[:, 2] > 0])
    assert 45 < half.gaps_pct < 55 and abs(half.covered_fraction - 0.5) < 0.02


def test_suggest_direction_points_into_the_gap_nearest_the_unit():
    rng = np.random.default_rng(2)
    v = rng.normal(size=(5000, 3))
    v = v[v[:, 2] > -0.3]  # the bottom cap is missing
    counts = region_counts(v)
    d = suggest_direction(counts, current=[1.0, 0.0, 0.0])
    assert d[2] < -0.3
    assert suggest_direction(np.full(100, 5)) is None
