"""The calibrate step's temperature model: each channel's bias as a polynomial in temperature.

Two sources (issue 17.1), one flow:

* **joint** (``[temperature] model = "auto"`` when the session's still periods span
  ``min_span_c`` (10 C) or more, or ``"on"``): the session's own still periods, and those of
  the sessions given with ``--with`` (the same unit at other temperatures, merged into one;
  :func:`merge_sessions`). The accelerometer's temperature terms are fitted jointly with its
  gravity-magnitude model (:mod:`imucal_cli.estimators.thermal.joint`) on block means of the
  still periods; the gyroscope's from the raw gyro block means, which read its bias at their
  temperatures (:func:`imucal_cli.estimators.thermal.temperature.fit_tempco`).
* **warm-up** (``--warmup FILE``, repeatable): still recordings through a warm-up or a
  cool-down; each still period keeps its own level and the temperature curve is shared, so a
  warm-up in a single orientation gives every channel's curve.

Then the raw samples are compensated to ``T_ref`` (``raw - sum_k c_k (T - T_ref)^k``, each
sample at its recorded temperature), the configured solvers calibrate the compensated session
as usual, and each section gets the standard ``temperature_ref`` and ``bias_tempco`` fields,
``temperature_range_c``, the model's diagnostics (``temperature_model``), one parameter row
per term, and bias standard deviations that include the temperature terms' uncertainty.
``T_ref`` is the session's mean temperature (its bias is measured there).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from dataclasses import replace as copy_with

import numpy as np

from imucal_cli.calibrate.accel.section import model_map
from imucal_cli.calibrate.common import channel_names, session_name, with_segments
from imucal_cli.errors import DesignError, ImucalWarning
from imucal_cli.estimators.accel.gravity import fit_gravity, model_to_params
from imucal_cli.estimators.thermal.joint import fit_gravity_tempco
from imucal_cli.estimators.thermal.temperature import (
    MAX_DEGREE,
    TempcoFit,
    check_span,
    fit_tempco,
    reexpand,
    unfitted_prior,
)
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.model.accel import Compensation
from imucal_cli.model.calibration import SensorCalibration
from imucal_cli.model.codec import build
from imucal_cli.model.parts import Parameter, SelectionRow
from imucal_cli.model.parts import TemperatureModel as TemperatureModelRecord
from imucal_cli.model.session import GRAVITY_DEFAULT as G0

__all__ = ["TemperatureModel", "attach", "compensate", "given_accel", "merge_sessions",
           "temperature_models", "widen_accel"]

#: Length of the blocks each still period is averaged over, s.
BLOCK_S = 5.0
#: Fewest blocks a warm-up recording's still time is cut into (shorter blocks when short).
MIN_BLOCKS = 30
#: Blocks each still period gives the accelerometer's joint fit at least. One: the blocks of a
#: pose differ by a fraction of a degree (qureshi18 through 10 -> 40 C: a median 0.33 C of a
#: 28 C span), so a term only they would fix is fitted to within-pose differences; its error
#: then moves the compensated poses the gyro solver reads, which no std states (two blocks
#: took the gyro matrix's coverage on that ramp from 94 % to 84 %). The joint fit counts
#: distinct poses, not blocks (:func:`fit_gravity_tempco`'s ``groups``).
JOINT_BLOCKS = 1
UNITS_PER_C = {1: "per C", 2: "per C^2", 3: "per C^3"}


@dataclass
class TemperatureModel:
    """One sensor's bias temperature model, ready to compensate and to attach.

    ``tempco``/``tempco_std`` (K, n) raw units per C^k about ``temperature_ref``; ``degree``
    (n,); ``t_min``/``t_max`` the fitted range, C; ``bias_var_extra`` (n,) what the terms add
    to the bias variance at ``T_ref``; ``details`` the solver's diagnostics (members of the
    section's :class:`~imucal_cli.model.parts.TemperatureModel`); ``note`` for the section's
    notes (a degree the poses or ``max_degree`` limited, a prior widened: one or a list);
    ``model_cov_extra`` (9, 9) what the terms add to the
    gravity-magnitude model's ``(B, M upper)`` covariance (:func:`widen_accel`);
    ``terms_columns``/``terms_cov`` the joint fit's covariance of ``(B, M upper, the terms)``
    with the terms the poses could not fit (:attr:`JointResult.terms_cov`).
    """

    temperature_ref: float
    tempco: np.ndarray
    tempco_std: np.ndarray
    degree: np.ndarray
    t_min: float
    t_max: float
    source: str
    bias_var_extra: np.ndarray
    details: dict = field(default_factory=dict)
    note: str | list[str] | None = None
    model_cov_extra: np.ndarray | None = None
    terms_columns: list | None = None
    terms_cov: np.ndarray | None = None

    def change(self, temperature: np.ndarray) -> np.ndarray:
        """Bias change from ``T_ref`` at each temperature, (N, n) raw units."""
        dt = np.asarray(temperature, float) - self.temperature_ref
        return (dt[:, None] ** np.arange(1, len(self.tempco) + 1)[None, :]) @ self.tempco


def sample_temperature(session: Session) -> np.ndarray | None:
    """The session's temperature per sample, gaps (NaN) filled from the neighbours in time;
    None without readings."""
    t = session.temperature
    if t is None:
        return None
    t = np.asarray(t, float)
    ok = np.isfinite(t)
    if not ok.any():
        return None
    return t if ok.all() else np.interp(session.time, session.time[ok], t[ok])


def still_blocks(session: Session, block_s: float,
                 per_period: int = 1) -> list[tuple[int, int, int]]:  # fmt: skip
    """``(start, stop, still period)`` of blocks of about ``block_s`` in each still period, at
    least ``per_period`` of them in each (shorter then; never under 2 samples)."""
    rate = 1.0 / float(np.median(np.diff(session.time))) if len(session.time) > 1 else 1.0
    n = max(int(round(block_s * rate)), 2)
    out = []
    for k, s in enumerate(session.static_segments()):
        m = min(max((s.stop - s.start) // n, per_period), max((s.stop - s.start) // 2, 1))
        edges = np.linspace(s.start, s.stop, m + 1).astype(int)
        out += [(int(a), int(b), k) for a, b in zip(edges[:-1], edges[1:], strict=True)
                if b - a >= 2]  # fmt: skip
    return out


def _points(session: Session, name: str, block_s: float, per_period: int = 1):
    """Block means of sensor ``name`` with their temperature, noise and still period."""
    data = getattr(session, name)
    temp = sample_temperature(session)
    blocks = still_blocks(session, block_s, per_period)
    if data is None or temp is None or not blocks:
        return None
    values = np.array([data[a:b].mean(axis=0) for a, b, _ in blocks])
    temps = np.array([temp[a:b].mean() for a, b, _ in blocks])
    sigma = np.array([data[a:b].std(axis=0, ddof=1) / np.sqrt(b - a) for a, b, _ in blocks])
    groups = np.array([k for _, _, k in blocks])
    return values, temps, np.maximum(sigma, 1e-12), groups


def _from_fit(fit: TempcoFit, t_ref: float, source: str, extra_var=None) -> TemperatureModel:
    _, tempco = reexpand(fit.tempco, fit.temperature_ref, t_ref)
    n = len(fit.channels)
    details = {"points": fit.n_points,
               "selection": [[build(SelectionRow, **t) for t in c.tests] for c in fit.channels],
               "noise_scale": [c.noise_scale for c in fit.channels],
               "correlation": [c.correlation for c in fit.channels]}  # fmt: skip
    std = fit.tempco_std if abs(t_ref - fit.temperature_ref) < 1e-9 else _moved_std(fit, t_ref)
    return TemperatureModel(t_ref, tempco, std, fit.degree, fit.t_min, fit.t_max, source,
                            np.zeros(n) if extra_var is None else extra_var, details)  # fmt: skip


def _moved_std(fit: TempcoFit, t_ref: float) -> np.ndarray:
    """Standard deviations of the coefficients re-expanded about ``t_ref`` (linear map)."""
    out = np.zeros((fit.K, len(fit.channels)))
    for i, c in enumerate(fit.channels):
        if not c.degree:
            continue
        A = np.zeros((c.degree, c.degree))  # column k: the re-expansion of (T - T_old)^k
        for k in range(1, c.degree + 1):
            unit = np.zeros((k, 1))
            unit[-1] = 1.0
            _, col = reexpand(unit, fit.temperature_ref, t_ref)
            A[:k, k - 1] = col[:, 0]
        out[: c.degree, i] = np.sqrt(np.clip(np.diag(A @ c.tempco_cov @ A.T), 0, None))
    return out


def warmup_models(warmups: list[Session], cfg: Config, t_ref: float) -> dict:
    """Each sensor's model from still warm-up recordings: block means, a level per still
    period and recording, the curve shared, serial correlation allowed for."""
    opt = cfg.temperature
    models = {}
    for name in ("accel", "gyro"):
        pts = [_points(with_segments(w)[0], name, BLOCK_S) for w in warmups]
        if any(p is None for p in pts):
            continue
        values = np.vstack([p[0] for p in pts])
        temps = np.concatenate([p[1] for p in pts])
        sigma = np.vstack([p[2] for p in pts])
        groups = np.concatenate([p[3] + 1000 * i for i, p in enumerate(pts)])
        names = ", ".join(session_name(w) for w in warmups)
        fit = fit_tempco(temps, values, sigma=sigma, groups=groups, max_degree=opt.max_degree,
                         min_span_c=opt.min_span_c, serial=True,
                         what=f"warm-up {names} ({name})")  # fmt: skip
        models[name] = _from_fit(fit, t_ref, f"still warm-up recording(s) {names}")
    if not models:
        raise DesignError("the warm-up recordings have no still periods with temperature "
                          "readings and accelerometer or gyro data")  # fmt: skip
    return models


def _joint_accel(session: Session, cfg: Config, t_ref: float) -> TemperatureModel | None:
    """The accelerometer's model fitted jointly with its gravity-magnitude model."""

    pts = _points(session, "accel", BLOCK_S, JOINT_BLOCKS)
    if pts is None or session.accel.shape[1] != 3:
        return None
    opt = cfg.temperature
    values, temps, sigma, groups = pts
    g = cfg.gravity or session.gravity
    start = fit_gravity(values, g)
    cov = np.array([np.diag(s**2) for s in sigma])
    # the terms the poses cannot fit, carried with a prior (the datasheet's tempco, G0 m/s^2 per g)
    tempco_max = opt.accel_tempco_mg_per_c * G0 / 1000.0
    prior = unfitted_prior(tempco_max, (2, 3))
    joint = fit_gravity_tempco(values, temps, g, (start.bias, start.M), cov_mean=cov,
                               temperature_ref=t_ref, groups=groups, max_degree=opt.max_degree,
                               min_span_c=opt.min_span_c, unfitted_std=prior,
                               tempco_max=tempco_max,
                               what=f"{session_name(session)} (accel)")  # fmt: skip
    details = {"points": len(temps), "selection": [build(SelectionRow, **t) for t in joint.tests],
               "noise_scale": joint.noise_scale, "chi2": joint.chi2, "dof": joint.dof}
    notes = []
    if joint.design_degree < MAX_DEGREE:
        notes.append(_degree_note(joint, len(np.unique(groups)), opt))
        used = opt.accel_tempco_mg_per_c * joint.prior_scale
        details["prior_tempco_mg_per_c"] = [float(v) for v in used]
        details["bias_tempco_std_prior"] = joint.tempco_std_prior.tolist()
        details["prior_degrees"] = list(range(joint.design_degree + 1, MAX_DEGREE + 1))
        wide = [f"{'xyz'[c]} {used[c]:.2g} mg/C" for c in range(3) if joint.prior_scale[c] > 1]
        if wide:
            notes.append(
                "temperature model: the part's fitted linear tempco (" + ", ".join(wide) + ") "
                f"exceeds [temperature] accel_tempco_mg_per_c = {opt.accel_tempco_mg_per_c:g} "
                "mg/C by more than 2 std: the prior of the terms the poses cannot fit was "
                f"widened to the fitted value on {'that axis' if len(wide) == 1 else 'those axes'}"
                "; set the key from your part's datasheet (its largest axis), or record a still "
                "warm-up, which fits the cubic")
    return TemperatureModel(
        t_ref, joint.tempco, joint.tempco_std, joint.degree, joint.t_min, joint.t_max,
        "the session's still periods, jointly with the gravity-magnitude model",
        joint.bias_var_extra, details, notes or None, joint.model_cov_extra,
        joint.terms_columns, joint.terms_cov,
    )  # fmt: skip


