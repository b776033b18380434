"""Issue 9.4: every plan imucal offers calibrates with the default config.

Each plan of the registry is simulated (``imucal simulate``), then calibrated with no config
(``imucal calibrate``): exit 0, and each sensor the plan determines within tolerances of the
truth derived from the simulated noise and placement error (``still:MINUTES`` goes through
``imucal noise`` instead, its purpose; ``warmup:MINUTES`` through ``imucal calibrate --warmup``,
its bias-against-temperature curve checked against the truth's).

Comparison: ``y = matrix @ (raw - bias)`` of the calibration against the true input ``x`` in 200
directions (raw made with the truth), the largest error relative to ``|x|``.  What a design
cannot fix (the frame of a gravity-magnitude fit) is removed by the best rotation (Kabsch) first;
where the plan's labels fix the frame, the vectors are compared as they are.

Accelerometer tolerances are ``Z`` = 5 standard deviations of that error, from the linearised
Fisher information of the session's own poses (the Cramer-Rao bound of the design): the pose
means and the noise pooled over their samples, for a gravity-magnitude fit (``h_k = |U (m_k -
b)| = g``, ``U`` upper-trapezoidal: the gauge of a magnitude-only fit) or, where the poses are
labelled, a vector fit (``M (m_k - b) = g up_k`` with the placement error, RMS ``jitter``, as
noise across ``up_k``).  Gyroscope tolerances: the rate noise integrated over the turns
(``sigma_g sqrt(T dt)`` rad per turn of ``T`` s, relative to its angle, over ``sqrt(K / p)``
turns) and, where labelled axes fix the frame, the placement error of those axes
(``jitter sqrt(3 / K)``).

A plan whose default solvers do not yet calibrate it would be marked xfail with what it needs
(``Case.needs``); none is today.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest

from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.session import read_session
from tests.cli_helpers import run

G = 9.80665
Z = 5.0
SEED = 11
GYRO_NOISE, JITTER_DEG = 0.005, 2.0  # the simulator's defaults
RATE_HZ = 100.0


def place_rel(k: int) -> float:
    """Relative error of what rests on k labels placed with RMS error JITTER_DEG."""
    return np.radians(JITTER_DEG) * np.sqrt(3.0 / k)


def turn_rel(turn_s: float, angle_rad: float, k: int, p: int = 12) -> float:
    """Relative gyro error from the rate noise integrated over k turns of turn_s seconds."""
    return GYRO_NOISE * np.sqrt(turn_s / RATE_HZ) / angle_rad * np.sqrt(p / k)


@dataclass(frozen=True)
class Gyro:
    """What a plan determines of the gyroscope: relative tolerance, and whether its labels fix
    the frame (compare without the best rotation)."""

    tol: float
    frame: bool = False


@dataclass(frozen=True)
class Case:
    plan: str
    args: tuple[str, ...]
    accel: str | None  # "magnitude" (frame free), "labelled" (frame fixed), None (not asked)
    gyro: Gyro | None
    needs: str = ""  # why it fails on main today (xfail reason); "" = must pass


def _z(*terms: float) -> float:
    return Z * float(np.sqrt(np.sum(np.square(terms))))


# hand turns of ~1.5-3 s and ~1-3 rad; the iron's sweeps 6 s of ~1 rad, known to the solver's
# orthogonality to about 1e-3.
CASES = [
    Case("six", (), accel="labelled", gyro=None),
    Case("qureshi18", (), accel="magnitude", gyro=None),
    Case("random:N", ("--plan", "random:20"), accel="magnitude", gyro=None),
    # gyro-axes and hk-gyro: 3 faces (x 2 mountings) cannot determine the accel, which is left
    # out with a note; the gyro calibrates without it (known-angle turns about labelled axes;
    # the factorization).  hwangbo-iron: the labelled fit (the second mounting's poses by
    # their magnitude) and the factorization.
    Case("gyro-axes", (), accel=None,
         gyro=Gyro(_z(turn_rel(4.5, 2 * np.pi, 3, 9), place_rel(3)), frame=True)),
    # ferraris (MaD Lab): the 6 labelled faces; the gyro from the 3 known full turns about
    # labelled axes, each axis placed with the jitter, as gyro-axes
    Case("ferraris", (), accel="labelled",
         gyro=Gyro(_z(turn_rel(4.5, 2 * np.pi, 3, 9), place_rel(3)), frame=True)),
    Case("hwangbo-iron", (), accel="labelled", gyro=Gyro(_z(turn_rel(6.0, 1.0, 6, 9), 1e-3))),
    Case("hk-gyro", (), accel=None, gyro=Gyro(_z(turn_rel(6.0, 1.0, 6, 9), 1e-3))),
    Case("hk-redundant", (), accel="magnitude", gyro=None),
    Case("qureshi-axes[:N]", ("--plan", "qureshi-axes:6", "--still", "2"), accel="magnitude",
         gyro=Gyro(_z(turn_rel(2.0, 1.5, 18), 1e-4))),
    Case("free:N", ("--plan", "free:12", "--still", "2"), accel="magnitude",
         gyro=Gyro(_z(turn_rel(2.0, 1.5, 12), 1e-4))),
]  # fmt: skip


def _directions(magnitude: float) -> np.ndarray:
    dirs = np.random.default_rng(0).normal(size=(200, 3))
    return magnitude * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)


def _poses(session) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """Raw pose means (K, na), samples per pose (K,), the noise covariance of one sample
    pooled over the poses (na, na), and the static segments."""
    acc = np.asarray(session.accel, float)
    segs = [s for s in session.static_segments() if s.stop - s.start >= 2]
    means = np.array([acc[s.start : s.stop].mean(axis=0) for s in segs])
    n = np.array([s.stop - s.start for s in segs], float)
    resid = np.concatenate([acc[s.start : s.stop] - m for s, m in zip(segs, means, strict=True)])
    return means, n, resid.T @ resid / (len(resid) - len(segs)), segs


def _jacobian(f, theta: np.ndarray) -> np.ndarray:
    """Central differences of f (vector-valued) at theta."""
    cols = []
    for i in range(len(theta)):
        step = 1e-6 * max(1.0, abs(theta[i]))
        e = np.zeros_like(theta)
        e[i] = step
        cols.append((f(theta + e) - f(theta - e)) / (2 * step))
    return np.stack(cols, axis=-1)


def accel_tolerance(session, truth, labelled: bool) -> float:
    """Z standard deviations of the largest relative error of the accel over 200 directions,
    from the Fisher information of the session's poses (see the module notes)."""
    means, n, cov, segs = _poses(session)
    M_T, b_T = np.asarray(truth.matrix, float), np.asarray(truth.bias, float)
    na = len(b_T)
    g = float(session.gravity or G)
    if labelled:  # vector fit: M (3 x na) and b, labels with placement error
        mask = np.ones((3, na), bool)
        M0 = M_T
    else:  # magnitude fit in its own gauge: M = Q U, U upper-trapezoidal
        mask = np.triu(np.ones((3, na), bool))
        q, M0 = np.linalg.qr(M_T)
        M0 = M0 * np.sign(np.diag(M0))[:, None]
    theta0 = np.concatenate([M0[mask], b_T])

    def unpack(theta):
        M = np.zeros((3, na))
        M[mask] = theta[: mask.sum()]
        return M, theta[mask.sum() :]

    info = np.zeros((len(theta0), len(theta0)))
    for k, (m, nk) in enumerate(zip(means, n, strict=True)):
        M, b = unpack(theta0)
        if labelled:
            if segs[k].up is None:  # a still in another mounting: not square to the labels
                continue
            up = np.asarray(segs[k].up, float)
            J = _jacobian(lambda t, m=m: unpack(t)[0] @ (m - unpack(t)[1]), theta0)
            place = (g * np.radians(JITTER_DEG)) ** 2 / 2.0 * (np.eye(3) - np.outer(up, up))
            C = M @ (cov / nk) @ M.T + place
            info += J.T @ np.linalg.solve(C, J)
        else:
            y = M @ (m - b)
            J = _jacobian(lambda t, m=m: np.atleast_1d(np.linalg.norm(
                unpack(t)[0] @ (m - unpack(t)[1]))), theta0)  # fmt: skip
            grad = M.T @ y / np.linalg.norm(y)
            info += J.T @ J / float(grad @ (cov / nk) @ grad)
    # scaled to unit diagonal (counts and m/s^2 per count differ by 1e5).  What the poses do
    # not see is a gauge, left out: a redundant unit's raw data span 3 of its n dimensions, so
    # its bias along the null space of U and U acting across that span are seen by the noise
    # alone (scaled eigenvalues below 1e-5), and change no calibrated reading of real data
    d = 1.0 / np.sqrt(np.maximum(np.diag(info), 1e-300))
    Cov = d[:, None] * np.linalg.pinv(d[:, None] * info * d, rcond=1e-5, hermitian=True) * d
    raw = _directions(g) @ np.linalg.pinv(M_T).T + b_T
    worst = 0.0
    for r in raw:
        J = _jacobian(lambda t, r=r: unpack(t)[0] @ (r - unpack(t)[1]), theta0)
        worst = max(worst, float(np.trace(J @ Cov @ J.T)))
    return Z * np.sqrt(worst) / g


