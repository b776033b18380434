"""Checks every accelerometer fit goes through before it is saved (issue 10).

* **Outliers** (10.6): a bumped pose, a pose that moved during its hold, a wrong label. Each
  pose's studentized statistic (:mod:`imucal_cli.design.outliers`) is tested against the
  measured noise; flagged poses are left out (``[accel] outliers = "exclude"``, the default),
  down-weighted to what their residual shows (``"downweight"``) or only reported (``"keep"``),
  and named in the warnings by segment and label with the likely cause. A wrong label in the
  labelled-pose solver costs the label, not the pose (its magnitude still counts).
* **A fit far above the noise** (10.2): residuals many times what the measured noise allows
  are refused (exit 1) unless ``--force``, naming the segments that disagree most.
* **Too few spare equations** (10.3): a fit that can hardly check itself, or whose held-out
  error is several times its fit error, is flagged with what to capture; a fit residual below
  what the noise allows is marked so that no improvement factor is made of it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from imucal_cli.calibrate.common import StaticPoses
from imucal_cli.design import outliers as out
from imucal_cli.errors import SolverError
from imucal_cli.estimators.accel.labelled import contradicted_labels
from imucal_cli.model.accel import Coverage, OutlierRow

#: Residuals this many times what the measured noise allows make a fit refused ...
MISFIT_SIGMAS = 10.0
#: ... when their RMS is also above this, in mg (a fit at 0.1 mg is fine whatever the noise).
MISFIT_FLOOR_MG = 1.0
#: Fewer spare equations than this: the fit can hardly check itself.
MIN_SPARE = 5
#: Held-out RMS more than this many times the fit RMS: the poses do not constrain each other.
HELD_OUT_RATIO = 3.0
#: A labelled pose further than this from its label (and 5 placements) has a wrong label.
WRONG_LABEL_DEG = 20.0
#: At most this fraction of the poses is left out as outliers.
MAX_OUTLIER_FRACTION = 0.25


@dataclass
class Outlier:
    """A pose that disagrees with the rest."""

    index: int  # into the session's static poses
    segment: str
    label: str | None
    excess: float  # sqrt(T / rank): how many times what the measured noise allows
    p_value: float  # family-wise
    cause: str
    action: str  # "left out", "down-weighted", "kept", "label ignored"

    def row(self) -> OutlierRow:
        """Its row of the section's ``outliers`` table."""
        return OutlierRow(
            segment=self.segment,
            label=self.label,
            times_noise=float(self.excess) if np.isfinite(self.excess) else None,
            p_value=float(self.p_value),
            cause=self.cause,
            action=self.action,
        )

    def warning(self) -> str:
        name = f"segment {self.segment}" + (f" ({self.label})" if self.label else "")
        what = {
            "left out": "left out",
            "down-weighted": "down-weighted",
            "kept": 'kept (outliers = "keep")',
            "label ignored": "its label ignored, its magnitude kept",
        }[self.action]
        how = (
            f" ({self.excess:.1f}x what the measured noise allows, p {_p_text(self.p_value)})"
            if np.isfinite(self.excess)
            else ""
        )
        return f"{name} disagrees with the other poses{how}: {self.cause}; {what}"


def _p_text(p: float) -> str:
    return f"< {max(p, 1e-12):.0e}" if p < 1e-3 else f"= {p:.2g}"


def _cause(poses: StaticPoses, k: int, up_angle: float | None, placement: float) -> str:
    if (
        up_angle is not None
        and np.isfinite(up_angle)
        and up_angle > max(WRONG_LABEL_DEG, 5 * placement)
    ):
        return f"its measured up is {up_angle:.0f} deg from its label: the label is wrong"
    if poses.moved is not None and poses.moved[k]:
        return "the unit moved during the hold (its samples drift over time)"
    return "a bump, a shifted pose or a knock during the hold"