def _degree_note(joint, n_poses: int, opt) -> str:
    """Why the joint fit stops below the cubic, by cause: ``[temperature] max_degree`` or the
    number of poses (or their layout), and what carries the rest."""
    d = joint.design_degree
    rest = "the cubic is" if d == MAX_DEGREE - 1 else "the terms above it are"
    prior = (f"{rest} carried in the std from a prior ([temperature] accel_tempco_mg_per_c = "
             f"{opt.accel_tempco_mg_per_c:g} mg/C)")
    if d == opt.max_degree and joint.pose_degree > d:
        return (f"temperature model: degree capped by [temperature] max_degree = "
                f"{opt.max_degree} (the {n_poses} poses would determine degree "
                f"{joint.pose_degree}); {prior}")
    if joint.pose_degree <= d:
        return (f"temperature model: the {n_poses} poses determine at most degree {d} (of "
                f"{MAX_DEGREE}) with the gravity-magnitude model; {prior}: capture more poses "
                "or a still warm-up to fit it")
    return (f"temperature model: the {n_poses} poses' orientations determine at most degree "
            f"{d} (of {MAX_DEGREE}) with the gravity-magnitude model; {prior}: capture poses "
            "on more faces and edges, or a still warm-up, to fit it")


def _joint_gyro(session: Session, cfg: Config, t_ref: float) -> TemperatureModel | None:
    """The gyroscope's model from its still periods (each reads the bias at its temperature)."""
    pts = _points(session, "gyro", BLOCK_S)
    if pts is None:
        return None
    opt = cfg.temperature
    values, temps, sigma, _ = pts
    fit = fit_tempco(temps, values, sigma=sigma, temperature_ref=t_ref,
                     max_degree=opt.max_degree, min_span_c=opt.min_span_c, serial=True,
                     what=f"{session_name(session)} (gyro still periods)")  # fmt: skip
    return _from_fit(fit, t_ref, "the session's still periods (gyro bias read at each "
                     "temperature)", _level_extra(fit))  # fmt: skip