def _kabsch(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The rotation R minimising |R y - x| over rows (3 x 3)."""
    u, _, vt = np.linalg.svd(x.T @ y)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def _compare(name: str, cal, truth, tol: float, frame: bool, magnitude: float) -> list[str]:
    """Problems of one sensor's calibration against the truth (empty when within tolerance)."""
    if cal is None:
        return [f"{name}: not calibrated"]
    x = _directions(magnitude)
    raw = x @ np.linalg.pinv(truth.matrix).T + truth.bias
    y = (raw - cal.bias) @ np.asarray(cal.matrix).T
    R = np.eye(3) if frame else _kabsch(y, x)
    err = float(np.max(np.linalg.norm(y @ R.T - x, axis=1)) / magnitude)
    how = "" if frame else " after the best rotation"
    return [] if err <= tol else [f"{name}: error {err:.2e}{how} > {tol:.2e} (relative)"]


def _params(case: Case):
    marks = [pytest.mark.xfail(reason=case.needs, strict=False)] if case.needs else []
    return pytest.param(case, id=case.plan, marks=marks)


@pytest.mark.parametrize("case", [_params(c) for c in CASES])
def test_plan_calibrates_with_the_default_config(case, tmp_path):
    session = tmp_path / "s.h5"
    args = case.args or ("--plan", case.plan)
    sim = run("simulate", *args, "--seed", SEED, "-o", session)
    assert sim.returncode == 0, sim.stderr
    cal_path = tmp_path / "s.cal.json"
    proc = run("calibrate", session, "-o", cal_path)
    assert proc.returncode == 0, proc.stderr
    cal = read_calibration(cal_path)
    truth = read_calibration(tmp_path / "s.truth.json")
    problems = []
    if case.accel is not None:
        tol = accel_tolerance(read_session(session), truth.accel, case.accel == "labelled")
        problems += _compare("accel", cal.accel, truth.accel, tol, case.accel == "labelled", G)
    if case.gyro is not None:
        problems += _compare("gyro", cal.gyro, truth.gyro, case.gyro.tol, case.gyro.frame, 1.0)
    assert not problems, problems


def test_the_matrix_covers_every_plan():
    from imucal_cli.plans import BUILTIN_PLANS

    # still:MINUTES and warmup:MINUTES have their own checks below (noise; temperature)
    assert {c.plan for c in CASES} | {"still:MINUTES", "warmup:MINUTES"} == set(BUILTIN_PLANS)


def test_still_plan_gives_the_noise_of_the_part(tmp_path):
    """still:MINUTES is for ``imucal noise``: the random walk it measures is the simulated white
    noise plus the rounding to counts (1/sqrt(12) LSB), times sqrt(dt).  3 minutes at 100 Hz
    fit the random walk to about 2 %: the tolerance is 5 times that."""
    session = tmp_path / "still.h5"
    sim = run("simulate", "--plan", "still:3", "--seed", SEED, "-o", session)
    assert sim.returncode == 0, sim.stderr
    proc = run("noise", session, "--calibration", tmp_path / "still.truth.json", "--json")
    assert proc.returncode == 0, proc.stderr
    sensors = json.loads(proc.stdout)["sensors"]
    lsb = {"accel": 8192.0 / G, "gyro": 16.4 * 180.0 / np.pi}  # counts per SI unit
    for kind, sigma, key in (("accel", 0.01, "vrw_m_s_per_sqrt_s"),
                             ("gyro", GYRO_NOISE, "arw_rad_per_sqrt_s")):  # fmt: skip
        want = np.hypot(sigma, 1.0 / np.sqrt(12.0) / lsb[kind]) / np.sqrt(RATE_HZ)
        got = np.array([axis[key] for axis in sensors[kind]["axes"]])
        np.testing.assert_allclose(got, want, rtol=0.1)


def _warmup_shape_bound(session, grid: np.ndarray, t_ref: float) -> dict[str, float]:
    """RMS over ``grid`` of the Cramer-Rao standard deviation of a cubic bias curve's shape
    (its change from ``t_ref``) fitted to the still blocks of ``session``, white noise (the
    per-sample noise measured from the session), in counts."""
    from imucal_cli.calibrate.thermal import BLOCK_S, still_blocks
    from imucal_cli.estimators.thermal.temperature import polynomial_bound, powers

    blocks = still_blocks(session, BLOCK_S)
    out = {}
    for name in ("accel", "gyro"):
        data = getattr(session, name)
        sigma = float(np.std(np.diff(data, axis=0)) / np.sqrt(2.0))
        T = np.array([session.temperature[a:b].mean() for a, b, _ in blocks])
        sig = np.array([sigma / np.sqrt(b - a) for a, b, _ in blocks])
        cov = polynomial_bound(T, sig, 3, t_ref, np.array([k for _, _, k in blocks]))[-3:, -3:]
        X = powers(grid, t_ref, 3)
        out[name] = float(np.sqrt(np.mean(np.einsum("nj,jk,nk->n", X, cov, X))))
    return out


def test_warmup_plan_gives_the_temperature_curve(tmp_path):
    """warmup:MINUTES is for ``imucal calibrate --warmup``: a simulated warm-up (--ramp 5:40)
    and a qureshi18 session at room temperature give each sensor's bias curve; its shape (the
    change from 25 C) is within Z Cramer-Rao standard deviations of a cubic on the warm-up's
    still blocks (RMS over the span), and the compensated bias is closer to the truth over the
    span than the constant bias of the same session calibrated without the warm-up."""
    warm, room = tmp_path / "warm.h5", tmp_path / "room.h5"
    sim = run("simulate", "--plan", "warmup:4", "--ramp", "5:40", "--seed", SEED, "-o", warm)
    assert sim.returncode == 0, sim.stderr
    sim = run("simulate", "--plan", "qureshi18", "--ramp", "24:26:linear", "--seed", SEED,
              "-o", room)  # fmt: skip
    assert sim.returncode == 0, sim.stderr
    with_warmup, plain = tmp_path / "w.cal.json", tmp_path / "p.cal.json"
    proc = run("calibrate", room, "--warmup", warm, "-o", with_warmup)
    assert proc.returncode == 0, proc.stderr
    config = tmp_path / "off.toml"
    config.write_text('[temperature]\nmodel = "off"\n')
    proc = run("calibrate", room, "--config", config, "-o", plain)
    assert proc.returncode == 0, proc.stderr
    cal, off = read_calibration(with_warmup), read_calibration(plain)
    truth = read_calibration(tmp_path / "warm.truth.json")
    session = read_session(warm)
    t = session.temperature
    grid = np.linspace(t.min() + 1.0, t.max() - 1.0, 41)
    bound = _warmup_shape_bound(session, grid, 25.0)
    problems = []
    for name in ("accel", "gyro"):
        sec, true = getattr(cal, name), getattr(truth, name)
        assert sec.temperature_terms is not None, name
        err = sec.bias_at(grid) - true.bias_at(grid)
        shape = err - (sec.bias_at(25.0) - true.bias_at(25.0))
        rms = float(np.sqrt(np.mean(np.square(shape))))
        if rms > Z * bound[name]:
            problems.append(f"{name}: curve shape error {rms:.3g} > {Z:g} x {bound[name]:.3g}")
        before = np.tile(getattr(off, name).bias, (len(grid), 1)) - true.bias_at(grid)
        if not np.sqrt(np.mean(np.square(err))) < np.sqrt(np.mean(np.square(before))):
            problems.append(f"{name}: the warm-up does not improve the bias over the span")
    assert not problems, problems
