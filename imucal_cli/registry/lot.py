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
judged against.  Everything is read from the sections' packed figures (one row per sensor of a
calibration): no calibration JSON is parsed.
"""

from __future__ import annotations

import json
from collections import defaultdict
from typing import Any

import numpy as np
from sqlalchemy import select

from imucal_cli.use.limits import ProductLimits, limits_from_dict
from imucal_cli.use.report.history import DRIFT_SIGMAS, compare_with_reference

from .schema import calibrations, sections, units
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


MAD_TO_STD = 1.482602218505602
"""1 / Phi^-1(3/4): the MAD of normal data times this is its std."""


def outliers(values: np.ndarray) -> tuple[np.ndarray, float]:
    """The modified z-score of each value, ``(x - median) / (1.4826 MAD)`` (NaN where the MAD
    is 0), and the normal-scaled MAD (an estimate of the std)."""
    values = np.asarray(values, dtype=float)
    median = float(np.median(values))
    mad = MAD_TO_STD * float(np.median(np.abs(values - median)))
    if not mad > 0:
        return np.full(values.shape, np.nan), mad
    return (values - median) / mad, mad


def _rows(registry: Registry, lot: str) -> tuple[list, dict[int, tuple]]:
    """The sections (figures packed) of the lot's calibrations, and per calibration (serial,
    created, verdict, limits JSON)."""
    in_lot = units.c.lot == lot
    cal_query = (
        select(calibrations.c.id, units.c.serial, calibrations.c.created, calibrations.c.verdict,
               calibrations.c.limits)
        .join(units, units.c.id == calibrations.c.unit_id).where(in_lot)
    )  # fmt: skip
    sec_query = (
        select(sections.c.calibration_id, sections.c.sensor, sections.c.units, sections.c.basis,
               sections.c.layout, sections.c["values"], sections.c.stds)
        .join(calibrations, calibrations.c.id == sections.c.calibration_id)
        .join(units, units.c.id == calibrations.c.unit_id).where(in_lot)
    )  # fmt: skip
    with registry.read() as conn:
        cals = {r[0]: tuple(r[1:]) for r in conn.execute(cal_query)}
        rows = conn.execute(sec_query).all()
    return rows, cals


class _Layout:
    """A packed section's figure names, units and tracked flags (one per distinct layout)."""

    def __init__(self, text: str) -> None:
        items = json.loads(text)
        self.names = [i[0] for i in items]
        self.units = [i[1] for i in items]
        self.tracked = [bool(i[2]) for i in items]


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
    layouts: dict[str, _Layout] = {}
    # per calibration: {sensor: (layout, basis, values, stds)}
    per_cal: dict[int, dict[str, tuple]] = defaultdict(dict)
    for cal_id, sensor, _units, basis, layout, vals, stds in rows:
        shape = layouts.get(layout)
        if shape is None:
            shape = layouts[layout] = _Layout(layout)
        per_cal[cal_id][sensor] = (shape, basis, np.frombuffer(vals, "<f8"),
                                   np.frombuffer(stds, "<f8"))  # fmt: skip
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


def _columns(latest: dict[str, int], per_cal: dict, limits: ProductLimits | None) -> dict:
    """``{(sensor, name, unit): (serials, values)}`` over the latest calibrations: each
    layout's values stacked into a matrix, a column per figure (gain errors added from the
    sensitivities when the limits give a nominal)."""
    groups: dict[tuple, tuple[list[str], list[np.ndarray]]] = {}
    for serial, cal_id in latest.items():
        for sensor, (layout, _basis, vals, _stds) in per_cal.get(cal_id, {}).items():
            serials, rows = groups.setdefault((sensor, id(layout)), ([], []))
            serials.append(serial)
            rows.append(vals)
            groups[(sensor, id(layout))] = (serials, rows)
    by_id = {id(layout): layout for sections in per_cal.values()
             for layout, *_ in sections.values()}  # fmt: skip
    columns: dict[tuple, tuple[list[str], list[np.ndarray]]] = {}
    for (sensor, key), (serials, rows) in groups.items():
        layout = by_id[key]
        matrix = np.vstack(rows)
        names, unit_of = list(layout.names), list(layout.units)
        if limits is not None and sensor in limits.nominal:
            nominal = limits.nominal[sensor]
            sens = [j for j, n in enumerate(names) if n.startswith("sensitivity ")]
            for i, j in enumerate(sens):
                s0 = nominal[0] if len(nominal) == 1 else nominal[min(i, len(nominal) - 1)]
                matrix = np.column_stack([matrix, 100.0 * (matrix[:, j] / s0 - 1.0)])
                names.append("gain error " + names[j][len("sensitivity ") :])
                unit_of.append("%")
        for j, (name, unit) in enumerate(zip(names, unit_of, strict=True)):
            who, parts = columns.setdefault((sensor, name, unit), ([], []))
            who.extend(serials)
            parts.append(matrix[:, j])
    return {k: (who, np.concatenate(parts)) for k, (who, parts) in columns.items()}


def _distribution(latest: dict[str, int], per_cal: dict, limits: ProductLimits | None,
                  keep: bool) -> list:  # fmt: skip
    """One entry per (sensor, figure, unit) over the units' latest calibrations."""
    out = []
    for (sensor, name, unit), (who, column) in _columns(latest, per_cal, limits).items():
        finite = np.isfinite(column)
        if not finite.any():
            continue
        x = column[finite]
        serials = [s for s, f in zip(who, finite, strict=True) if f] if not finite.all() else who
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


def _tracked(section: tuple | None) -> dict[str, tuple[float | None, float | None]]:
    """``{name: (value, std)}`` of a packed section's tracked figures (NaN read as None)."""
    if section is None:
        return {}
    layout, _basis, vals, stds = section
    return {n: (_number(v), _number(s))
            for n, t, v, s in zip(layout.names, layout.tracked, vals, stds, strict=True)
            if t}  # fmt: skip


def _number(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _drift(by_unit: dict[str, list[int]], per_cal: dict) -> dict[str, Any]:
    """The history's drift test on every unit of the lot calibrated more than once."""
    alarms = []
    checked = 0
    order = ("accel", "gyro", "mag")
    for serial, ids in by_unit.items():
        if len(ids) < 2:
            continue
        checked += 1
        drifted = []
        sensors = {s for i in ids for s in per_cal.get(i, {})}
        for sensor in sorted(sensors, key=lambda s: order.index(s) if s in order else 9):
            secs = [per_cal.get(i, {}).get(sensor) for i in ids]
            bases = [None if s is None else s[1] for s in secs]
            tables = [_tracked(s) for s in secs]
            for name in dict.fromkeys(n for t in tables for n in t):
                found = [t.get(name, (None, None)) for t in tables]
                values = [v for v, _ in found]
                if all(v is None for v in values):
                    continue
                result = compare_with_reference(values, [s for _, s in found], bases)
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