def _level_extra(fit: TempcoFit) -> np.ndarray:
    """What the temperature terms' uncertainty adds to each channel's bias variance at
    ``T_ref`` (n,): the level's variance in the fit minus its variance were the terms known
    (``1 / (C^-1)_00``, the conditional), as the accelerometer's joint fit states it.  The
    gyro solver measures its bias on the same still periods, compensated with the terms: their
    error moves it by ``sum_k dc_k mean((T - T_ref)^k)``, which its own std leaves out."""
    out = np.zeros(len(fit.channels))
    for i, c in enumerate(fit.channels):
        if c.degree and len(c.level) == 1:
            out[i] = max(float(c.cov[0, 0] - 1.0 / np.linalg.inv(c.cov)[0, 0]), 0.0)
    return out


def joint_models(
    session: Session, cfg: Config, t_ref: float, strict: bool
) -> tuple[dict, list[str]]:  # fmt: skip
    """Each sensor's model from the session's own still periods. ``strict`` (``model =
    "on"``): a sensor whose data cannot give one is refused; else it is left without, with a
    note why."""
    models, notes = {}, []
    for name, fit in (("accel", _joint_accel), ("gyro", _joint_gyro)):
        try:
            model = fit(session, cfg, t_ref)
        except DesignError as exc:
            if strict:
                raise
            notes.append(f"no {name} temperature model: {exc}")
            continue
        if model is not None:
            models[name] = model
    return models, notes


