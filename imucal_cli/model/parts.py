"""Records several sections share: a fitted parameter, the covariance, the fit statistics, the
solver choice, the bias temperature model, the sample clock and the factorization's fields
(DEVELOPERS.md, "Calibration JSON")."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from .codec import Record, item


@dataclass
class Parameter(Record):
    """A fitted parameter of a section's ``parameters`` table.

    Attributes
    ----------
    name : str
        As the solver names it (``b_x``, ``s_y``, ``gain_3``, ``tc1_z``).
    value : float
    std : float or None
        Standard deviation (None: not determined).
    unit : str
    ci95 : float or None
        Half-width of the 95 % interval (Student t), where the solver gives it.
    status : str or None
        ``"measured"`` (the data determine it) or ``"assumed"`` (held at its prior, within
        the prior's std): written by a fit with a prior (``"solver": "partial"``, issue
        27.3); absent: measured (the solvers that determine the whole model).
    prior_std : float or None
        The prior's std of the parameter, with ``status``.
    """

    name: str = ""
    value: float | None = item(always=True)
    std: float | None = item(always=True)
    unit: str | None = None
    ci95: float | None = None
    status: str | None = None
    prior_std: float | None = None


@dataclass
class Combination(Record):
    """A combination of parameters a design determines although some of its parameters it
    does not: ``sum(terms[name] * parameter) = value +- std``."""

    terms: dict[str, float] | None = None
    value: float | None = None
    std: float | None = None


@dataclass
class Partial(Record):
    """What a design determines of a sensor's model, and what is assumed (issue 27.3; the
    section member ``"partial"``, written only where something is assumed).

    Attributes
    ----------
    rule : str
        When a parameter counts as measured.
    prior : str
        Where the assumed values and their std come from (nominal, or an earlier
        calibration).
    measured, assumed : list of str
        The parameters' names (``parameters``), each in one of the two.
    combinations : list of Combination
        Determined combinations that involve assumed parameters.
    capture : str
        What capture would determine the rest.
    """

    rule: str | None = None
    prior: str | None = None
    measured: list[str] | None = None
    assumed: list[str] | None = None
    combinations: list[Combination] | None = None
    capture: str | None = None


@dataclass
class Covariance(Record):
    """The covariance of the model's terms (``of`` says which, in which order and units)."""

    of: str | None = None
    values: np.ndarray | None = None


class By(StrEnum):
    """Who chose a section's solver: ``auto`` from the session's design, or the config."""

    AUTO = "auto"
    CONFIG = "config"


@dataclass
class Choice(Record):
    """The solver that calibrated a sensor, who chose it, and why (words for the user)."""

    solver: str = ""
    by: By = By.AUTO
    reason: str = ""


@dataclass
class FitStatistics(Record):
    """How an iterative fit went (members of the section itself).

    Attributes
    ----------
    init : str or None
        How it started.
    weighting : str or None
        ``"noise"`` (each equation by its measured noise) or ``"equal"``.
    iterations, function_evaluations : int or None
    converged : bool or None
    message : str or None
    chi2 : float or None
        The weighted sum of squared residuals; ``dof`` its degrees of freedom.
    dof : int or None
    noise_scale : float or None
        ``chi2 / dof``: 1 when the residuals are as the noise predicts.
    """

    init: str | None = None
    weighting: str | None = None
    iterations: int | None = None
    function_evaluations: int | None = None
    converged: bool | None = None
    message: str | None = None
    chi2: float | None = None
    dof: int | None = None
    noise_scale: float | None = None


@dataclass
class SelectionRow(Record):
    """One F-test of the degree of a channel's bias polynomial in temperature; ``alias``: the
    largest fraction of a kept coefficient's variance dropping the term would take off (the
    term is kept above ``ALIAS_MAX``, significant or not)."""

    channel: str | None = None
    degree: int | None = None
    F: float | None = None
    dof: list[float] | None = None
    p_value: float | None = None
    alias: float | None = None
    kept: bool | None = None


