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

A unit of several IMUs (a calibration with ``imus``) has its figures per IMU: the reference
IMU's are the lot's parameters as a single IMU's (``sensor`` ``accel``, ...), each other IMU's
are parameters of their own (``imu`` ``imu1``, shown as ``imu1 accel``), with their own
distribution, outliers, Cpk (against the same limits: every IMU is judged by them) and drift
test; they come after the reference's, the IMUs in their names' natural order.

The limits are the ones given (``--limits``), else those the lot's latest calibrations were
judged against.  Everything is read from the sections' packed figures (one row per sensor of
each IMU of a calibration): no calibration JSON is parsed.  The sections of one IMU and sensor
that share a layout (the same figures) are unpacked at once, a matrix with a row per section;
a lot's parameters are columns of the rows that are its units' latest calibrations, in the
order of the units' first calibrations (so that the result does not depend on how the rows
were grouped).
"""

from __future__ import annotations

import json
import math
import re
from collections import Counter, defaultdict
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import select

from imucal_cli.use.limits import ProductLimits, limits_from_dict
from imucal_cli.use.report.history import DRIFT_SIGMAS, compare_with_reference

from .schema import calibrations, sections, units
from .store import Registry, RegistryError

__all__ = ["LOT_FORMAT", "OUTLIER_TEST", "OUTLIER_Z", "cpk", "drop_values", "imu_order", "label",
           "lot_statistics", "outliers"]  # fmt: skip

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


def _read(registry: Registry, lot: str) -> tuple[_Calibrations, list[_Sections]]:
    """The lot's calibrations and their sections (:func:`_unpack`)."""
    in_lot = units.c.lot == lot
    cal_query = (
        select(calibrations.c.id, units.c.serial, calibrations.c.created, calibrations.c.verdict,
               calibrations.c.limits)
        .join(units, units.c.id == calibrations.c.unit_id).where(in_lot)
    )  # fmt: skip
    sec_query = (
        select(sections.c.calibration_id, sections.c.imu, sections.c.sensor, sections.c.basis,
               sections.c.layout, sections.c["values"], sections.c.stds)
        .join(calibrations, calibrations.c.id == sections.c.calibration_id)
        .join(units, units.c.id == calibrations.c.unit_id).where(in_lot)
    )  # fmt: skip
    with registry.read() as conn:
        cals = _Calibrations([], [], [], [], [])
        for row in conn.execute(cal_query):
            for column, value in zip(cals.columns(), row, strict=True):
                column.append(value)
        return cals, _unpack(conn.execute(sec_query), registry)


def _unpack(rows, registry: Registry) -> list[_Sections]:
    """Sections' rows ``(calibration id, imu, sensor, basis, layout JSON, values, stds)``
    grouped by IMU, sensor and layout, each group's packed figures unpacked at once into a
    matrix (rows streamed: nothing is kept per row but what the matrices are made of)."""
    packed: dict[tuple, dict[str, tuple[list, ...]]] = {}  # (imu, sensor) -> layout -> lists
    for index, (cal_id, imu, sensor, basis, layout, vals, stds) in enumerate(rows):
        of_sensor = packed.get((imu, sensor))
        if of_sensor is None:
            of_sensor = packed[(imu, sensor)] = {}
        lists = of_sensor.get(layout)
        if lists is None:
            lists = of_sensor[layout] = ([], [], [], [], [])
        ids, order, bases, blobs, std_blobs = lists
        ids.append(cal_id)
        order.append(index)
        bases.append(basis)
        blobs.append(vals)
        std_blobs.append(stds)
    layouts: dict[str, _Layout] = {}
    groups = []
    for (imu, sensor), of_sensor in packed.items():
        for layout, (ids, order, bases, blobs, std_blobs) in of_sensor.items():
            shape = layouts.get(layout)
            if shape is None:
                shape = layouts[layout] = _Layout(layout)
            width = len(shape.names)
            groups.append(_Sections(imu, sensor, shape, ids, order, bases,
                                    _matrix(blobs, width, registry),
                                    _matrix(std_blobs, width, registry)))  # fmt: skip
    return groups


