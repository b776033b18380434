"""Coverage of the temperature models' intervals, per term (issue 24.6: every fitted term's 95 %
intervals cover the truth 93-97 % of the time).

Two designs, each part a seed of the simulator (its biases a cubic in temperature,
:mod:`imucal_cli.simulate.temperature`), simulated to memory and calibrated with no config:

* ``warm-up``: ``bench live``'s warm-up (``warmup:2 --ramp 5:40``) given with ``--warmup`` to
  the calibration of a qureshi18 session of the same part at 24-26 C
  (:func:`bench.live.simulated`, :func:`bench.live.room`);
* ``ramp``: one qureshi18 session through a 10 -> 40 C warm-up (``--ramp 10:40``), calibrated
  alone (the accelerometer's terms fitted jointly with its gravity-magnitude model, the gyro's
  from its still periods).

Per design, sensor and term (``b``: the bias at the section's ``temperature_ref``; ``tcK``:
``bias_tempco``'s degree-K coefficients, the truth's re-expanded about that reference), over the
three axes (``matrix``: the ramp design's accelerometer ``k_*`` rows of its gravity-magnitude
model, in the solver's gauge, and the gyro's ``m_*`` rows, the truth's in the calibrated
accelerometer's frame, as ``bench live`` grades them: a temperature model whose error no std
states moves the compensated poses both solvers read), how many intervals were stated, the
fraction of ``value +- 1.96 std`` that hold the truth with its 95 % (Wilson) interval, the
three axes of one part counting as fewer independent intervals by the seeds' design effect
(:func:`bench.live_table.design_effect`), and the RMS of ``error / std``. A term the model left
out states no interval. Verdict per term: the coverage's interval reaches into 93-97 % (100
parts cannot tell 92.7 % from 93 %).
"""

from __future__ import annotations

import time
import warnings
from collections import defaultdict
from dataclasses import dataclass

import numpy as np
from rich.console import Console
from rich.table import Table

from bench import live
from bench.live_grade import _gauge, _params, _truth_in_accel_frame
from bench.live_table import design_effect, wilson
from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.estimators.accel.gravity import model_to_params
from imucal_cli.estimators.thermal.temperature import reexpand
from imucal_cli.formats.config import Config
from imucal_cli.simulate.play import simulate_plan
from imucal_cli.simulate.temperature import parse_ramp

__all__ = ["DESIGNS", "Coverage", "Interval", "coverage", "intervals", "run"]

DESIGNS = ("warm-up", "ramp")
#: The ramp design's temperature course.
RAMP = "10:40"
#: The target band of the coverage, %.
BAND = (93.0, 97.0)
WARMUP_PLAN = live.LivePlan("warmup:2", warmup=True, serve=("--ramp", live.WARMUP_RAMP))


@dataclass(frozen=True)
class Interval:
    """One stated interval: ``z`` is ``(value - truth) / std``."""

    design: str
    sensor: str
    term: str
    axis: str
    seed: int
    z: float


def _section(sec, true, design: str, name: str, seed: int) -> list[Interval]:
    """The intervals of one section's bias and temperature terms."""
    if sec is None or sec.temperature_terms is None:
        return []
    ref, tc = sec.temperature_terms
    td = true.to_dict()
    d0, tc_true = reexpand(np.asarray(td["bias_tempco"], float), td["temperature_ref"], ref)
    doc = sec.to_dict()
    rows = {r["name"]: r for r in doc["parameters"]}
    axes = "xyz"[: len(sec.bias)]
    out = [Interval(design, name, "b", a, seed,
                    (rows[f"b_{a}"]["value"] - td["bias"][i] - d0[i]) / rows[f"b_{a}"]["std"])
           for i, a in enumerate(axes)]  # fmt: skip
    std = np.asarray(doc["temperature_model"]["bias_tempco_std"], float)
    for k in range(len(tc)):
        true_k = tc_true[k] if k < len(tc_true) else np.zeros(len(axes))
        out += [Interval(design, name, f"tc{k + 1}", a, seed, (tc[k, i] - true_k[i]) / std[k, i])
                for i, a in enumerate(axes) if std[k, i] > 0]  # fmt: skip
    return out


