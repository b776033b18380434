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
three axes: how many intervals were stated, the fraction of ``value +- 1.96 std`` that hold the
truth, and the RMS of ``error / std``. A term the model left out states no interval.
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
from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.estimators.thermal.temperature import reexpand
from imucal_cli.formats.config import Config
from imucal_cli.simulate.play import simulate_plan
from imucal_cli.simulate.temperature import parse_ramp

__all__ = ["DESIGNS", "Interval", "coverage", "intervals", "run"]

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
    return out


def coverage(found: list[Interval]) -> dict[tuple[str, str, str], tuple[int, int, float, float]]:
    """Per (design, sensor, term): ``(intervals, seeds, coverage %, RMS z)``."""
    groups: dict[tuple[str, str, str], list[Interval]] = defaultdict(list)
    for iv in found:
        groups[(iv.design, iv.sensor, iv.term)].append(iv)
    out = {}
    for key, ivs in sorted(groups.items()):
        z = np.array([iv.z for iv in ivs])
        out[key] = (len(z), len({iv.seed for iv in ivs}), 100.0 * float(np.mean(np.abs(z) <= 1.96)),
                    float(np.sqrt(np.mean(z**2))))  # fmt: skip
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
    for col in ("design", "sensor", "term", "intervals", "seeds", "coverage [%]", "RMS z", ""):
        table.add_column(col, justify="right")
    ok = True
    for (design, sensor, term), (n, s, cov, rms) in coverage(found).items():
        good = BAND[0] <= cov <= BAND[1]
        ok = ok and good
        table.add_row(design, sensor, term, str(n), str(s), f"{cov:.1f}", f"{rms:.2f}",
                      "[green]ok[/]" if good else "[red]FAIL[/]")  # fmt: skip
    console.print(table)
    console.print(f"temperature coverage: {time.perf_counter() - t0:.0f} s; "
                  f"{'OK' if ok else 'FAILED'} (every term {BAND[0]:g}-{BAND[1]:g} %)")
    return ok