@dataclass
class TemperatureModel(Record):
    """How the bias temperature terms were fitted (``temperature_model``).

    Attributes
    ----------
    source : str
        The data (the session's still periods, warm-up recordings).
    degree : list of int
        Degree per channel, chosen by F-tests (``selection``).
    bias_tempco_std : list of list of float
        Standard deviations of ``bias_tempco`` (K x n).
    unit : str
        Of ``bias_tempco``: raw units per C^k.
    range_c : list of float
        ``[min, max]`` temperature fitted, C.
    points : int
        Blocks of still data fitted.
    selection : list
        The F-tests: one list per channel (a polynomial per channel) or one list (the joint
        fit with the gravity-magnitude model).
    noise_scale : float or list of float
        ``chi2 / dof`` (per channel where each has its own fit).
    chi2, dof : float, int
        Of the joint fit.
    correlation : list of float
        Lag-1 autocorrelation of each channel's residuals (allowed for in the std).
    prior_tempco_mg_per_c : list of float
        The joint fit's terms the poses cannot fit are carried from a prior: the linear tempco
        it was drawn for per channel, mg/C (``[temperature] accel_tempco_mg_per_c``, or the
        fitted value where the part exceeds it).
    bias_tempco_std_prior : list of list of float
        The part of ``bias_tempco_std`` that prior gives (K x n; ``std^2 = noise^2 +
        prior^2``).
    prior_degrees : list of int
        The degrees carried from that prior (above what the poses determine).
    """

    source: str | None = None
    degree: list[int] | None = None
    bias_tempco_std: list[list[float]] | None = None
    unit: str | None = None
    range_c: list[float] | None = None
    points: int | None = None
    selection: list[list[SelectionRow]] | list[SelectionRow] | None = None
    noise_scale: float | list[float] | None = None
    chi2: float | None = None
    dof: int | None = None
    correlation: list[float] | None = None
    prior_tempco_mg_per_c: list[float] | None = None
    bias_tempco_std_prior: list[list[float]] | None = None
    prior_degrees: list[int] | None = None


@dataclass
class SampleClock(Record):
    """The device's sample clock measured against the host's arrival times (issue 17.2).

    Attributes
    ----------
    scale, scale_std : float
        Device seconds per true second, and its std.
    ppm, ppm_std : float
        ``(scale - 1) 1e6`` and its std.
    jitter_s, latency_max_s, duration_s : float
        Arrival jitter and the longest latency above the envelope, and the recording's span, s.
    bins, bins_dropped, backlog_reads : int
    correlation : float
    threshold_ppm : float
        Below it the error is not told apart from none.
    significant : bool
    method, basis : str
    applied : bool
        The session's time was corrected by it before the solvers ran.
    corrected : str
        Words for what was done.
    note : str
        Why the clock could not be estimated (then nothing else is given).
    """

    scale: float | None = None
    scale_std: float | None = None
    ppm: float | None = None
    ppm_std: float | None = None
    jitter_s: float | None = None
    latency_max_s: float | None = None
    duration_s: float | None = None
    bins: int | None = None
    bins_dropped: int | None = None
    backlog_reads: int | None = None
    correlation: float | None = None
    threshold_ppm: float | None = None
    significant: bool | None = None
    method: str | None = None
    basis: str | None = None
    applied: bool | None = None
    corrected: str | None = None
    note: str | None = None


@dataclass
class Linear(Record):
    """The factorization's linear solution (before the refinement), in the paper's terms."""

    method: str | None = None
    bias: list[float] | None = None
    sensitivity: list[float] | None = None
    angles_deg: list[list[float]] | None = None
    constraint_rms: float | None = None


@dataclass
class Factorization(Record):
    """Hwangbo & Kanade's factorization of a unit (members of an accel or gyro section).

    Attributes
    ----------
    configuration, case : str
        The unit's configuration and the constraints' case (the paper's Table I).
    elements : int
        Sensing elements (channels).
    angles_deg, angles_std_deg : list of list of float
        Angle between each pair of sensitivity axes (n x n; null on the diagonal's
        undetermined pairs), and its std.
    axis_names : list of str
    constraint_rms : float
        RMS of the constraints' errors (the paper's C_err).
    linear : Linear
    refined : bool
        The nonlinear refinement ran (section IV-C).
    fixture_tolerance_deg : float
    singular_values : list of float
    rotation : str
        How the free rotation was fixed.
    use : str
        ``[accel.factorization] use``.
    constraints : int
    noise_raw : float
        Raw noise per sample.
    """

    configuration: str | None = None
    case: str | None = None
    elements: int | None = None
    angles_deg: list[list[float]] | None = None
    angles_std_deg: list[list[float]] | None = None
    axis_names: list[str] | None = None
    constraint_rms: float | None = None
    linear: Linear | None = None
    refined: bool | None = None
    fixture_tolerance_deg: float | None = None
    singular_values: list[float] | None = None
    rotation: str | None = None
    use: str | None = None
    constraints: int | None = None
    noise_raw: float | None = None


@dataclass
class ImportedFrom(Record):
    """The other tool's file a calibration was read from."""

    format: str | None = None
    file: str | None = None


JSON = Any
"""A JSON value kept as it is (a config or simulator options document)."""
