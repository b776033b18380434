"""``imucal registry lot LOT --plot FILE.png``: each parameter's distribution across the lot.

One histogram per parameter (those with a limit first; at most :data:`MAX_PANELS`), the limits
as red lines, the median as a black one, the units that stand apart marked in orange.  Drawn
from :func:`~imucal_cli.registry.lot.lot_statistics` with ``values=True``; nothing is queried.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.output import safe_output
from imucal_cli.use.plots import pyplot

from .lot import label

__all__ = ["MAX_PANELS", "lot_figure"]

MAX_PANELS = 24


def _panels(stats: dict[str, Any]) -> list[dict[str, Any]]:
    """The parameters to draw: limited ones, then biases, sensitivities, misalignments."""
    params = [p for p in stats["parameters"] if p.get("values")]
    limited = [p for p in params if p["limit"] is not None]
    others = [p for p in params if p["limit"] is None and
              p["name"].split(" ")[0].split("_")[0] in ("b", "sensitivity", "misalignment")]
    return (limited + others)[:MAX_PANELS]


def lot_figure(stats: dict[str, Any], path: str | os.PathLike, *, force: bool = False) -> Path:
    """Draw the lot's histograms to a PNG.

    Raises
    ------
    InputError
        matplotlib missing, nothing to draw, or the file cannot be written.
    """
    panels = _panels(stats)
    if not panels:
        raise InputError(f"{path}: nothing to plot: the lot has no parameter with values")
    plt = pyplot()
    cols = min(4, len(panels))
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.0 * rows), squeeze=False,
                             layout="constrained")  # fmt: skip
    for ax, p in zip(axes.flat, panels, strict=False):
        x = np.asarray(p["values"], dtype=float)
        ax.hist(x, bins=min(60, max(8, int(np.sqrt(x.size)))), color="tab:blue", alpha=0.75)
        ax.axvline(p["median"], color="black", lw=1)
        lim = p["limit"]
        if lim is not None:
            for edge in ((-lim["maximum"], lim["maximum"]) if lim["two_sided"]
                         else (lim["maximum"],)):  # fmt: skip
                ax.axvline(edge, color="red", lw=1.5)
        apart = [o["value"] for o in p["outliers"]]
        if apart:
            ax.plot(apart, np.zeros(len(apart)), "v", color="tab:orange", ms=6)
        cpk = "" if p["cpk"] is None else f", Cpk {p['cpk']:.2f}"
        ax.set_title(f"{label(p)} {p['name']}{cpk}", fontsize=9)
        ax.set_xlabel(p["unit"] or "", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(panels):]:
        ax.set_visible(False)
    fig.suptitle(f"lot {stats['lot']}: {stats['units']} units (red: limits, black: median, "
                 "orange: units apart)")  # fmt: skip
    path = Path(path)
    try:
        with safe_output(path, force=force) as out, out.open("wb") as handle:
            fig.savefig(handle, dpi=100, format="png")
    except ValueError as exc:
        raise InputError(f"{path}: cannot write the plot ({exc})") from None
    finally:
        plt.close(fig)
    return path