def _matrix(blobs: list[bytes], width: int, registry: Registry) -> np.ndarray:
    """Packed figures (float64 little-endian, ``width`` each) as a matrix, a row per blob."""
    if any(len(b) != 8 * width for b in blobs):
        raise RegistryError(f"registry {registry.name}: a section's packed figures do not "
                            "match its layout")  # fmt: skip
    return np.frombuffer(b"".join(blobs), "<f8").reshape(len(blobs), width)


class _Layout:
    """A packed section's figure names, units and tracked flags (one per distinct layout)."""

    def __init__(self, text: str) -> None:
        items = json.loads(text)
        self.names = [i[0] for i in items]
        self.units = [i[1] for i in items]
        self.tracked = [bool(i[2]) for i in items]
        self.tracked_at = [j for j, t in enumerate(self.tracked) if t]
        self.tracked_names = [self.names[j] for j in self.tracked_at]


@dataclass(frozen=True)
class _Calibrations:
    """The lot's calibrations, a list per column (in the query's order)."""

    ids: list[int]
    serials: list[str]
    created: list[str]  #: ISO 8601 UTC: they sort as text
    verdicts: list[str | None]
    limits: list[str | None]  #: the product file judged against, JSON

    def columns(self) -> tuple[list, ...]:
        return self.ids, self.serials, self.created, self.verdicts, self.limits

    def by_unit(self) -> tuple[dict[str, int], dict[str, list[int]]]:
        """Each unit's latest calibration ``{serial: index}`` (the units in the order of their
        first calibration) and the calibration ids of each unit calibrated more than once
        ``{serial: [id, ...]}``, oldest first: by ``created``, then by id."""
        order = np.lexsort((np.asarray(self.ids), np.asarray(self.created))).tolist()
        latest: dict[str, int] = {}
        for k in order:
            latest[self.serials[k]] = k  # a later one replaces it, in the first one's place
        again: dict[str, list[int]] = {}
        if len(latest) < len(order):
            counts = Counter(self.serials)
            for k in order:
                if counts[self.serials[k]] > 1:
                    again.setdefault(self.serials[k], []).append(self.ids[k])
        return latest, again


@dataclass(frozen=True)
class _Sections:
    """The sections of one IMU's sensor that share a layout, a row per section."""

    imu: str | None  #: the IMU of a set (None: the reference, or the only IMU)
    sensor: str
    layout: _Layout
    cal_ids: list[int]  #: each section's calibration
    order: list[int]  #: each section's place among the rows the query returned
    bases: list[str]  #: each section's history basis
    values: np.ndarray  #: (rows, figures), NaN for none
    stds: np.ndarray  #: (rows, figures), NaN for none


def lot_statistics(registry: Registry, lot: str, *, limits: ProductLimits | None = None,
                   values: bool = False) -> dict[str, Any]:  # fmt: skip
    """The statistics of lot ``lot`` (see the module notes) as a JSON-ready dict; with
    ``values`` each parameter also lists its ``values`` (one per unit: for the plot).

    Raises
    ------
    RegistryError
        No unit in that lot.
    """
    cals, groups = _read(registry, lot)
    if not cals.ids:
        raise RegistryError(f"registry {registry.name}: no unit in lot {lot!r}")
    latest, again = cals.by_unit()
    limits, limits_note = _limits(limits, [cals.limits[k] for k in latest.values()])
    latest_ids = {serial: cals.ids[k] for serial, k in latest.items()}
    parameters = _distribution(_columns(latest_ids, groups, limits), limits, values)
    verdicts = {"pass": 0, "fail": 0, "not judged": 0}
    for k in latest.values():
        verdicts[cals.verdicts[k] or "not judged"] += 1
    apart: dict[str, list[str]] = defaultdict(list)
    for p in parameters:
        for o in p["outliers"]:
            apart[o["serial"]].append(f"{label(p)} {p['name']} ({o['score']:+.1f})")
    return {
        "format": LOT_FORMAT, "format_version": 1, "lot": lot,
        "units": len(latest), "calibrations": len(cals.ids), "verdicts": verdicts,
        "limits": None if limits is None else limits.to_dict(), "limits_source": limits_note,
        "outlier_test": OUTLIER_TEST,
        "parameters": parameters,
        "units_apart": [{"serial": s, "parameters": apart[s]} for s in sorted(apart)],
        "drift": _drift(again, groups),
    }  # fmt: skip


