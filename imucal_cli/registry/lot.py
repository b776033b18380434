"""``imucal registry lot LOT``: a lot's statistics (issue 29.4).

For every figure the registry keeps (the history's tracked parameters and the acceptance
figures; gain errors when the limits give a nominal sensitivity), over the latest calibration of
each unit of the lot:

- its distribution: n, mean, std, median, MAD, min, max (and ``--plot``: a histogram each);
- the process capability against the product's limit on it (Cpk, Montgomery's *Introduction to
  Statistical Quality Control*: ``min(USL - mean, mean - LSL) / (3 std)`` for a two-sided
  spec ``-max..max``, ``(USL - mean) / (3 std)`` for an upper limit alone), and how many units
  are beyond it;
- the units that stand apart from their lot: Iglewicz & Hoaglin's modified z-score,
  ``|x - median| / (1.4826 MAD) > 3.5`` (:data:`OUTLIER_Z`): median and MAD are not moved by
  the outliers themselves, as a mean and std would be;
- the drift alarm: every unit calibrated more than once, each tracked parameter compared with
  its reference calibration of the same basis by :func:`~imucal_cli.use.report.history.
  compare_with_reference`, the test of ``imucal report A B`` (a change beyond
  :data:`~imucal_cli.use.report.history.DRIFT_SIGMAS` combined std); accel, gyro and mag.

The limits are the ones given (``--limits``), else those the lot's latest calibrations were
judged against.  Everything is read from the ``figures`` rows: no calibration JSON is parsed.
"""

from __future__ import annotations

import json
from collections import defaultdict
from typing import Any

import numpy as np
from scipy.stats import median_abs_deviation
from sqlalchemy import select

from imucal_cli.use.limits import ProductLimits, gain_error_rows, limits_from_dict
from imucal_cli.use.report.history import DRIFT_SIGMAS, compare_with_reference

from .schema import calibrations, figures, sections, units
from .store import Registry, RegistryError

__all__ = ["LOT_FORMAT", "OUTLIER_TEST", "OUTLIER_Z", "cpk", "drop_values", "lot_statistics",
           "outliers"]

LOT_FORMAT = "imucal-registry-lot"
OUTLIER_Z = 3.5
"""Iglewicz & Hoaglin's cut for the modified z-score."""
OUTLIER_TEST = (
    f"modified z-score |x - median| / (1.4826 MAD) > {OUTLIER_Z:g} (Iglewicz & Hoaglin, 1993)"
)