def robust_fit(
    fit: Callable[[StaticPoses], object],
    poses: StaticPoses,
    mode: str,
    design_ok: Callable[[StaticPoses], bool],
    labelled: bool = False,
) -> tuple[object, StaticPoses, list[Outlier]]:
    """Fit, test every pose, and leave out / down-weight / keep the ones that disagree.

    Parameters
    ----------
    fit : callable
        ``fit(poses)`` -> a solver result with ``deletion`` (:class:`.outliers.Deletion`) and
        ``up_angle_deg`` (angle of each pose to its label, NaN unlabelled).
    poses : StaticPoses
    mode : {"exclude", "downweight", "keep"}
    design_ok : callable
        Whether a reduced set of poses still determines the model.
    labelled : bool
        The solver uses the labels: a wrong label is dropped instead of the pose.

    Returns
    -------
    (result, poses used, outliers)
        ``poses used`` has the left-out poses removed (indices in ``Outlier.index`` refer to
        the poses given).
    """
    index = np.arange(len(poses.segments))
    res = fit(poses)
    found: list[Outlier] = []
    max_out = max(1, int(MAX_OUTLIER_FRACTION * len(index)))
    for _ in range(max_out + 2):
        bad = _flagged(res, poses, {o.index for o in found}, index)
        if not len(bad):
            break
        k = int(bad[0])
        o = _describe(res, poses, k, index)
        if mode == "keep" or sum(x.action == "left out" for x in found) >= max_out:
            found.append(replace(o, action="kept"))
            continue
        if labelled and "label is wrong" in o.cause:
            up = poses.up.copy()
            up[k] = np.nan
            trial = replace(poses, up=up)
            action = "label ignored"
        elif mode == "downweight":
            cov = poses.cov_mean.copy()
            cov[k] *= max(o.excess**2, 1.0)
            trial, action = replace(poses, cov_mean=cov), "down-weighted"
        else:
            trial, action = poses.subset(np.arange(len(index)) != k), "left out"
        if not design_ok(trial):
            cause = o.cause + " (the other poses cannot do without it)"
            found.append(replace(o, action="kept", cause=cause))
            continue
        try:
            refit = fit(trial)
        except SolverError:  # e.g. 9 directions left for 9 parameters, and no convergence
            cause = o.cause + " (without it the fit does not converge)"
            found.append(replace(o, action="kept", cause=cause))
            continue
        found.append(replace(o, action=action))
        poses, res = trial, refit
        if action == "left out":
            index = index[np.arange(len(index)) != k]
    return res, poses, found


def drop_wrong_labels(poses: StaticPoses, g: float) -> tuple[StaticPoses, list[Outlier]]:
    """Labels the readings contradict (a pose labelled with the wrong face) dropped before the
    labelled-pose fit, which they would spoil or stop: the pose keeps its magnitude."""

    found = []
    up = poses.up.copy()
    for k, angle in contradicted_labels(poses.a_mean, poses.up, g, WRONG_LABEL_DEG):
        seg = poses.segments[k]
        cause = f"its measured up is {angle:.0f} deg from its label: the label is wrong"
        found.append(Outlier(k, seg.name, seg.label, float("inf"), 0.0, cause, "label ignored"))
        up[k] = np.nan
    return (replace(poses, up=up) if found else poses), found


def _flagged(res, poses: StaticPoses, done: set[int], index: np.ndarray) -> np.ndarray:
    """Poses flagged by their statistic or by motion during the hold, worst first, not yet
    handled."""
    d = res.deletion
    bad = list(out.flag(d))
    if poses.moved is not None:
        bad += [k for k in np.flatnonzero(poses.moved) if k not in bad]
    return np.array([k for k in bad if int(index[k]) not in done], dtype=int)


def _describe(res, poses: StaticPoses, k: int, index: np.ndarray) -> Outlier:
    d = res.deletion
    rank = max(int(d.rank[k]), 1)
    excess = float(np.sqrt(max(d.T[k], 0.0) / rank))  # against the measured noise
    p = out.significance(d, k)
    up_angle = None if res.up_angle_deg is None else float(res.up_angle_deg[k])
    finite = res.up_angle_deg is not None and np.isfinite(res.up_angle_deg).any()
    placement = float(np.nanmedian(res.up_angle_deg)) if finite else 0.0
    seg = poses.segments[k]
    return Outlier(
        int(index[k]), seg.name, seg.label, excess, p, _cause(poses, k, up_angle, placement), ""
    )


# --------------------------------------------------------------------------- fit quality