def _limits(given: ProductLimits | None,
            latest: list[str | None]) -> tuple[ProductLimits | None, str]:  # fmt: skip
    """The limits to judge the lot by, and where they come from; ``latest``: the limits (JSON)
    the units' latest calibrations were judged against."""
    if given is not None:
        return given, given.source
    stored = [text for text in latest if text]
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


def _latest_rows(latest: dict[str, int], groups: list[_Sections]) -> list[tuple]:
    """Per group with a unit's latest calibration: ``(group, rows, serials)``, the rows of
    those sections in the order of ``latest``; the groups in the order the units first have
    them (a unit's sections in the query's order)."""
    rank = {cal_id: r for r, cal_id in enumerate(latest.values())}
    serial_at = list(latest)
    found = []
    for group in groups:
        ranks = np.fromiter((rank.get(c, -1) for c in group.cal_ids), dtype=np.intp,
                            count=len(group.cal_ids))  # fmt: skip
        rows = np.flatnonzero(ranks >= 0)
        if not rows.size:
            continue
        rows = rows[np.argsort(ranks[rows], kind="stable")]
        first = (int(ranks[rows[0]]), group.order[rows[0]])
        found.append((first, group, rows, [serial_at[r] for r in ranks[rows]]))
    found.sort(key=lambda f: f[0])
    return [f[1:] for f in found]


def _columns(latest: dict[str, int], groups: list[_Sections],
             limits: ProductLimits | None) -> dict:  # fmt: skip
    """``{(imu, sensor, name, unit): (serials, values)}`` over the latest calibrations: the
    rows of each layout's matrix that are a unit's latest, a column per figure (gain errors
    added from the sensitivities when the limits give a nominal)."""
    columns: dict[tuple, tuple[list[str], list[np.ndarray]]] = {}
    for group, rows, serials in _latest_rows(latest, groups):
        sensor, layout = group.sensor, group.layout
        matrix = group.values[rows]
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
            who, parts = columns.setdefault((group.imu, sensor, name, unit), ([], []))
            who.extend(serials)
            parts.append(matrix[:, j])
    return {k: (who, np.concatenate(parts)) for k, (who, parts) in columns.items()}


def _distribution(columns: dict, limits: ProductLimits | None, keep: bool) -> list:
    """One entry per (IMU, sensor, figure, unit) of ``columns`` (:func:`_columns`); the other
    IMUs' entries name theirs (``imu``), the reference's do not (as a single IMU's)."""
    out = []
    for (imu, sensor, name, unit), (who, column) in columns.items():
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
        if imu is not None:
            entry = {"imu": imu, **entry}
        lim = _limit_of(limits, sensor, name)
        if lim is not None:
            two = lim.kind.two_sided
            beyond = np.abs(x) > lim.maximum if two else x > lim.maximum
            entry.update(limit={"key": lim.key, "maximum": lim.maximum, "two_sided": two},
                         cpk=cpk(x, lim.maximum, two), beyond_limit=int(beyond.sum()))
        if keep:
            entry["values"] = x.tolist()
        out.append(entry)
    out.sort(key=lambda e: (imu_order(e.get("imu")), SENSOR_ORDER.get(e["sensor"], 9),
                            e["limit"] is None, e["name"]))  # fmt: skip
    return out