def still_span(session: Session) -> float | None:
    """Span of the still periods' mean temperatures, C (None without readings)."""
    temp = sample_temperature(session)
    segs = session.static_segments()
    if temp is None or not segs:
        return None
    t = np.array([temp[s.start : s.stop].mean() for s in segs])
    return float(t.max() - t.min())


def temperature_models(
    session: Session, cfg: Config, warmup: list[Session] | None = None
) -> tuple[dict, str | None]:
    """Decide whether the calibration gets temperature models, and fit them.

    Returns ``(models, note)``: ``models`` per sensor (empty: none), ``note`` why not where a
    user would want to know (readings present but a span too small).

    Raises
    ------
    DesignError
        ``model = "on"`` or ``--warmup`` and the data cannot give a model: no temperature
        readings, or a span under ``min_span_c`` (the message says why).
    """
    opt = cfg.temperature
    where = session_name(session)
    temp = sample_temperature(session)
    if warmup:
        if temp is None:
            raise DesignError(
                f"{where}: records no temperature (/raw/temperature): the bias it measures "
                "cannot be placed on the warm-up's curve; capture it with the temperature field"
            )
        return warmup_models(warmup, cfg, float(np.mean(temp))), None
    if opt.model == "off":
        return {}, None
    span = still_span(session)
    if opt.model == "on":
        if span is None:
            raise DesignError(f"{where}: [temperature] model = \"on\" but the session has no "
                              "temperature readings in its still periods")  # fmt: skip
        segs = session.static_segments()
        check_span(np.array([temp[s.start : s.stop].mean() for s in segs]),
                   f"{where}: [temperature] model = \"on\"", opt.min_span_c)  # fmt: skip
    elif span is None:
        return {}, None
    elif span < opt.min_span_c:
        return {}, (f"no temperature model: the still periods span {span:.1f} C, and a bias "
                    f"model needs at least {opt.min_span_c:g} C")  # fmt: skip
    models, notes = joint_models(session, cfg, float(np.mean(temp)), opt.model == "on")
    return models, "; ".join(notes) or None