def _matrices(cal, truth, seed: int) -> list[Interval]:
    """The ramp design's matrix intervals: the accelerometer's ``k_*`` (gravity-magnitude
    model, M upper triangular: the truth in that gauge) and the gyro's ``m_*`` (the truth
    rotated into the calibrated accelerometer's frame)."""
    out = []
    if cal.accel is not None:
        names, value, std, _ = _params(cal.accel)
        if names[3:9] == ["k_x", "k_y", "k_z", "k_xy", "k_xz", "k_yz"]:
            x_true = model_to_params(truth.accel.bias, _gauge(truth.accel.matrix)[0])
            out += [Interval("ramp", "accel", "matrix", names[i], seed,
                             (value[i] - x_true[i]) / std[i]) for i in range(3, 9)]  # fmt: skip
    if cal.gyro is not None:
        names, value, std, _ = _params(cal.gyro)
        if names[3:12] == [f"m_{a}{c}" for a in "xyz" for c in "xyz"]:
            m_true = (_truth_in_accel_frame(cal, truth) @ truth.gyro.matrix).ravel()
            z = (value[3:12] - m_true) / std[3:12]
            out += [Interval("ramp", "gyro", "matrix", names[3 + i], seed, float(z[i]))
                    for i in range(9)]  # fmt: skip
    return out


def intervals(seed: int, designs: tuple[str, ...] = DESIGNS) -> list[Interval]:
    """Every temperature-model interval of one part (seed) in ``designs``."""
    out: list[Interval] = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if "warm-up" in designs:
            warm, truth = live.simulated(WARMUP_PLAN, seed)
            cal = calibrate_session(live.room(seed), Config(), warmup=[warm])
            for name in ("accel", "gyro"):
                out += _section(getattr(cal, name), getattr(truth, name), "warm-up", name, seed)
        if "ramp" in designs:
            session, truth = simulate_plan("qureshi18", seed=seed, temperature=parse_ramp(RAMP))
            cal = calibrate_session(session, Config())
            for name in ("accel", "gyro"):
                out += _section(getattr(cal, name), getattr(truth, name), "ramp", name, seed)
            out += _matrices(cal, truth, seed)
    return out


@dataclass(frozen=True)
class Coverage:
    """One term's figures: ``intervals`` over ``seeds`` parts, ``percent`` of them holding the
    truth, its 95 % interval ``low .. high`` (%, with the design effect ``deff``), ``rms_z``."""

    intervals: int
    seeds: int
    percent: float
    low: float
    high: float
    deff: float
    rms_z: float

    @property
    def ok(self) -> bool:
        """The coverage's interval reaches into :data:`BAND`."""
        return self.high >= BAND[0] and self.low <= BAND[1]


def coverage(found: list[Interval]) -> dict[tuple[str, str, str], Coverage]:
    """Per (design, sensor, term), sorted."""
    groups: dict[tuple[str, str, str], list[Interval]] = defaultdict(list)
    for iv in found:
        groups[(iv.design, iv.sensor, iv.term)].append(iv)
    out = {}
    for key, ivs in sorted(groups.items()):
        z = np.array([iv.z for iv in ivs])
        hits = np.abs(z) <= 1.96
        by_seed: dict[int, list[bool]] = defaultdict(list)
        for iv, hit in zip(ivs, hits, strict=True):
            by_seed[iv.seed].append(bool(hit))
        deff = design_effect([np.array(h) for h in by_seed.values()])
        lo, hi = wilson(hits, deff=deff)
        out[key] = Coverage(len(z), len(by_seed), 100.0 * float(hits.mean()), 100.0 * lo,
                            100.0 * hi, deff, float(np.sqrt(np.mean(z**2))))  # fmt: skip
    return out


def run(console: Console, n_seeds: int = 100) -> bool:
    """The coverage table over seeds ``0 .. n_seeds - 1``; True when every term is in
    :data:`BAND`."""
    t0 = time.perf_counter()
    found: list[Interval] = []
    for seed in range(n_seeds):
        found += intervals(seed)
    table = Table(title=f"temperature models: 95 % intervals per term ({n_seeds} seeds, "
                  f"warm-up {live.WARMUP_RAMP} C with a room session, qureshi18 ramp {RAMP} C)")
    for col in ("design", "sensor", "term", "intervals", "seeds", "coverage [%]",
                "95 % interval [%]", "design effect", "RMS z", ""):  # fmt: skip
        table.add_column(col, justify="right")
    ok = True
    for (design, sensor, term), c in coverage(found).items():
        ok = ok and c.ok
        table.add_row(design, sensor, term, str(c.intervals), str(c.seeds), f"{c.percent:.1f}",
                      f"{c.low:.1f} .. {c.high:.1f}", f"{c.deff:.2f}", f"{c.rms_z:.2f}",
                      "[green]ok[/]" if c.ok else "[red]FAIL[/]")  # fmt: skip
    console.print(table)
    console.print(f"temperature coverage: {time.perf_counter() - t0:.0f} s; "
                  f"{'OK' if ok else 'FAILED'} (every term's coverage interval reaches into "
                  f"{BAND[0]:g}-{BAND[1]:g} %)")  # fmt: skip
    return ok
