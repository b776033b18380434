"""Issue 17.1: the temperature ramp of the simulator and the bias-vs-temperature solvers."""

import math

import numpy as np
import pytest

from imucal_cli.errors import DesignError, InputError
from imucal_cli.estimators.accel.gravity import fit_gravity
from imucal_cli.estimators.thermal import joint
from imucal_cli.estimators.thermal.joint import fit_gravity_tempco
from imucal_cli.estimators.thermal.temperature import (
    ALIAS_MAX,
    MIN_SPAN_C,
    SELECT_P,
    alias_inflation,
    check_span,
    consider_cov,
    f1_pvalue,
    fit_tempco,
    noise_scale,
    polynomial_bound,
    reexpand,
)
from imucal_cli.simulate.temperature import Ramp, parse_ramp
from imucal_cli.simulate.triad import simulate

G0 = 9.80665


def test_ramp_session_records_temperature_and_truth_holds_the_polynomial():
    plain, truth0 = simulate(seed=11, plan="six")
    warm, truth = simulate(seed=11, plan="six", temperature=Ramp(5.0, 40.0, "linear"))
    assert plain.temperature is None
    t = warm.temperature
    assert t.shape == warm.time.shape
    assert abs(t[0] - 5.0) < 0.2 and abs(t[-1] - 40.0) < 0.2
    for name in ("accel", "gyro"):
        sec = getattr(truth, name)
        assert sec.temperature_ref == 25.0
        tc = np.array(sec.bias_tempco)
        assert tc.shape == (3, 3) and np.all(tc[0] != 0)
        # the same seed is the same part: the bias at T_ref is unchanged by the ramp
        np.testing.assert_array_equal(sec.bias, getattr(truth0, name).bias)
    # the raw data move by the truth's polynomial at the true temperature (same noise draws)
    tc = np.array(truth.accel.bias_tempco)
    true_c = Ramp(5.0, 40.0, "linear").true_c(warm.time)
    dt = true_c - 25.0
    change = (dt[:, None] ** np.arange(1, 4)) @ tc
    np.testing.assert_allclose(warm.accel - plain.accel, change, atol=1.01)  # quantised counts


