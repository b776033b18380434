"""The virtual IMU's temperature: a ramp through the session and a bias that follows it.

A MEMS part's biases move with its temperature: tens of milli-g and tenths of a degree per
second over a warm-up for the consumer parts the toolkit is for. :func:`thermal_part` gives a
simulated part (:mod:`imucal_cli.simulate.sensor`) a bias polynomial per channel about
:data:`T_REF` (the truth's ``temperature_ref`` and ``bias_tempco``), drawn from the seed's own
generator (``SeedSequence(seed, spawn_key=(7,))``), so that the same seed is the same part
with or without a ramp (the other draws are untouched). A :class:`Ramp` is the temperature's
course through the session: a cold start warming up (exponential approach, as a board warms
after power-on) or a linear ramp (a hair dryer, a climatic chamber); the recorded reading is
the true temperature plus the sensor's noise, rounded to its resolution.

Figures (per channel, uniform draws): accelerometer linear term up to
:data:`ACCEL_MG_PER_C` mg/C (MPU-6050 datasheet: 0.35 mg/C x, y, 0.75 mg/C z), gyroscope up to
:data:`GYRO_DPS_PER_C` deg/s per C; a quadratic term up to 1/50 of the linear one per C and a
cubic up to 1/2500 of it per C^2 (over +-15 C: about 30 % and 10 % of the linear change).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from imucal_cli.errors import InputError

from .sensor import ACCEL_LSB_PER_G, G0, GYRO_LSB_PER_DPS, Imu

__all__ = ["ACCEL_MG_PER_C", "GYRO_DPS_PER_C", "T_REF", "Ramp", "parse_ramp", "ramp_part",
           "temperatures", "thermal_part"]  # fmt: skip

T_REF = 25.0
"""Reference temperature of the simulated part's bias polynomials, degrees C."""
ACCEL_MG_PER_C = 0.5
"""Largest linear accelerometer bias coefficient, mg per C."""
GYRO_DPS_PER_C = 0.03
"""Largest linear gyroscope bias coefficient, deg/s per C."""
#: Spawn key of the temperature generator below the simulation's seed.
SPAWN_KEY = 7


@dataclass(frozen=True)
class Ramp:
    """The part's temperature through a session.

    Attributes
    ----------
    start_c, end_c : float
        Temperature at the first and the last sample, degrees C.
    shape : {"warmup", "linear"}
        ``warmup``: ``start + (end - start) (1 - exp(-3 t/D)) / (1 - exp(-3))`` over the
        session's duration ``D`` (most of the change early, as after a cold start);
        ``linear``: a constant rate.
    noise_c : float
        White noise of the recorded reading, degrees C.
    resolution_c : float
        The reading is rounded to this, degrees C.
    """

    start_c: float
    end_c: float
    shape: str = "warmup"
    noise_c: float = 0.02
    resolution_c: float = 0.01

    def true_c(self, time: np.ndarray) -> np.ndarray:
        """The true temperature at each time (s from the first sample), degrees C."""
        t = np.asarray(time, float) - float(time[0])
        x = t / max(float(t[-1]), 1e-9)
        if self.shape == "linear":
            f = x
        else:
            f = (1.0 - np.exp(-3.0 * x)) / (1.0 - np.exp(-3.0))
        return self.start_c + (self.end_c - self.start_c) * f

    def reading_c(self, true_c: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The recorded temperature: true plus noise, rounded to the resolution."""
        value = true_c + self.noise_c * rng.standard_normal(len(true_c))
        return np.round(value / self.resolution_c) * self.resolution_c

    def options(self) -> dict:
        return {"start_c": self.start_c, "end_c": self.end_c, "shape": self.shape,
                "noise_c": self.noise_c, "resolution_c": self.resolution_c}  # fmt: skip


def parse_ramp(text: str) -> Ramp:
    """``FROM:TO`` or ``FROM:TO:linear`` (degrees C) as a :class:`Ramp` (``--ramp``).

    Raises
    ------
    InputError
        Not two numbers, equal ends, or an unknown shape.
    """
    parts = str(text).split(":")
    shape = parts.pop() if len(parts) == 3 else "warmup"
    try:
        start, end = (float(p) for p in parts)
    except ValueError:
        raise InputError(f"--ramp {text!r}: give FROM:TO in degrees C (e.g. 5:45), "
                         "optionally :linear") from None  # fmt: skip
    if shape not in ("warmup", "linear"):
        raise InputError(f"--ramp {text!r}: the shape is warmup or linear, not {shape!r}")
    if not (np.isfinite(start) and np.isfinite(end)) or start == end:
        raise InputError(f"--ramp {text!r}: FROM and TO must be different numbers")
    if not (-60 <= min(start, end) and max(start, end) <= 125):
        raise InputError(f"--ramp {text!r}: outside -60 .. 125 C")
    return Ramp(start, end, shape)


def _draw(rng: np.random.Generator, linear_max: float, n: int) -> np.ndarray:
    """Coefficients (3, n) of degrees 1-3 about T_REF: linear up to ``linear_max``."""
    c1 = rng.uniform(-linear_max, linear_max, n)
    c2 = rng.uniform(-1.0, 1.0, n) * linear_max / 50.0
    c3 = rng.uniform(-1.0, 1.0, n) * linear_max / 2500.0
    return np.vstack([c1, c2, c3])


def thermal_part(imu: Imu, seed: int) -> Imu:
    """``imu`` with bias temperature coefficients on its accelerometer and gyroscope.

    Drawn from ``SeedSequence(seed, spawn_key=(7,))``: accelerometer first, then gyroscope,
    always in that order, in raw units (counts, or SI for a part of nominal gain 1).
    """
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(SPAWN_KEY,)))
    counts = imu.quantise
    per = {  # raw units per (mg, deg/s)
        "accel": (ACCEL_LSB_PER_G / 1000.0) if counts else G0 / 1000.0,
        "gyro": GYRO_LSB_PER_DPS if counts else np.pi / 180.0,
    }
    linear = {"accel": ACCEL_MG_PER_C, "gyro": GYRO_DPS_PER_C}
    draws = {name: _draw(rng, linear[name] * per[name], 3) for name in ("accel", "gyro")}
    groups = tuple(
        replace(g, tempco=draws[g.name], temperature_ref=T_REF) if g.name in draws else g
        for g in imu.groups
    )
    return replace(imu, groups=groups)


def temperatures(
    ramp: Ramp, time: np.ndarray, seed: int
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The true temperature of every sample and the reading recorded, (N,) each; the reading's
    noise comes from ``SeedSequence(seed, spawn_key=(7, 1))``."""
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(SPAWN_KEY, 1)))
    true_c = ramp.true_c(time)
    return true_c, ramp.reading_c(true_c, rng)


def ramp_part(
    imu: Imu, ramp: Ramp | None, time: np.ndarray, opt: dict
) -> tuple[Imu, tuple[np.ndarray, np.ndarray] | None]:  # fmt: skip
    """A simulator's part through ``ramp`` (None: as it is, no temperature): the part with its
    bias polynomials (:func:`thermal_part`) and the true and recorded temperature at ``time``
    (:func:`temperatures`); the ramp goes into the simulator's options ``opt`` (``seed``)."""
    if ramp is None:
        return imu, None
    opt["temperature"] = ramp.options()
    return thermal_part(imu, opt["seed"]), temperatures(ramp, time, opt["seed"])
