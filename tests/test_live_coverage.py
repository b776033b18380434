"""The designs whose 95 % intervals ``bench live`` found short on the file path (issue 24):
each fix checked on a few seeds against what the noise (or the prior) allows.  The Monte-Carlo
over many seeds is ``python -m bench --only live`` (and the slow tests here)."""

from __future__ import annotations

import warnings

import numpy as np

from bench import live
from bench.live_grade import Graded, grade, partial_truth
from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.estimators.accel import partial as map_fit
from imucal_cli.formats.config import Config


def _graded(plan: str, seed: int) -> dict:
    session, truth = live.simulated(live.LivePlan(plan), seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return grade(session, calibrate_session(session, Config()), truth)


def test_partial_truth_is_the_reports_parameters():
    """The partial fit's parameters of a part, read back through its own Gram matrix (eq. 4:
    ``G = S S^T``), give the part's ``G``."""
    rng = np.random.default_rng(24)
    S = np.diag([850.0, 820.0, 840.0]) + rng.normal(0.0, 5.0, (3, 3))
    p = partial_truth(np.linalg.inv(S), np.array([10.0, -20.0, 30.0]))
    assert np.allclose(map_fit.gram(p), S @ S.T, rtol=1e-9)


def test_gyro_axes_accelerometer_graded_in_its_own_parameters():
    """gyro-axes holds 3 directions: the accelerometer is the partial fit (bias measured, gains
    and angles the datasheet prior's), stated as sensitivities in counts per m/s^2 and angles
    in degrees.  Graded as such, its std is the Bayesian bound at the truth (the same
    information and prior, within the change from the estimate to the truth) and no error is
    beyond 4 std (the prior is wider than the simulated parts: 3 % against +-3 % uniform).
    Graded as the gravity solver's matrix entries (the old grading), the gains were 37 std off."""
    for seed in (0, 1):
        graded = _graded("gyro-axes", seed)
        acc = graded["accel"]
        assert isinstance(acc, Graded) and acc.names == list(map_fit.NAMES), acc
        assert np.all(np.abs(acc.err) < 4 * acc.std), (seed, acc.err / acc.std)
        assert np.allclose(acc.std**2 / acc.crb, 1.0, atol=0.1), acc.std**2 / acc.crb
        # the known-angle gyro beside it has its bound (the grader once called a helper the
        # pipeline had renamed, and every known-angle row said "no bound")
        assert graded["gyro"].crb is not None, graded["gyro"].note
