"""Number formatting for report tables: significant digits, ``value ± std``, axis names."""

from __future__ import annotations

import math

import numpy as np

MISSING = "—"
"""Shown where a figure is missing."""


def fmt(value: float | None, unit: str | None = None, digits: int = 5) -> str:
    """``value unit`` with ``digits`` significant digits, or a dash when missing."""
    if value is None:
        return MISSING
    return f"{value:.{digits}g}" + (f" {unit}" if unit else "")


def fmt_std(value: float | None, std: float | None, unit: str | None = None) -> str:
    """``value ± std unit`` with as many decimals as the std warrants."""
    if value is None:
        return MISSING
    suffix = f" {unit}" if unit else ""
    if std is None or not math.isfinite(std) or std < 0 or not math.isfinite(value):
        return f"{value:.5g} ± n/a{suffix}"  # also a std a file got wrong (negative, inf)
    if std == 0:
        return f"{value:.5g} ± 0{suffix}"
    scale = max(abs(value), std)
    exponent = 3 * math.floor(math.log10(scale) / 3) if scale < 1e-2 or scale >= 1e6 else 0
    if exponent:
        value, std = value / 10.0**exponent, std / 10.0**exponent
    decimals = _decimals_for(std)
    text = f"{value:.{decimals}f} ± {std:.{decimals}f}"
    return (f"({text})e{exponent}" if exponent else text) + suffix


def fmt_like(value: float | None, std: float | None) -> str:
    """A value with the decimals ``fmt_std`` gives its neighbour ``value ± std`` (aligned
    columns); 6 significant digits without a std or for values shown with an exponent."""
    if value is None:
        return MISSING
    if std is None or std <= 0 or not 1e-2 <= max(abs(value), std) < 1e6:
        return f"{value:.6g}"
    return f"{value:.{_decimals_for(std)}f}"


def _decimals_for(std: float) -> int:
    """Decimals that show a std with one significant digit (two when it starts with a 1)."""
    exponent = math.floor(math.log10(std))
    leading = std / 10**exponent
    decimals = -exponent + (1 if leading < 2 else 0)
    return min(max(decimals, 0), 9)


def fixed(value: float | None, decimals: int, signed: bool = False) -> str:
    if value is None:
        return MISSING
    return f"{value:+.{decimals}f}" if signed else f"{value:.{decimals}f}"


def axis_name(up: list[float] | None) -> str:
    """``+Z``, ``-X``, ``+X+Z`` (a 45-degree edge) when the vector is one of those, else numbers."""
    if not up:
        return MISSING
    vector = np.asarray(up, dtype=float)
    norm = np.linalg.norm(vector)
    if norm == 0:
        return MISSING
    vector = vector / norm
    nonzero = np.abs(vector) > 1e-3
    magnitude = 1 / math.sqrt(nonzero.sum())
    if np.allclose(np.abs(vector[nonzero]), magnitude, atol=2e-3):
        return "".join(
            f"{'+' if c > 0 else '-'}{axis}"
            for axis, c in zip("XYZ", vector, strict=True)
            if abs(c) > 1e-3
        )
    return "[" + ",".join(f"{c:.2f}" for c in vector) + "]"
