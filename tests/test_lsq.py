"""solvers/lsq.py (numpy Levenberg-Marquardt) against scipy.optimize.least_squares: on
textbook problems, and on every problem family the solvers pose (the solver run once with
ours and once with scipy's swapped in): the solutions agree to far within their stated std."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize

from imucal_cli.formats.config import config_from_dict
from imucal_cli.pipeline.calibrate import calibrate_session, static_poses
from imucal_cli.simulate.triad import simulate
from imucal_cli.solvers import factorization, gravity, gyro_full, labelled, lsq, magnetometer
from imucal_cli.solvers.labelled import fit_labelled
from imucal_cli.solvers.magnetometer import fit_magnetometer
from tests.test_gravity_solver import cube18, poses, random_part
from tests.test_mag_solver import Design, F

CREATED = "2026-01-01T00:00:00Z"
G0 = 9.80665
SOLVER_MODULES = (gravity, labelled, magnetometer, gyro_full, factorization)


def scipy_least_squares(fun, x0, jac=None, *, x_scale="jac", **kw):
    """scipy's solver behind our signature (trf: it takes x_scale="jac" and arrays alike;
    ``blocks``, our hint on the Jacobian's structure, has no counterpart)."""
    kw.pop("blocks", None)
    return scipy.optimize.least_squares(
        fun, x0, jac="2-point" if jac is None else jac, x_scale=x_scale, method="trf", **kw
    )


@pytest.fixture
def with_scipy(monkeypatch):
    """A function that runs ``fn()`` with scipy's least_squares in every solver module."""

    def run(fn):
        with monkeypatch.context() as m:
            for mod in SOLVER_MODULES:
                m.setattr(mod, "least_squares", scipy_least_squares)
            return fn()

    return run


def rosenbrock(x):
    return np.array([10 * (x[1] - x[0] ** 2), 1 - x[0]])


def rosenbrock_jac(x):
    return np.array([[-20 * x[0], 10.0], [-1.0, 0.0]])


@pytest.mark.parametrize("x_scale", ["jac", 1.0, [0.5, 2.0]])
@pytest.mark.parametrize("analytic", [True, False])
def test_textbook_problems_reach_scipy_solution(x_scale, analytic):
    jac = rosenbrock_jac if analytic else None
    r = lsq.least_squares(rosenbrock, [-1.2, 1.0], jac, x_scale=x_scale, xtol=1e-12,
                          ftol=1e-12, gtol=1e-12)  # fmt: skip
    assert r.success and r.status > 0 and r.message == lsq.MESSAGES[r.status]
    np.testing.assert_allclose(r.x, [1.0, 1.0], atol=1e-7)
    assert r.cost < 1e-20 and r.nfev > 5
    # exponential fit, overdetermined: same minimum, cost, Jacobian and gradient as scipy
    t = np.linspace(0, 3, 40)
    y = 2.5 * np.exp(-1.3 * t) + 0.3 + 0.01 * np.random.default_rng(0).standard_normal(40)

    def f(p):
        return p[0] * np.exp(-p[1] * t) + p[2] - y

    def J(p):
        e = np.exp(-p[1] * t)
        return np.column_stack([e, -p[0] * t * e, np.ones_like(t)])

    jac = J if analytic else None
    r = lsq.least_squares(f, [1.0, 1.0, 0.0], jac, x_scale=x_scale if x_scale != [0.5, 2.0]
                          else [1.0, 1.0, 0.1], xtol=1e-12, ftol=1e-12, gtol=1e-12)  # fmt: skip
    ref = scipy.optimize.least_squares(f, [1.0, 1.0, 0.0], J, method="lm", xtol=1e-12,
                                       ftol=1e-12, gtol=1e-12)  # fmt: skip
    std = np.sqrt(np.diag(np.linalg.inv(ref.jac.T @ ref.jac)) * 2 * ref.cost / 37)
    assert np.all(np.abs(r.x - ref.x) < 1e-6 * std)
    assert r.cost == pytest.approx(ref.cost, rel=1e-10)
    np.testing.assert_allclose(r.jac, J(r.x), rtol=1e-5, atol=1e-6)
    assert r.optimality == pytest.approx(np.max(np.abs(J(r.x).T @ f(r.x))), abs=1e-6)


def test_rank_deficient_and_limits():
    # two identical columns: the minimum-norm step, a solution on the valley of minima
    A = np.array([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])
    y = np.array([1.0, 2.0, 3.1])
    r = lsq.least_squares(lambda x: A @ x - y, [0.0, 0.0], lambda x: A, x_scale=1.0)
    assert r.success and abs(r.x.sum() - (A[:, 0] @ y) / (A[:, 0] @ A[:, 0])) < 1e-9
    # the iteration limit: status 0, not a success
    r = lsq.least_squares(rosenbrock, [-1.2, 1.0], rosenbrock_jac, max_nfev=3)
    assert r.status == 0 and not r.success and r.nfev <= 3
    # a sparse Jacobian is taken as dense; fewer residuals than parameters is refused
    from scipy.sparse import csr_matrix

    r = lsq.least_squares(rosenbrock, [-1.2, 1.0], lambda x: csr_matrix(rosenbrock_jac(x)))
    assert r.success and np.allclose(r.x, 1.0, atol=1e-6)
    assert lsq.least_squares(lambda x: x[:1], [1.0, 2.0]).status == -1
    # residuals that blow up (NaN) are a rejected step, not a NaN solution
    r = lsq.least_squares(lambda x: np.array([np.sqrt(x[0]) - 1.0, 0.1 * x[0] - 0.1]),
                          [4.0], lambda x: np.array([[0.5 / np.sqrt(x[0])], [0.1]]))  # fmt: skip
    assert r.success and r.x[0] == pytest.approx(1.0, abs=1e-6)