def compensate(session: Session, models: dict) -> Session:
    """The session with each modelled sensor's raw data moved to ``T_ref``."""
    temp = sample_temperature(session)
    changes = {}
    for name, model in models.items():
        data = getattr(session, name)
        if data is not None:
            changes[name] = np.asarray(data, float) - model.change(temp)
    return replace(session, **changes)


def given_accel(session: Session, accel: SensorCalibration) -> tuple[Session, SensorCalibration]:
    """An earlier accelerometer calibration (``--accel``) with temperature terms: the session's
    accelerometer data moved to its ``temperature_ref`` and a copy of it without the terms,
    for the gyro solvers that apply it to those data."""

    terms = accel.temperature_terms
    if terms is None or session.accel is None:
        return session, accel
    temp = sample_temperature(session)
    if temp is None:
        raise DesignError(
            f"{session_name(session)}: records no temperature, but the given accelerometer "
            "calibration's bias depends on it (bias_tempco)"
        )
    moved = session.accel - (accel.bias_at(temp) - accel.bias)
    plain = copy_with(accel, temperature_ref=None, bias_tempco=None)
    return replace(session, accel=moved), plain


def widen_accel(sec: SensorCalibration | None, model: TemperatureModel | None) -> None:
    """A gravity-magnitude (9-parameter) accelerometer section fitted to the compensated poses
    takes the temperature terms as known: add what their uncertainty adds to its model
    (``model_cov_extra``, joint minus conditional) to its ``covariance``, which the gyro
    solver propagates into its turns (issue 10.2), and to its ``k_*`` rows' std (the ``b_*``
    rows get theirs in :func:`attach`). Before this, the gyro matrix's intervals through a
    10 -> 40 C ramp covered 92 %, or 81 % with a cubic fixed by within-pose blocks."""
    extra = None if model is None else model.model_cov_extra
    if sec is None or extra is None or sec.variant != "9-parameter" or \
            sec.covariance is None or sec.covariance.values is None:  # fmt: skip
        return
    Ji = model_map(model_to_params, sec.bias, sec.matrix)
    sec.covariance.values = np.asarray(sec.covariance.values, float) + Ji @ extra @ Ji.T
    names = [f"k_{a}" for a in ("x", "y", "z", "xy", "xz", "yz")]
    for row in sec.parameters or []:
        if row.name in names and row.std is not None:
            i = 3 + names.index(row.name)
            row.std = float(np.sqrt(row.std**2 + max(extra[i, i], 0.0)))
    if model.terms_cov is not None and hasattr(sec, "compensation"):
        sec.compensation = _compensation(sec, model, Ji)


def _compensation(sec: SensorCalibration, model: TemperatureModel, Ji: np.ndarray) -> Compensation:
    """The terms' error jointly with the section's ``(B, A)``: each compensated pose is off by
    ``-X(T) dc`` as well as by the calibration's error, and both come from one fit, so the gyro
    solver that reads the poses moves them together
    (:func:`imucal_cli.calibrate.gyro.full.accel_uncertainty`)."""
    C = model.terms_cov
    cross = Ji @ C[:9, 9:]
    full = np.block([[np.asarray(sec.covariance.values, float), cross], [cross.T, C[9:, 9:]]])
    w, V = np.linalg.eigh((full + full.T) / 2)  # the (B, A) block is the solver's, not the fit's
    return Compensation(model.temperature_ref, [tuple(c) for c in model.terms_columns],
                        (V * np.clip(w, 0.0, None)) @ V.T,
                        (float(w.min()), float(w.max())))  # fmt: skip