def pose_sigmas(poses: StaticPoses, matrix: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """Noise of each pose's calibrated magnitude, m/s^2 (``u^T M Sigma_k M^T u``)."""
    h = (poses.a_mean - bias) @ matrix.T
    u = h / np.linalg.norm(h, axis=1, keepdims=True)
    v = u @ matrix
    return np.sqrt(np.clip(np.einsum("ni,nij,nj->n", v, poses.cov_mean, v), 0, None))


@dataclass
class Quality:
    """How the fit residual compares with the noise and with the held-out residual."""

    spare: int  # spare equations
    n_params: int
    expected_rms: float  # fit RMS the noise predicts, m/s^2
    excess: float  # sqrt(chi^2 / dof) against the measured noise (1 = as the noise predicts)
    below_noise: bool  # fit residual below what the noise allows (an exact fit)
    warnings: list[str]
    blocking: list[str]


def quality(
    poses: StaticPoses,
    residuals: np.ndarray,
    sigmas: np.ndarray,
    spare: int,
    n_params: int,
    rms_loo: float | None,
    g: float,
    coverage: Coverage,
    excess: float | None = None,
    distinct: int | None = None,
    instead: str | None = None,
) -> Quality:
    """The checks of 10.2 and 10.3 on a finished fit (module docstring). ``excess`` is the
    solver's own sqrt(chi^2 / dof) against the measured noise; default: from the magnitudes.

    ``distinct``: for a fit of one magnitude equation per pose (gravity solver), the number
    of distinct directions among the poses. A pose repeating a direction repeats its
    equation: it averages the noise (``spare`` still counts it for the noise) but checks
    nothing of the model, so the spare equations said in the warning and in
    ``spare_equations`` are ``min(spare, distinct - n_params)``. ``instead``: what would
    work with what the session has (another solver), said before a new capture (9.6)."""
    stat_spare = spare
    if distinct is not None:
        spare = min(spare, distinct - n_params)
    N = len(residuals)
    rms_after = float(np.sqrt(np.mean(residuals**2)))
    sig = float(np.sqrt(np.mean(sigmas**2)))
    expected = sig * np.sqrt(max(stat_spare, 0) / N)
    if excess is None:
        chi2 = float(np.sum((residuals / np.maximum(sigmas, 1e-12)) ** 2))
        excess = float(np.sqrt(chi2 / stat_spare)) if stat_spare > 0 else float("nan")
    warnings, blocking = [], []
    below = stat_spare <= 0 or rms_after < 0.5 * expected
    if spare < MIN_SPARE:
        warnings.append(_spare_warning(spare, N, n_params, distinct, instead))
    if rms_loo is not None and np.isfinite(rms_loo):
        ratio = rms_loo / max(rms_after, expected, 1e-12)
        if ratio > HELD_OUT_RATIO:
            weak = coverage.weakest_direction
            where = (
                ""
                if weak is None
                else (" (weakest direction [" + ", ".join(f"{x:+.2f}" for x in weak) + "])")
            )
            warnings.append(
                f"held-out error {rms_loo:.3g} m/s^2 is {rms_loo / max(rms_after, 1e-12):.0f}x "
                "the fit error "
                f"{rms_after:.2g} m/s^2: each pose is needed to determine the others (left out, "
                "its axis rests on the rest's labels or magnitudes alone), so no pose is checked "
                "by the others and a bump or a misplaced pose would go unnoticed; capture more "
                f"poses spread over the sphere (the 12 edges of plan qureshi18){where}"
            )
    if stat_spare > 0 and excess > MISFIT_SIGMAS and 1000 * rms_after / g > MISFIT_FLOOR_MG:
        worst = np.argsort(-np.abs(residuals / np.maximum(sigmas, 1e-12)))[:3]
        names = ", ".join(
            poses.segments[k].name
            + (f" ({poses.segments[k].label})" if poses.segments[k].label else "")
            for k in worst
        )
        blocking.append(
            f"the poses disagree: residuals {excess:.0f}x what the measured noise allows (RMS "
            f"{rms_after:.3g} m/s^2 where {max(expected, 1e-9):.2g} is expected); most of all "
            f"{names}: was the unit still during each hold, and is each label right?"
        )
    return Quality(spare, n_params, expected, excess, below, warnings, blocking)


def _spare_warning(
    spare: int, N: int, n_params: int, distinct: int | None, instead: str | None
) -> str:
    """The 10.3 warning of a fit with fewer than :data:`MIN_SPARE` spare equations."""
    more = max(18 - (N if distinct is None else distinct), 3)
    what = (
        "the fit is exact and cannot check itself: its residual says nothing about the accuracy"
        if spare <= 0
        else "the fit can hardly check itself (one bad pose would go unnoticed)"
    )
    poses = f"{N} poses for {n_params} parameters" if distinct is None or distinct >= N else (
        f"{N} poses in {distinct} distinct directions for {n_params} parameters; a repeated "
        "direction checks the noise, not the model")  # fmt: skip
    return (
        f"only {max(spare, 0)} spare equations ({poses}): "
        f"{what}; {instead + ', or ' if instead else ''}capture {more} or more further poses "
        "in new directions spread over the sphere (the 45-degree edges: plan qureshi18)"
    )