SENSOR_ORDER = {"accel": 0, "gyro": 1, "mag": 2}


def imu_order(imu: str | None) -> tuple:
    """Sort key of an IMU: the reference (None) first, then the names in natural order
    (``imu2`` before ``imu10``)."""
    if imu is None:
        return (0,)
    return (1, [(0, int(p), "") if p.isdigit() else (1, 0, p) for p in re.split(r"(\d+)", imu)])


def label(entry: dict[str, Any]) -> str:
    """A parameter's sensor as shown: ``accel``, or ``imu1 accel`` for another IMU of a set."""
    imu = entry.get("imu")
    return entry["sensor"] if imu is None else f"{imu} {entry['sensor']}"


def _limit_of(limits: ProductLimits | None, sensor: str, name: str):
    if limits is None:
        return None
    return next((lim for lim in limits.for_sensor(sensor) if lim.bounds(name)), None)


def _tracked(found: tuple | None) -> dict[str, tuple[float | None, float | None]]:
    """``{name: (value, std)}`` of a section's tracked figures (NaN read as None); ``found``
    is where the section is, ``(group, row)``."""
    if found is None:
        return {}
    group, row = found
    at = group.layout.tracked_at
    values = group.values[row, at].tolist()
    stds = group.stds[row, at].tolist()
    return {n: (_number(v), _number(s))
            for n, v, s in zip(group.layout.tracked_names, values, stds, strict=True)}  # fmt: skip


def _number(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _drift(again: dict[str, list[int]], groups: list[_Sections]) -> dict[str, Any]:
    """The history's drift test on every unit of the lot calibrated more than once (``again``:
    their calibration ids, oldest first)."""
    where = _where({cal_id for ids in again.values() for cal_id in ids}, groups)
    alarms = []
    for serial, ids in again.items():
        drifted = []
        sensors = {s for i in ids for s in where.get(i, {})}
        for imu, sensor in sorted(sensors, key=lambda k: (imu_order(k[0]),
                                                          SENSOR_ORDER.get(k[1], 9))):
            found = [where.get(i, {}).get((imu, sensor)) for i in ids]
            bases = [None if f is None else f[0].bases[f[1]] for f in found]
            tables = [_tracked(f) for f in found]
            for name in dict.fromkeys(n for t in tables for n in t):
                pairs = [t.get(name, (None, None)) for t in tables]
                values = [v for v, _ in pairs]
                if all(v is None for v in values):
                    continue
                result = compare_with_reference(values, [s for _, s in pairs], bases)
                flagged = [z for z, f in zip(result["z"], result["drifted"], strict=True) if f]
                if flagged:
                    worst = max(flagged, key=abs)
                    shown = sensor if imu is None else f"{imu} {sensor}"
                    drifted.append(f"{shown} {name} (z = {worst:+.1f})")
        if drifted:
            alarms.append({"serial": serial, "calibrations": len(ids), "drifted": drifted})
    return {"test": f"change from the reference calibration of the same basis beyond "
                    f"{DRIFT_SIGMAS:g} combined std (imucal report's history)",
            "units_checked": len(again), "alarms": alarms}  # fmt: skip


def _where(cal_ids: set[int], groups: list[_Sections]) -> dict[int, dict[tuple, tuple]]:
    """Where the sections of the calibrations ``cal_ids`` are: ``{id: {(imu, sensor): (group,
    row)}}``."""
    where: dict[int, dict[tuple, tuple]] = defaultdict(dict)
    for group in groups:
        for row, cal_id in enumerate(group.cal_ids):
            if cal_id in cal_ids:
                where[cal_id][(group.imu, group.sensor)] = (group, row)
    return where


def drop_values(stats: dict[str, Any]) -> None:
    """Remove the per-unit ``values`` that :func:`lot_statistics` added for a plot."""
    for p in stats["parameters"]:
        p.pop("values", None)