def cpk(values: np.ndarray, maximum: float, two_sided: bool) -> float | None:
    """Process capability of ``values`` against ``-maximum..maximum`` (two-sided) or
    ``..maximum``; None with fewer than 2 values or no spread."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if values.size < 2:
        return None
    mean, std = float(values.mean()), float(values.std(ddof=1))
    if std <= 0:
        return None
    upper = (maximum - mean) / (3 * std)
    return min(upper, (mean + maximum) / (3 * std)) if two_sided else upper


def outliers(values: np.ndarray) -> tuple[np.ndarray, float]:
    """The modified z-score of each value (NaN where the MAD is 0) and the MAD (normal-scaled:
    an estimate of the std)."""
    values = np.asarray(values, dtype=float)
    mad = float(median_abs_deviation(values, scale="normal", nan_policy="omit"))
    if not mad > 0:
        return np.full(values.shape, np.nan), mad
    return (values - np.nanmedian(values)) / mad, mad


def _rows(registry: Registry, lot: str) -> tuple[list, dict[int, tuple]]:
    """Every figure row of the lot's calibrations, and per calibration (serial, created,
    verdict, limits JSON)."""
    cal_query = (
        select(calibrations.c.id, units.c.serial, calibrations.c.created, calibrations.c.verdict,
               calibrations.c.limits)
        .join(units, units.c.id == calibrations.c.unit_id).where(units.c.lot == lot)
    )  # fmt: skip
    fig_query = (
        select(sections.c.calibration_id, sections.c.sensor, sections.c.units,
               sections.c.basis, figures.c.name, figures.c.unit, figures.c.value,
               figures.c.std, figures.c.tracked)
        .join(sections, sections.c.id == figures.c.section_id)
        .join(calibrations, calibrations.c.id == sections.c.calibration_id)
        .join(units, units.c.id == calibrations.c.unit_id)
        .where(units.c.lot == lot)
    )  # fmt: skip
    with registry.read() as conn:
        cals = {r[0]: tuple(r[1:]) for r in conn.execute(cal_query)}
        rows = conn.execute(fig_query).all()
    return rows, cals


def lot_statistics(registry: Registry, lot: str, *, limits: ProductLimits | None = None,
                   values: bool = False) -> dict[str, Any]:  # fmt: skip
    """The statistics of lot ``lot`` (see the module notes) as a JSON-ready dict; with
    ``values`` each parameter also lists its ``values`` (one per unit: for the plot).

    Raises
    ------
    RegistryError
        No unit in that lot.
    """
    rows, cals = _rows(registry, lot)
    if not cals:
        raise RegistryError(f"registry {registry.name}: no unit in lot {lot!r}")
    # per calibration: {sensor: {"units", "basis", "rows": [...]}}
    per_cal: dict[int, dict[str, dict[str, Any]]] = defaultdict(dict)
    for cal_id, sensor, sec_units, basis, name, unit, value, std, tracked in rows:
        sec = per_cal[cal_id].get(sensor)
        if sec is None:
            sec = per_cal[cal_id][sensor] = {"units": sec_units, "basis": basis, "rows": []}
        sec["rows"].append({"name": name, "unit": unit, "value": value, "std": std,
                            "tracked": bool(tracked)})  # fmt: skip
    by_unit: dict[str, list[int]] = defaultdict(list)
    for cal_id, (serial, _created, _verdict, _stored) in sorted(
        cals.items(), key=lambda kv: (kv[1][1], kv[0])
    ):
        by_unit[serial].append(cal_id)
    latest = {serial: ids[-1] for serial, ids in by_unit.items()}
    limits, limits_note = _limits(limits, [cals[i] for i in latest.values()])
    parameters = _distribution(latest, per_cal, limits, values)
    verdicts = {"pass": 0, "fail": 0, "not judged": 0}
    for cal_id in latest.values():
        verdicts[cals[cal_id][2] or "not judged"] += 1
    apart: dict[str, list[str]] = defaultdict(list)
    for p in parameters:
        for o in p["outliers"]:
            apart[o["serial"]].append(f"{p['sensor']} {p['name']} ({o['score']:+.1f})")
    return {
        "format": LOT_FORMAT, "format_version": 1, "lot": lot,
        "units": len(by_unit), "calibrations": len(cals), "verdicts": verdicts,
        "limits": None if limits is None else limits.to_dict(), "limits_source": limits_note,
        "outlier_test": OUTLIER_TEST,
        "parameters": parameters,
        "units_apart": [{"serial": s, "parameters": apart[s]} for s in sorted(apart)],
        "drift": _drift(by_unit, per_cal),
    }  # fmt: skip


def _limits(given: ProductLimits | None, latest: list[tuple]) -> tuple[ProductLimits | None, str]:
    """The limits to judge the lot by, and where they come from."""
    if given is not None:
        return given, given.source
    stored = [meta[3] for meta in latest if meta[3]]
    if not stored:
        return None, "none (no --limits, and no unit of the lot was judged)"
    counts: dict[str, int] = defaultdict(int)
    for text in stored:
        counts[text] += 1
    text = max(counts, key=lambda t: counts[t])
    note = "recorded with the lot's calibrations"
    if len(counts) > 1:
        note += f" (the most common of {len(counts)} different product files)"
    return limits_from_dict(json.loads(text), "registry"), note


def _distribution(latest: dict[str, int], per_cal: dict, limits: ProductLimits | None,
                  keep: bool) -> list:  # fmt: skip
    """One entry per (sensor, figure, unit) over the units' latest calibrations."""
    values: dict[tuple, list[tuple[str, float]]] = defaultdict(list)
    for serial, cal_id in latest.items():
        for sensor, sec in per_cal.get(cal_id, {}).items():
            rows = sec["rows"]
            if limits is not None and sensor in limits.nominal:
                rows = rows + gain_error_rows(rows, limits.nominal[sensor])
            for r in rows:
                if r["value"] is not None and np.isfinite(r["value"]):
                    values[(sensor, r["name"], r["unit"])].append((serial, float(r["value"])))
    out = []
    for (sensor, name, unit), pairs in values.items():
        serials = [s for s, _ in pairs]
        x = np.array([v for _, v in pairs])
        z, mad = outliers(x)
        apart = np.flatnonzero(np.abs(z) > OUTLIER_Z)
        entry = {
            "sensor": sensor, "name": name, "unit": unit, "n": int(x.size),
            "mean": float(x.mean()), "std": float(x.std(ddof=1)) if x.size > 1 else None,
            "median": float(np.median(x)), "mad": mad, "min": float(x.min()),
            "max": float(x.max()),
            "outliers": [{"serial": serials[i], "value": float(x[i]), "score": float(z[i])}
                         for i in apart[np.argsort(-np.abs(z[apart]))]],
            "limit": None, "cpk": None, "beyond_limit": None,
        }  # fmt: skip
        lim = _limit_of(limits, sensor, name)
        if lim is not None:
            two = lim.kind.two_sided
            beyond = np.abs(x) > lim.maximum if two else x > lim.maximum
            entry.update(limit={"key": lim.key, "maximum": lim.maximum, "two_sided": two},
                         cpk=cpk(x, lim.maximum, two), beyond_limit=int(beyond.sum()))
        if keep:
            entry["values"] = x.tolist()
        out.append(entry)
    order = {"accel": 0, "gyro": 1, "mag": 2}
    out.sort(key=lambda e: (order.get(e["sensor"], 9), e["limit"] is None, e["name"]))
    return out