def _agree(ours, ref, std, factor=1e-3):
    ours, ref, std = (np.asarray(v, float).ravel() for v in (ours, ref, std))
    assert np.all(np.abs(ours - ref) < factor * std), np.max(np.abs(ours - ref) / std)


@pytest.mark.parametrize("variant", ["9", "12"])
def test_gravity_family(with_scipy, variant):
    rng = np.random.default_rng(4)
    S, b = random_part(rng)
    a, cov, _ = poses(rng, S, b, cube18(), sigma_counts=4.0, jitter_deg=1)

    def fit():
        return gravity.fit_gravity(a, G0, cov_mean=cov, up=cube18(), variant=variant)

    ours, ref = fit(), with_scipy(fit)
    _agree(ours.params, ref.params, np.sqrt(np.diag(ref.cov)))
    res = gravity.fit_gravity(a, G0, cov_mean=cov)  # leave-one-out refits
    loo = gravity.leave_one_out(a, G0, res, cov_mean=cov)
    loo_ref = with_scipy(lambda: gravity.leave_one_out(a, G0, res, cov_mean=cov))
    _agree(loo, loo_ref, np.full(len(a), 1e-3 * np.std(loo_ref)), factor=1.0)


def test_labelled_family(with_scipy):
    session, _ = simulate(plan="qureshi18", seed=3, created=CREATED)
    p = static_poses(session)

    def fit():
        return fit_labelled(p.a_mean, p.up, G0, p.cov_mean, noise_dof=p.noise.dof)

    ours, ref = fit(), with_scipy(fit)
    _agree(ours.params, ref.params, ref.std)


def test_magnetometer_family(with_scipy):
    d = Design(1)
    ours, ref = fit_magnetometer(d.data, F), with_scipy(lambda: fit_magnetometer(d.data, F))
    _agree(ours.params, ref.params, ref.std)


@pytest.mark.parametrize(
    "cfg",
    [
        {"accel": {"solver": "factorization"}, "gyro": {"solver": "none"}},
        {"accel": {"solver": "gravity"}, "gyro": {"solver": "full"}},
    ],
)
def test_factorization_and_gyro_full_families(with_scipy, cfg):
    session, _ = simulate(plan="qureshi18", seed=5, created=CREATED)
    config = config_from_dict(cfg)
    ours = calibrate_session(session, config)
    ref = with_scipy(lambda: calibrate_session(session, config))
    for sensor in ("accel", "gyro") if cfg["gyro"]["solver"] != "none" else ("accel",):
        a, r = getattr(ours, sensor), getattr(ref, sensor)
        std = np.array([p["std"] for p in r.extra["parameters"]])
        vals = np.array([p["value"] for p in a.extra["parameters"]])
        vals_ref = np.array([p["value"] for p in r.extra["parameters"]])
        _agree(vals, vals_ref, std)


def test_bounded_scalar_minimum_matches_scipy():
    from imucal_cli.solvers.scalar_min import minimize_bounded

    rng = np.random.default_rng(0)
    for _ in range(30):
        c, s, w = rng.uniform(-2, 2), rng.uniform(0.3, 3), rng.uniform(0, 2)

        def f(x, c=c, s=s, w=w):
            return s * (x - c) ** 2 + 0.1 * w * np.sin(3 * x) + abs(x - c) ** 3

        ref = scipy.optimize.minimize_scalar(f, bounds=(-3, 3), method="bounded",
                                             options={"xatol": 2e-3})  # fmt: skip
        x, fx, n = minimize_bounded(f, -3, 3, xatol=2e-3)
        assert abs(x - ref.x) < 1e-9 and fx == pytest.approx(ref.fun) and n == ref.nfev


def test_pencil_roots_match_scipy_generalised_eigenvalues():
    import scipy.linalg

    from imucal_cli.solvers.factorization import _pencil_roots

    rng = np.random.default_rng(1)
    for k in range(4):
        A, B = (rng.standard_normal((4, 4)) for _ in range(2))
        A, B = A + A.T, B + B.T
        if k == 3:  # a singular B: one root at infinity
            B[:, 0] = B[0, :] = 0
        ours, ref = _pencil_roots(A, B), scipy.linalg.eigvals(A, -B)
        finite = np.isfinite(ref)
        assert np.sum(~np.isfinite(ours)) == np.sum(~finite)
        for r in ref[finite]:  # each root found (conjugate pairs in any order)
            assert np.min(np.abs(ours[np.isfinite(ours)] - r)) < 1e-9 * max(1, abs(r))
