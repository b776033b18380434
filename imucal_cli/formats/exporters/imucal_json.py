"""Compact JSON: the standard fields of the calibration format only (``format``,
``format_version``, ``session``, ``created``; per sensor ``solver``, ``units``, ``bias``,
``matrix``, ``residual_rms``) plus ``model`` per sensor, on one line with a fixed key order,
for scripts.  It reads back with :func:`imucal_cli.formats.calibration.calibration_from_json`.
"""

from __future__ import annotations

import json
import math

from imucal_cli.formats.exporters import all_sections
from imucal_cli.model.calibration import FORMAT, FORMAT_VERSION, MODEL_EQUATION, Calibration
from imucal_cli.model.codec import jsonable

__all__ = ["OPTIONAL_TERMS", "export_json"]

#: The formats page's optional terms: a reader must apply them or refuse the file.
OPTIONAL_TERMS = ("temperature_ref", "bias_tempco", "g_sensitivity", "sample_clock_scale")


def _finite_or_none(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def export_json(cal: Calibration) -> str:
    """Return the standard fields of the calibration as compact JSON on one line (plus ``\\n``).

    Keys in a fixed order: ``format``, ``format_version``, ``session`` (when known),
    ``created``, then ``accel``/``gyro``/``mag`` each with ``solver``, ``units``, ``model``,
    ``bias``, ``matrix``, ``residual_rms``, and the optional terms present
    (:data:`OPTIONAL_TERMS`).
    Numbers are written so that they read back bit for bit.
    """
    doc: dict = {"format": FORMAT, "format_version": FORMAT_VERSION}
    if cal.session is not None:
        doc["session"] = cal.session
    doc["created"] = cal.created
    for name, sec in all_sections(cal):
        doc[name] = {
            "solver": sec.solver,
            "units": sec.units,
            "model": MODEL_EQUATION,
            "bias": [float(v) for v in sec.bias],
            "matrix": [[float(v) for v in row] for row in sec.matrix],
            "residual_rms": _finite_or_none(sec.residual_rms),
        }
        for key in OPTIONAL_TERMS:  # the formats page's optional terms, applied before matrix
            if getattr(sec, key) is not None:
                doc[name][key] = jsonable(getattr(sec, key))
    return json.dumps(doc, separators=(",", ":"), allow_nan=False) + "\n"
