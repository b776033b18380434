"""How well a known-angle fit (:mod:`.known`) predicts turns between still periods it did not
use: each one's gravity residual under the fit, and under the fit refitted without it (issue
24.5: whether the turns measured by gravity add anything the known turns do not)."""

from __future__ import annotations

import numpy as np

from imucal_cli.estimators.gyro.known import KnownResult, KnownTurns, fit_known
from imucal_cli.estimators.gyro.known_turns import gravity_statistics
from imucal_cli.estimators.gyro.model import Problem, Rotations, Stills


def predict_gravity(rot: Rotations, still: Stills, gyro_sigma: float, res: KnownResult,
                    accel_dirs: np.ndarray | None = None) -> dict:  # fmt: skip
    """:func:`gravity_statistics` of turns between still periods that ``res`` did not use:
    how well the result predicts them (the excess ``res.tau`` of the fit, zero when it used
    no such turn)."""
    with_g = res.G is not None
    gp = Problem(rot, still, gyro_sigma, g_sensitivity=with_g)
    x = np.r_[res.b, res.M.ravel(), res.G.ravel() if with_g else []]
    return gravity_statistics(gp, x, res.tau, accel_dirs)


def held_out_turns(known: KnownTurns, still: Stills, gyro_sigma: float, rot: Rotations,
                   res: KnownResult, *, accel_dirs: np.ndarray | None = None,
                   max_iterations: int = 50) -> np.ndarray:  # fmt: skip
    """Each gravity-referenced turn's residual angle (deg) predicted by the fit refitted
    without it (``res``'s model and excess ``tau``, from its solution): how well the turns
    predict one another, for :func:`imucal_cli.calibrate.gyro.known_checks`' choice whether
    they add anything the known turns do not (the bench's held-out check, done on the
    session itself).

    Raises
    ------
    DesignError, SolverError
        As :func:`fit_known` (the rest may not determine the model).
    """
    with_g = res.G is not None
    x0 = np.r_[res.b, res.M.ravel()]
    out = np.zeros(len(rot.t))
    for k in range(len(rot.t)):
        keep = np.setdiff1d(np.arange(len(rot.t)), [k])
        sub = Rotations([rot.t[i] for i in keep], [rot.z[i] for i in keep], rot.before[keep],
                        rot.after[keep], None if rot.a is None else [rot.a[i] for i in keep])
        refit = fit_known(known, still, gyro_sigma, x0[:3], rot=sub, x0=x0,
                          g_sensitivity=with_g, tau=res.tau, accel_dirs=accel_dirs,
                          max_iterations=max_iterations)  # fmt: skip
        one = Rotations([rot.t[k]], [rot.z[k]], rot.before[[k]], rot.after[[k]],
                        None if rot.a is None else [rot.a[k]])  # fmt: skip
        out[k] = predict_gravity(one, still, gyro_sigma, refit)["gravity_residual_deg"][0]
    return out