def _limit_of(limits: ProductLimits | None, sensor: str, name: str):
    if limits is None:
        return None
    return next((lim for lim in limits.for_sensor(sensor) if lim.bounds(name)), None)


def _drift(by_unit: dict[str, list[int]], per_cal: dict) -> dict[str, Any]:
    """The history's drift test on every unit of the lot calibrated more than once."""
    alarms = []
    checked = 0
    for serial, ids in by_unit.items():
        if len(ids) < 2:
            continue
        checked += 1
        drifted = []
        sensors = {s for i in ids for s in per_cal.get(i, {})}
        for sensor in sorted(sensors, key=lambda s: ("accel", "gyro", "mag").index(s)):
            secs = [per_cal.get(i, {}).get(sensor) for i in ids]
            bases = [None if s is None else s["basis"] for s in secs]
            tables = [{} if s is None else {r["name"]: r for r in s["rows"] if r["tracked"]}
                      for s in secs]  # fmt: skip
            names = list(dict.fromkeys(n for t in tables for n in t))
            for name in names:
                found = [t.get(name) for t in tables]
                values = [None if r is None else r["value"] for r in found]
                stds = [None if r is None else r["std"] for r in found]
                if all(v is None for v in values):
                    continue
                result = compare_with_reference(values, stds, bases)
                flagged = [z for z, f in zip(result["z"], result["drifted"], strict=True) if f]
                if flagged:
                    worst = max(flagged, key=abs)
                    drifted.append(f"{sensor} {name} (z = {worst:+.1f})")
        if drifted:
            alarms.append({"serial": serial, "calibrations": len(ids), "drifted": drifted})
    return {"test": f"change from the reference calibration of the same basis beyond "
                    f"{DRIFT_SIGMAS:g} combined std (imucal report's history)",
            "units_checked": checked, "alarms": alarms}  # fmt: skip


def drop_values(stats: dict[str, Any]) -> None:
    """Remove the per-unit ``values`` that :func:`lot_statistics` added for a plot."""
    for p in stats["parameters"]:
        p.pop("values", None)