def test_ramp_is_reproducible_and_warmup_shape_is_front_loaded():
    a, _ = simulate(seed=5, plan="six", temperature=Ramp(10.0, 30.0))
    b, _ = simulate(seed=5, plan="six", temperature=Ramp(10.0, 30.0))
    np.testing.assert_array_equal(a.temperature, b.temperature)
    np.testing.assert_array_equal(a.accel, b.accel)
    true_c = Ramp(10.0, 30.0).true_c(a.time)
    assert true_c[len(true_c) // 2] > 25.0  # a warm-up makes most of its change early


# 20:200 and -1e300:1e300 passed a check whose `not` bound only its first half: numpy overflow
# warnings, then an error about the written session's NaN (audit)
@pytest.mark.parametrize("text", ["5", "a:b", "5:5", "5:40:zigzag", "-100:20", "20:200",
                                  "-1e300:1e300"])
def test_parse_ramp_refuses_nonsense(text):
    with pytest.raises(InputError, match="--ramp"):
        parse_ramp(text)


def test_parse_ramp_reads_shape():
    assert parse_ramp("5:45") == Ramp(5.0, 45.0, "warmup")
    assert parse_ramp("40:20:linear") == Ramp(40.0, 20.0, "linear")


def test_f1_pvalue_matches_closed_forms():
    # F(1, 1) is the square of a Cauchy variable: P(F > x) = 1 - 2/pi atan(sqrt x)
    for x in (0.1, 1.0, 7.5, 300.0):
        assert f1_pvalue(x, 1.0) == pytest.approx(1 - 2 / math.pi * math.atan(math.sqrt(x)),
                                                  rel=1e-10)  # fmt: skip
    # F(1, 2): P(F > x) = 1 - sqrt(x / (x + 2))
    for x in (0.3, 4.0, 99.0):
        assert f1_pvalue(x, 2.0) == pytest.approx(1 - math.sqrt(x / (x + 2)), rel=1e-10)
    # large dof: the chi-square(1) tail, P(Z^2 > 3.8415) = 0.05
    assert f1_pvalue(3.841459, 1e7) == pytest.approx(0.05, rel=1e-4)
    assert f1_pvalue(0.0, 5) == 1.0


def test_span_under_minimum_is_refused_saying_why():
    with pytest.raises(DesignError, match=r"spans only 6.0 C .*at least 10 C"):
        check_span(np.linspace(20, 26, 50), "warm.h5")
    with pytest.raises(DesignError, match="no temperature readings"):
        check_span(np.full(5, np.nan), "warm.h5")
    assert check_span(np.linspace(20, 20 + MIN_SPAN_C, 5), "x") == pytest.approx(MIN_SPAN_C)


def _points(coef, n=200, sigma=0.5, seed=0, span=(0.0, 40.0)):
    rng = np.random.default_rng(seed)
    T = np.linspace(*span, n)
    y = np.polyval(coef[::-1], T - 20.0) + sigma * rng.standard_normal(n)
    return T, y


@pytest.mark.parametrize("coef", [[3.0, 0.0], [3.0, 0.4], [3.0, 0.4, 0.01],
                                  [3.0, 0.4, 0.01, 0.0008]])  # fmt: skip
def test_a_term_aliased_with_the_kept_ones_is_kept(coef):
    """Over 0-40 C, ``(T - 20)^3`` is so like ``T - 20`` that dropping the cubic would take
    about 5/6 off the linear term's variance: whatever the F-test says, the cubic stays (held
    at zero, a cubic the test cannot find moves the linear term by up to 2.6 sqrt(5) of its
    std).  The fit is then the cubic's own: its std the bound's, its estimates within it."""
    T, y = _points(np.array(coef))
    fit = fit_tempco(T, y, sigma=np.full(len(T), 0.5), temperature_ref=20.0)
    c = fit.channels[0]
    assert c.degree == 3
    top = c.tests[0]
    assert top["degree"] == 3 and top["kept"] and top["alias"] > ALIAS_MAX
    if len(coef) < 4:
        assert top["p_value"] > SELECT_P  # kept for its aliasing, not its significance
    truth = np.r_[coef, np.zeros(4 - len(coef))][1:]
    std = fit.tempco_std[:, 0]
    assert np.all(np.abs(fit.tempco[:, 0] - truth) < 4.5 * std)
    crb = polynomial_bound(T, 0.5, 3, 20.0)
    np.testing.assert_allclose(std, np.sqrt(np.diag(crb)[1:]), rtol=1e-9)
    assert c.level[0] == pytest.approx(3.0, abs=0.3)


def test_consider_cov_estimates_the_held_terms_shift_without_double_counting():
    """``A max(d d^T - C_d, 0) A^T``: ``E[d d^T] = delta delta^T + C_d``, so the rule is an
    unbiased estimate of the shift's square ``A delta delta^T A^T`` wherever the clip does not
    bite; adding ``C_d`` on top (as before) counted it twice."""
    A = np.array([[0.5, -0.2], [1.5, 0.3], [0.0, 2.0]])
    C = np.array([[0.04, 0.01], [0.01, 0.09]])
    delta = np.array([3.0, -2.0])
    # one estimate: the matrix difference's positive part (here of full rank 1 plus a negative)
    d = np.array([2.5, -1.5])
    w, V = np.linalg.eigh(np.outer(d, d) - C)
    expect = A @ V @ np.diag(np.clip(w, 0, None)) @ V.T @ A.T
    np.testing.assert_allclose(consider_cov(A, d, C), expect, rtol=1e-12, atol=1e-15)
    assert np.linalg.eigvalsh(consider_cov(A, d, C)).min() > -1e-12
    assert not consider_cov(A, np.zeros(2), C).any()  # nothing seen: nothing added
    # over draws of d ~ N(delta, C), its mean is A delta delta^T A^T (MC std of the mean
    # about 0.5 % of the entries at 20,000 draws; 2 % allowed)
    rng = np.random.default_rng(3)
    L = np.linalg.cholesky(C)
    draws = delta + rng.standard_normal((20000, 2)) @ L.T
    mean = np.mean([consider_cov(A, x, C) for x in draws], axis=0)
    target = A @ np.outer(delta, delta) @ A.T
    np.testing.assert_allclose(mean, target, rtol=0.02, atol=0.02 * np.abs(target).max())
    assert alias_inflation(np.diag([2.0, 1.1, 9.0]), np.diag([1.0, 1.0])) == pytest.approx(1.0)


def test_an_unaliased_term_is_dropped_with_its_shift_carried():
    """A linear model about a reference near the points' mean temperature: the slope hardly
    moves the level (alias under ``ALIAS_MAX``), so a slope the F-test cannot find is
    dropped, and the level's variance is the constant fit's plus ``consider_cov`` of the slope
    (what it still adds), computed here on its own."""
    T = np.linspace(0.0, 40.0, 41)
    rng = np.random.default_rng(5)
    ref = 21.0  # the mean is 20: dropping the slope takes 0.2 % off the level's variance
    sig = np.full(len(T), 0.5)
    X = np.column_stack([np.ones(len(T)), T - ref]) / 0.5
    big = np.linalg.inv(X.T @ X)
    y = 3.0 + 0.5 * rng.standard_normal(len(T))
    # a slope of 2 of its std: not significant at 1 %, and d^2 - C_d = 3 C_d > 0
    y += (2.0 * np.sqrt(big[1, 1]) - (big @ X.T @ (y / 0.5))[1]) * (T - ref)
    fit = fit_tempco(T, y, sigma=sig, temperature_ref=ref, max_degree=1)
    c = fit.channels[0]
    assert c.degree == 0 and not c.tests[0]["kept"] and c.tests[0]["alias"] < ALIAS_MAX
    beta = big @ X.T @ (y / 0.5)
    A = np.array([[np.sum(X[:, 0] * X[:, 1]) / np.sum(X[:, 0] ** 2)]])  # (X_0'X_0)^-1 X_0'X_1
    held = consider_cov(A, beta[1:], big[1:, 1:])
    np.testing.assert_allclose(held, 3.0 * A**2 * big[1, 1], rtol=1e-9)
    chi2 = float(np.sum(((y - y.mean()) / 0.5) ** 2))
    scale = noise_scale(chi2, len(T) - 1, True)
    np.testing.assert_allclose(c.cov, scale * 0.25 / len(T) + held, rtol=1e-9)
    # the same slope about a reference at the span's end: the level is the slope's alias
    off = fit_tempco(T, y, sigma=sig, temperature_ref=0.0, max_degree=1).channels[0]
    assert off.degree == 1 and off.tests[0]["alias"] > ALIAS_MAX


def test_noise_scale_is_one_rule():
    """``chi2/dof`` when the noise is unknown; with it given, only past the 99th percentile of
    ``chi^2(dof)`` (the joint fit and the polynomial share the function)."""
    from scipy.stats import chi2 as chi2_dist

    assert noise_scale(30.0, 10, False) == pytest.approx(3.0)
    edge = float(chi2_dist.ppf(0.99, 10))
    assert noise_scale(0.99 * edge, 10, True) == 1.0
    assert noise_scale(1.01 * edge, 10, True) == pytest.approx(1.01 * edge / 10)
    assert joint.noise_scale is noise_scale


def test_a_cubic_the_test_cannot_find_leaves_the_linear_term_s_intervals_honest():
    """A cubic the 1 % F-test cannot tell from zero (1-2 of its std) moves the linear term of
    a lower-degree fit by several of that fit's std (a warm-up's 8-40 C, most of it warm): it
    is kept, and the linear term's 95 % intervals hold the truth 95 % of the time (were it
    dropped: 32 % and 66 %).  200 draws each: binomial std 1.5 %, so at least 90 %."""
    x = np.linspace(0.0, 1.0, 24)
    T = 8.0 + 32.0 * (1.0 - np.exp(-3.0 * x)) / (1.0 - np.exp(-3.0))
    ref = float(T.mean())
    s3 = float(np.sqrt(polynomial_bound(T, 1.0, 3, ref)[-1, -1]))
    rng = np.random.default_rng(24)
    for k in (1.0, 2.0):
        hits, unfound = [], 0
        for _ in range(200):
            y = 50.0 + (T - ref) + k * s3 * (T - ref) ** 3 + rng.standard_normal(len(T))
            c = fit_tempco(T, y, sigma=np.ones(len(T))).channels[0]
            assert c.degree == 3
            unfound += c.tests[0]["p_value"] >= SELECT_P
            hits.append(abs(c.tempco[0] - 1.0) <= 1.96 * np.sqrt(c.tempco_cov[0, 0]))
        assert unfound > 50  # the case at stake: a cubic the test does not find
        assert np.mean(hits) >= 0.90, (k, np.mean(hits))


def test_groups_share_the_curve_and_keep_their_levels():
    T, y = _points(np.array([0.0, 0.3]), n=120, sigma=0.2, seed=3)
    g = np.arange(len(T)) % 3
    y = y + np.array([100.0, -50.0, 7.0])[g]
    fit = fit_tempco(T, np.column_stack([y, 2 * y]), groups=g, temperature_ref=20.0)
    np.testing.assert_allclose(fit.level[:, 0], [100.0, -50.0, 7.0], atol=0.2)
    assert fit.tempco[0, 0] == pytest.approx(0.3, abs=0.01)
    assert fit.tempco[0, 1] == pytest.approx(0.6, abs=0.02)


def test_serial_correlation_inflates_the_standard_deviation():
    rng = np.random.default_rng(7)
    T = np.linspace(0, 30, 300)
    e = np.zeros(len(T))
    for i in range(1, len(T)):  # AR(1) wander, rho = 0.9
        e[i] = 0.9 * e[i - 1] + 0.1 * rng.standard_normal()
    y = 0.2 * (T - 15) + e
    red = fit_tempco(T, y, serial=True)
    assert red.channels[0].correlation > 0.7
    # the wander does not pass for a cubic (kept for its aliasing with the slope, not found)
    assert red.channels[0].tests[0]["p_value"] > SELECT_P
    white = fit_tempco(T, y, max_degree=1)
    assert red.tempco_std[0, 0] > 3 * white.tempco_std[0, 0]  # sqrt((1 + rho) / (1 - rho))
    assert abs(red.tempco[0, 0] - 0.2) < 3 * red.tempco_std[0, 0]


def test_fit_refuses_narrow_span_and_too_few_points():
    with pytest.raises(DesignError, match="at least 10 C"):
        fit_tempco(np.linspace(20, 25, 30), np.zeros(30), what="warm.h5")
    with pytest.raises(DesignError, match="2 points"):
        fit_tempco(np.array([0.0, 30.0]), np.zeros(2))


def test_reexpand_keeps_the_polynomial():
    rng = np.random.default_rng(1)
    c = rng.normal(size=(3, 2))
    d0, d = reexpand(c, 25.0, 31.0)
    T = np.linspace(0, 50, 7)
    old = ((T - 25.0)[:, None] ** np.arange(1, 4)) @ c
    new = d0 + ((T - 31.0)[:, None] ** np.arange(1, 4)) @ d
    np.testing.assert_allclose(new, old, atol=1e-9)


def _pose_means(session):
    segs = session.static_segments()
    a = np.array([session.accel[s.start : s.stop].mean(0) for s in segs])
    T = np.array([session.temperature[s.start : s.stop].mean() for s in segs])
    cov = np.array([np.cov(session.accel[s.start : s.stop].T) / (s.stop - s.start)
                    for s in segs])  # fmt: skip
    return a, T, cov


@pytest.mark.parametrize("seed", [5, 8])
def test_joint_gravity_fit_recovers_the_bias_change_over_the_span(seed):
    session, truth = simulate(seed=seed, plan="qureshi18", temperature=Ramp(5.0, 40.0, "linear"))
    a, T, cov = _pose_means(session)
    plain = fit_gravity(a, G0)
    joint = fit_gravity_tempco(a, T, G0, (plain.bias, plain.M), cov_mean=cov)
    tc_true = np.array(truth.accel.bias_tempco)
    grid = np.array([T.min(), T.max()])
    true_change = ((grid - 25.0)[:, None] ** np.arange(1, 4)) @ tc_true
    est = ((grid - joint.temperature_ref)[:, None] ** np.arange(1, joint.tempco.shape[0] + 1)
           ) @ joint.tempco  # fmt: skip
    # the change of bias across the span (about 100 counts): within 20 % of the truth's
    np.testing.assert_allclose(est[1] - est[0], true_change[1] - true_change[0],
                               rtol=0.2, atol=5.0)  # fmt: skip
    # the joint fit explains the poses: residuals at the noise, far below the plain fit's
    assert np.sqrt(np.mean(joint.residuals**2)) < 0.5 * np.sqrt(np.mean(plain.residuals**2))
    assert np.all(joint.degree <= 3) and joint.tempco_std.shape == joint.tempco.shape


def test_joint_fit_refuses_a_narrow_span():
    session, _ = simulate(seed=4, plan="qureshi18", temperature=Ramp(20.0, 26.0, "linear"))
    a, T, cov = _pose_means(session)
    plain = fit_gravity(a, G0)
    with pytest.raises(DesignError, match="at least 10 C"):
        fit_gravity_tempco(a, T, G0, (plain.bias, plain.M), cov_mean=cov)


def test_cli_simulate_ramp_writes_temperature_and_truth(tmp_path):
    from imucal_cli.formats.calibration import read_calibration
    from imucal_cli.formats.session import read_session

    from .cli_helpers import assert_one_line_error, run

    out = tmp_path / "warm.h5"
    proc = run("simulate", "--plan", "six", "--seed", "3", "--ramp", "10:35:linear", "-o", out)
    assert proc.returncode == 0, proc.stderr
    s = read_session(out)
    assert s.temperature.min() < 10.2 and s.temperature.max() > 34.8
    truth = read_calibration(tmp_path / "warm.truth.json")
    assert len(truth.accel.bias_tempco) == 3
    assert_one_line_error(run("simulate", "--ramp", "20", "-o", tmp_path / "x.h5"), "--ramp")


def _level_ramp():
    """A qureshi18 ramp's pose temperatures and mean covariances (seed 5, 10 -> 40 C), its
    gravity fit without temperature, raw units per m/s^2, and its poses' means moved to read
    gravity exactly (no temperature term): the level a test adds its temperature terms to."""
    session, _ = simulate(seed=5, plan="qureshi18", temperature=Ramp(10.0, 40.0, "linear"))
    a, T, cov = _pose_means(session)
    plain = fit_gravity(a, G0)
    u = (a - plain.bias) @ plain.M.T
    level = plain.bias + (G0 * u / np.linalg.norm(u, axis=1, keepdims=True)) @ np.linalg.inv(
        plain.M).T  # fmt: skip
    return T, cov, plain, 1.0 / np.mean(np.diag(plain.M)), level


def test_a_cubic_the_poses_cannot_fit_is_in_the_kept_terms_std_through_its_prior():
    """Issue 24.6: 18 poses through a ramp determine a quadratic with the gravity-magnitude
    model; the part's cubic, held at zero, shifts tc1 and tc2 by ``A c3``.  Carried as a
    consider parameter with its prior (``A P A^T``, :func:`unfitted_prior`), the 95 %
    intervals hold the truth for cubics drawn from that prior (80 parts, 240 intervals: 97 %
    here, at least 88 %); without it, 57 % (the cubic is aliased with the linear term)."""
    from imucal_cli.estimators.thermal.temperature import unfitted_prior

    T, cov, plain, raw_per_si, level = _level_ramp()
    prior = unfitted_prior(0.5 * G0 / 1000.0, (2, 3))
    assert prior[3] == pytest.approx(0.1 * 0.5 * G0 / 1000.0 / 15.0**2 / np.sqrt(3.0))
    rng = np.random.default_rng(11)
    L = np.linalg.cholesky(cov)
    hits = {True: [], False: []}
    for _ in range(80):
        c = np.vstack([rng.uniform(-1, 1, 3) * 0.5, rng.uniform(-1, 1, 3) * 0.5 / 50,
                       rng.uniform(-1, 1, 3) * 0.5 / 2500]) * G0 / 1000.0 * raw_per_si
        dt = T - 25.0
        y = level + (dt[:, None] ** np.arange(1, 4)) @ c + np.einsum(
            "nij,nj->ni", L, rng.standard_normal((len(T), 3)))  # fmt: skip
        for with_prior in (True, False):
            fit = fit_gravity_tempco(y, T, G0, (plain.bias, plain.M), cov_mean=cov,
                                     unfitted_std=prior if with_prior else None)  # fmt: skip
            assert fit.design_degree == 2 and list(fit.degree) == [2, 2, 2]
            _, c_ref = reexpand(c, 25.0, fit.temperature_ref)
            z = (fit.tempco[0] - c_ref[0]) / fit.tempco_std[0]
            hits[with_prior] += list(np.abs(z) <= 1.96)
            if with_prior:  # the terms' covariance: the fitted ones, then the cubic's prior
                assert fit.terms_columns[-3:] == [(3, 0), (3, 1), (3, 2)]
                assert fit.terms_cov.shape == (9 + 9, 9 + 9)
    assert np.mean(hits[True]) >= 0.88, np.mean(hits[True])
    assert np.mean(hits[False]) < 0.80, np.mean(hits[False])


def test_a_known_cubic_moves_tc1_by_the_alias_the_consider_term_states():
    """Issue 24.6, noise-free: a cubic put into a qureshi18 ramp's poses moves the fitted
    terms by ``A c3``; the consider term states ``A`` in its cross-covariance (``-A P``, so
    ``A = -terms_cov[:, cubic] / P``) and ``P`` is the prior's: ``0.1 x 0.5 mg/C x 15 C /
    15^3 / sqrt(3)`` per C^3, in raw units.  The shift is the linearised one within 1 %."""
    from imucal_cli.estimators.thermal.temperature import unfitted_prior

    T, cov, plain, raw_per_si, level = _level_ramp()
    prior = unfitted_prior(0.5 * G0 / 1000.0, (2, 3))
    per_mg = G0 / 1000.0 * raw_per_si  # raw units per mg
    c1 = np.array([0.3, -0.2, 0.4]) * per_mg
    c3 = np.array([1.0, -1.0, 0.5]) * 0.5 / 2500.0 * per_mg  # the simulator's largest cubic
    t_ref = float(np.mean(T))
    dt = (T - t_ref)[:, None]

    def fit(cubic):
        return fit_gravity_tempco(level + dt * c1 + dt**3 * cubic, T, G0, (plain.bias, plain.M),
                                  cov_mean=cov, temperature_ref=t_ref, select_p=1.0,
                                  unfitted_std=prior)  # fmt: skip

    base, moved = fit(0 * c3), fit(c3)
    assert list(moved.degree) == [2, 2, 2] and moved.design_degree == 2
    np.testing.assert_allclose(base.tempco[0], c1, rtol=1e-6)  # no cubic: exact
    cols = moved.terms_columns
    cub = [cols.index((3, c)) + 9 for c in range(3)]
    lin = [cols.index((1, c)) + 9 for c in range(3)]
    C = moved.terms_cov
    P = np.diag(C[np.ix_(cub, cub)])
    want = 0.1 * 0.5 * 15.0 / 15.0**3 / np.sqrt(3.0) * per_mg  # the prior's std, raw per C^3
    np.testing.assert_allclose(np.sqrt(P), want, rtol=1e-9)
    A = -C[np.ix_(lin, cub)] / P
    shift = moved.tempco[0] - base.tempco[0]
    assert np.all(np.abs(shift) > 0.2 * np.abs(c1) * 0.01)  # a shift worth checking
    np.testing.assert_allclose(shift, A @ c3, rtol=0.01)
