"""The calibration of one sensor (a section of the calibration JSON): what every section
holds, and how it applies.

For each sensor present, the calibrated 3-vector in SI units is::

    calibrated = matrix @ (raw - bias)

with ``bias`` (length n) in raw units and ``matrix`` of shape (3, n); optional terms (spec):
a temperature-dependent bias (``temperature_ref``, ``bias_tempco``), the gyro's
g-sensitivity and its sample clock scale. The sensors' own fields are in their subclasses
(:mod:`.accel`, :mod:`.gyro`, :mod:`.mag`, :mod:`.truth`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal_cli.errors import CalibrationFileError

from .codec import Record, encode, item
from .parts import Choice, Covariance, FitStatistics, Parameter, Partial, TemperatureModel

MODEL_EQUATION = "calibrated = matrix @ (raw - bias)"
#: The model equation of a gyro section with g-sensitivity (spec: optional term).
MODEL_EQUATION_G = "calibrated = matrix @ (raw - bias - g_sensitivity @ a)"


@dataclass
class SensorCalibration(Record):
    """Calibration of one sensor: ``calibrated = matrix @ (raw - bias)``.

    Attributes
    ----------
    solver : str
        Name of the solver that produced it, e.g. ``"gravity"``.
    units : str
        Units of the calibrated output: ``"m/s^2"`` (accel), ``"rad/s"`` (gyro), ``"uT"`` or
        ``"local field"`` (mag: hard iron ``bias``, soft iron ``matrix``).
    bias : ndarray, shape (n,)
        Bias in raw units, n >= 3 raw channels.
    matrix : ndarray, shape (3, n)
        Maps bias-free raw channels to the calibrated 3-vector.
    residual_rms : float or None
        RMS of what the solver minimised, in ``units``.
    model : str or None
        The model equation in words.
    units_in : str or None
        The raw units.
    frame : str or None
        The frame the calibrated vector is in.
    variant, gauge : str or None
        The solver's model variant, and how its free terms were fixed.
    sensitivity, sensitivity_std : list of float or None
        Each channel's gain (raw units per output unit, ``sensitivity_unit``) and its std.
    misalignment_deg, misalignment_std_deg : dict or None
        Angle between each pair of sensitivity axes minus 90 deg (``{"xy", "xz", "yz"}``).
    parameters : list of Parameter or None
        What the solver fitted, with std.
    covariance : Covariance or None
    fit : FitStatistics or None
        How the fit went (members of the section).
    temperature_ref : float or None
        Reference temperature of ``bias``, C (with ``bias_tempco``).
    bias_tempco : ndarray, shape (K, n), or None
        The bias's change per C^k (spec).
    temperature_range_c : list of float or None
        ``[min, max]`` temperature the terms were fitted over, C.
    temperature_model : TemperatureModel or None
    g_sensitivity : ndarray, shape (n, 3), or None
        The gyro's response to specific force, raw units per m/s^2 (spec: gyro only).
    g_sensitivity_unit : str or None
    sample_clock_scale : float or None
        Device seconds per true second (spec: gyro only).
    notes, warnings : list of str or None
        What the user should know; ``warnings`` stop a save without ``--force`` unless the
        section lists its ``blocking`` ones (the others are said, not refused).
    blocking : list of str or None
    choice : Choice or None
        Who chose the solver, and why.
    partial : Partial or None
        Which parameters the data measured and which are assumed (a design that cannot fix
        the whole model, issue 27.3); absent: every parameter measured.
    """

    solver: str = ""
    units: str = ""
    bias: np.ndarray = item(factory=lambda: np.zeros(3))
    matrix: np.ndarray = item(factory=lambda: np.eye(3))
    residual_rms: float | None = item(always=True)
    model: str | None = None
    units_in: str | None = None
    frame: str | None = None
    variant: str | None = None
    gauge: str | None = None
    sensitivity: list[float] | None = None
    sensitivity_std: list[float] | None = None
    sensitivity_unit: str | None = None
    misalignment_deg: dict[str, float] | None = None
    misalignment_std_deg: dict[str, float] | None = None
    parameters: list[Parameter] | None = None
    covariance: Covariance | None = None
    fit: FitStatistics | None = item(flat=True)
    temperature_ref: float | None = None
    bias_tempco: np.ndarray | None = None
    temperature_range_c: list[float] | None = None
    temperature_model: TemperatureModel | None = None
    g_sensitivity: np.ndarray | None = None
    g_sensitivity_unit: str | None = None
    sample_clock_scale: float | None = None
    notes: list[str] | None = None
    warnings: list[str] | None = None
    blocking: list[str] | None = None
    choice: Choice | None = None
    partial: Partial | None = None

    def __post_init__(self) -> None:
        self.bias = np.asarray(self.bias, dtype=np.float64)
        self.matrix = np.asarray(self.matrix, dtype=np.float64)
        for name in ("bias_tempco", "g_sensitivity"):
            value = getattr(self, name)
            if value is not None:
                setattr(self, name, np.asarray(value, dtype=np.float64))

    @property
    def g_term(self) -> np.ndarray | None:
        """The g-sensitivity term to apply (n x 3), None when absent or all zero.

        Raises
        ------
        CalibrationFileError
            Present but not n x 3 finite numbers.
        """
        if self.g_sensitivity is None:
            return None
        g = np.asarray(self.g_sensitivity, dtype=np.float64)
        n = self.bias.shape[0]
        if g.shape != (n, 3) or not np.isfinite(g).all():
            raise CalibrationFileError(f"g_sensitivity must be {n} x 3 finite numbers")
        return g if g.any() else None

    @property
    def temperature_terms(self) -> tuple[float, np.ndarray] | None:
        """The optional ``temperature_ref`` (degrees C) and ``bias_tempco`` (K x n, raw units
        per C^k) terms, None when absent (or K = 0).

        Raises
        ------
        CalibrationFileError
            One without the other, or not finite numbers of the right shape.
        """
        ref, tempco = self.temperature_ref, self.bias_tempco
        if ref is None and tempco is None:
            return None
        tempco = None if tempco is None else np.asarray(tempco, dtype=np.float64)
        if ref is None or tempco is None:
            have, miss = ("temperature_ref", "bias_tempco") if tempco is None else (
                "bias_tempco", "temperature_ref")  # fmt: skip
            raise CalibrationFileError(
                f"{have} without {miss}: the temperature model is incomplete")
        n = self.bias.shape[0]
        if not np.isfinite(ref):
            raise CalibrationFileError(f"temperature_ref must be a finite number (C), got {ref!r}")
        if tempco.size == 0:
            return None
        if tempco.ndim != 2 or tempco.shape[1] != n or not np.isfinite(tempco).all():
            raise CalibrationFileError(
                f"bias_tempco must be a list of vectors of {n} finite numbers (one per bias "
                "entry)"
            )
        return float(ref), tempco

    def bias_at(self, temperature: np.ndarray | float | None = None) -> np.ndarray:
        """The bias at each temperature, (N, n) raw units (``bias`` alone, shape (n,), when the
        section has no temperature terms):
        ``bias + sum_k bias_tempco[k-1] (T - temperature_ref)^k``.

        Raises
        ------
        CalibrationFileError
            The section has temperature terms and ``temperature`` is None.
        """
        terms = self.temperature_terms
        if terms is None:
            return self.bias
        if temperature is None:
            raise CalibrationFileError(
                "the calibration holds bias_tempco (a temperature-dependent bias): it needs "
                "the temperature of each sample"
            )
        t_ref, tempco = terms
        dt = np.atleast_1d(np.asarray(temperature, dtype=np.float64)) - t_ref
        return self.bias + (dt[:, None] ** np.arange(1, len(tempco) + 1)) @ tempco

    def apply(
        self, raw: np.ndarray, accel: np.ndarray | None = None,
        temperature: np.ndarray | None = None,
    ) -> np.ndarray:  # fmt: skip
        """Calibrate raw samples.

        Parameters
        ----------
        raw : ndarray, shape (N, n) or (n,)
            Raw channels in raw units.
        accel : ndarray, shape (N, 3) or (3,), optional
            The calibrated accelerometer of the same samples, m/s^2: needed when the section
            holds ``g_sensitivity``, subtracted as ``raw - bias - g_sensitivity @ accel``.
        temperature : ndarray, shape (N,) or float, optional
            Degrees C of each sample: needed when the section holds ``bias_tempco``
            (:meth:`bias_at`); a NaN temperature gives a NaN output.

        Returns
        -------
        ndarray, shape (N, 3) or (3,)
            ``matrix @ (raw - bias [- g_sensitivity @ accel])`` per sample, in ``units``.

        Raises
        ------
        CalibrationFileError
            ``raw`` does not have n channels in its last axis, or the section holds
            ``g_sensitivity`` and ``accel`` is not given, or ``bias_tempco`` and
            ``temperature`` is not given.
        """
        raw = np.asarray(raw, dtype=np.float64)
        n = self.bias.shape[0]
        if raw.ndim not in (1, 2) or raw.shape[-1] != n:
            raise CalibrationFileError(
                f"cannot apply a calibration for {n} raw channels to data of shape {raw.shape}"
            )
        gs = self.g_term
        bias = self.bias
        if self.temperature_terms is not None:
            bias = self.bias_at(temperature)
            if raw.ndim == 1 and len(bias) == 1:
                bias = bias[0]
            elif len(bias) not in (1, raw.shape[0]) or raw.ndim == 1:
                raise CalibrationFileError(f"{len(bias)} temperatures for {len(raw)} samples")
        if gs is None:
            return (raw - bias) @ self.matrix.T
        if accel is None:
            raise CalibrationFileError(
                "the gyro calibration holds g_sensitivity: it needs the calibrated "
                "accelerometer of the same samples"
            )
        return (raw - bias - np.asarray(accel, dtype=np.float64) @ gs.T) @ self.matrix.T

    def to_dict(self) -> dict:
        """The section's JSON object."""
        return encode(self)