def attach(sec: SensorCalibration | None, model: TemperatureModel | None) -> None:
    """Write the model into the section: the spec's terms, the diagnostics, parameter rows,
    and bias standard deviations that include the terms' uncertainty."""
    if sec is None or model is None:
        return
    n = sec.bias.shape[0]
    if model.tempco.shape[1] != n:
        return
    sec.temperature_ref = float(model.temperature_ref)
    sec.bias_tempco = np.asarray(model.tempco, float)
    sec.temperature_range_c = [float(model.t_min), float(model.t_max)]
    unit = sec.units_in or "raw units"
    if model.note:
        more = [model.note] if isinstance(model.note, str) else list(model.note)
        sec.notes = [*(sec.notes or []), *more]
    sec.temperature_model = build(
        TemperatureModelRecord, source=model.source, degree=model.degree.tolist(),
        bias_tempco_std=model.tempco_std.tolist(), unit=f"{unit} per C^k",
        range_c=[float(model.t_min), float(model.t_max)], **model.details,
    )  # fmt: skip
    if sec.parameters is None:
        sec.parameters = []
    rows = sec.parameters
    names = channel_names(n)
    for k in range(len(model.tempco)):
        for i in range(n):
            if k < model.degree[i]:
                rows.append(Parameter(f"tc{k + 1}_{names[i]}", float(model.tempco[k, i]),
                                      float(model.tempco_std[k, i]),
                                      f"{unit} {UNITS_PER_C[k + 1]}"))  # fmt: skip
    for row in rows:
        nm = row.name or ""
        if nm.startswith("b_") and nm[2:] in names and row.std is not None:
            i = names.index(nm[2:])
            row.std = float(np.sqrt(row.std ** 2 + model.bias_var_extra[i]))


def _same_unit_once_each(parts: list[Session]) -> None:
    """Refuse a recording given twice (its still periods and turns would count twice: every
    std too small by sqrt(2)); warn when two sessions name different units (``sensor``)."""
    for i, p in enumerate(parts):
        for q in parts[:i]:
            if len(p.time) == len(q.time) and np.array_equal(p.time, q.time) and all(
                    np.array_equal(getattr(p, n), getattr(q, n), equal_nan=True)
                    for n in ("accel", "gyro") if getattr(p, n) is not None):  # fmt: skip
                raise DesignError(f"{session_name(p)}: the same recording as "
                                  f"{session_name(q)}: each session once (its data would count "
                                  "twice)")  # fmt: skip
            a, b = ((s.sensor or "").strip() for s in (q, p))
            if a and b and a.casefold() != b.casefold():
                warnings.warn(f"{session_name(p)} is from '{b}' but {session_name(q)} from "
                              f"'{a}': --with joins sessions of one unit (name both the same "
                              "with label --sensor if they are)", ImucalWarning, stacklevel=3)


def merge_sessions(sessions: list[Session]) -> Session:
    """Several sessions of one unit as one: each segmented (if it was not), then their samples
    and segments one after the other in time. Refused when they differ in channels or units.
    Host arrival times are dropped (each session's clock would need its own estimate)."""
    parts = [with_segments(s)[0] for s in sessions]
    first = parts[0]
    _same_unit_once_each(parts)
    for p in parts[1:]:
        for name in ("accel", "gyro"):
            a, b = getattr(first, name), getattr(p, name)
            if (a is None) != (b is None) or (a is not None and a.shape[1] != b.shape[1]) or \
                    getattr(first, f"{name}_units") != getattr(p, f"{name}_units"):  # fmt: skip
                raise DesignError(f"{session_name(p)}: its {name} data differ from "
                                  f"{session_name(first)}'s (channels or units): not the same "
                                  "unit's sessions")  # fmt: skip
    times, segs, offset, t0 = [], [], 0, 0.0
    for p in parts:
        dt = float(np.median(np.diff(p.time))) if len(p.time) > 1 else 0.01
        times.append(p.time - p.time[0] + t0)
        t0 = float(times[-1][-1]) + max(dt, 1e-3)
        segs += [replace(s, name=f"{len(segs) + i:04d}", start=s.start + offset,
                         stop=s.stop + offset) for i, s in enumerate(p.segments)]  # fmt: skip
        offset += len(p.time)

    def cat(name):
        vals = [getattr(p, name) for p in parts]
        return None if any(v is None for v in vals) else np.concatenate(vals)

    return replace(first, time=np.concatenate(times), accel=cat("accel"), gyro=cat("gyro"),
                   temperature=cat("temperature"), mag=cat("mag"), segments=segs,
                   host_time=None)  # fmt: skip

