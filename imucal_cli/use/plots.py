"""Figures (PNG) for ``imucal report --plot`` and ``imucal noise --plot``.

matplotlib is an optional extra (``pip install 'imucal-cli[plot]'``): it is imported only when a
figure is drawn, with the non-interactive ``Agg`` backend; without it the plot functions raise
:class:`~imucal_cli.errors.InputError` with :data:`PLOT_HINT`.

The report figure is drawn from the report dict (:func:`imucal_cli.use.report.build_report`), so
it shows what the calibration stores and nothing is re-solved.  Only panels whose data exist
are drawn:

(a) |a| per pose before and after calibration with the gravity line (as Qureshi &
    Golnaraghi's Fig. 5);
(b) the residual of each pose and its held-out (leave-one-pose-out) residual, mg;
(c) per rotation of a gyroscope section, the angle error, degrees;
(d) the measured gravity directions on the unit sphere.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.output import safe_output

__all__ = ["PLOT_HINT", "draw_report", "noise_figure", "pyplot", "report_figure"]

PLOT_HINT = "plots need matplotlib: pip install 'imucal-cli[plot]'"


def pyplot():
    """matplotlib.pyplot on the Agg backend, or the one-line hint."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise InputError(PLOT_HINT) from None
    return plt


def _save(fig, path: str | os.PathLike[str], force: bool = False, inputs=()) -> Path:
    """Write the figure as PNG through the safe-output helper (see formats/output.py)."""
    path = Path(path)
    try:
        with safe_output(path, force=force, inputs=inputs) as out, out.open("wb") as handle:
            fig.savefig(handle, dpi=110, format="png")
    except ValueError as exc:
        raise InputError(f"{path}: cannot write the plot ({exc})") from None
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)
    return path


def _pose_names(poses: list[dict[str, Any]]) -> list[str]:
    return [p["label"] or p["segment"] or str(i) for i, p in enumerate(poses)]


def _magnitude_panel(ax, section: dict[str, Any]) -> None:
    poses = section["poses"]
    x = np.arange(len(poses))
    before = np.array([np.nan if p["magnitude_before"] is None else p["magnitude_before"]
                       for p in poses])  # fmt: skip
    after = np.array([np.nan if p["magnitude_after"] is None else p["magnitude_after"]
                      for p in poses])  # fmt: skip
    unit = section["units_out"]
    if not np.all(np.isnan(before)):  # solvers without a "before" figure draw no empty series
        ax.plot(x, before, "o", color="tab:red", label="before calibration")
    if not np.all(np.isnan(after)):
        ax.plot(x, after, "s", color="tab:blue", label="after calibration")
    if section["gravity"]:
        g = section["gravity"]["value"]
        ax.axhline(g, color="black", lw=1, ls="--", label=f"g = {g:.5g} {unit}")
        _include(ax, g, np.concatenate([before, after]))
    rms = section["rms"]
    title = "|a| per pose"
    if rms["before_mg"] is not None and rms["after_mg"] is not None:
        title += f": RMS {rms['before_mg']:.3g} -> {rms['after_mg']:.3g} mg"
    elif rms["after_mg"] is not None:
        title += f": RMS {rms['after_mg']:.3g} mg"
    ax.set_title(title)
    ax.set_xlabel("pose")
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.set_ylabel(f"|a|  [{unit}]")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)


def _include(ax, g: float, values: np.ndarray) -> None:
    """Y limits that show the g line with the points (axhline does not autoscale)."""
    finite = values[np.isfinite(values)]
    lo, hi = min(float(finite.min(initial=g)), g), max(float(finite.max(initial=g)), g)
    pad = 0.1 * (hi - lo) if hi > lo else 1e-4 * abs(g) or 1e-3
    ax.set_ylim(lo - pad, hi + pad)


def _residual_panel(ax, section: dict[str, Any]) -> None:
    poses = section["poses"]
    in_mg = any(p["residual_mg"] is not None for p in poses)
    key, unit = ("residual_mg", "mg") if in_mg else ("residual", section["units_out"])
    held = f"{key[:-3] if in_mg else key}_loo" + ("_mg" if in_mg else "")
    x = np.arange(len(poses))
    width = 0.4
    fit = [np.nan if p[key] is None else p[key] for p in poses]
    loo = [np.nan if p[held] is None else p[held] for p in poses]
    ax.bar(x - width / 2, fit, width, color="tab:blue", label="residual (fit)")
    if not np.all(np.isnan(loo)):
        ax.bar(x + width / 2, loo, width, color="tab:orange", label="held out (pose not fitted)")
    ax.axhline(0, color="black", lw=0.8)
    ax.set_title("|a| - g per pose after calibration")
    ax.set_xlabel("pose")
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.set_ylabel(f"residual  [{unit}]")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")


def _rotation_panel(ax, kind: str, section: dict[str, Any]) -> None:
    rows = [r for r in section["rotations"] if r["angle_error_deg"] is not None]
    x = np.arange(len(rows))
    errors = [r["angle_error_deg"] for r in rows]
    ax.bar(x, errors, color="tab:green")
    ax.axhline(0, color="black", lw=0.8)
    rms = float(np.sqrt(np.mean(np.square(errors)))) if errors else float("nan")
    ax.set_title(f"{kind}: angle error per rotation (RMS {rms:.3g} deg)")
    ax.set_xlabel("rotation")
    if any(r.get("known_angle_deg") is not None for r in rows):
        ax.set_ylabel("gyro angle - reference  [deg]")
    else:  # models without a reference angle (the full gyro model)
        ax.set_ylabel("predicted vs measured gravity after the turn  [deg]", fontsize=8)
    labels = [r["label"] or r["segment"] or str(i) for i, r in enumerate(rows)]
    if len(rows) <= 24:
        ax.set_xticks(x, labels, rotation=60, ha="right", fontsize=7)
    ax.grid(alpha=0.3, axis="y")


def _sphere_panel(ax, section: dict[str, Any]) -> None:
    d = np.array([p["direction"] for p in section["poses"] if p["direction"]], dtype=float)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    u, v = np.mgrid[0 : 2 * np.pi : 25j, 0 : np.pi : 13j]
    ax.plot_wireframe(np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v), color="0.8", lw=0.5)
    ax.scatter(d[:, 0], d[:, 1], d[:, 2], color="tab:blue", s=30, depthshade=False)
    coverage = section["coverage"] or {}
    title = "measured gravity directions"
    if coverage.get("fraction") is not None:
        title += f"\ncovered {100 * coverage['fraction']:.0f} % of the sphere"
    ax.set_title(title)
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    ax.set_box_aspect((1, 1, 1))


def report_figure(
    report: dict[str, Any], path: str | os.PathLike[str], *, force: bool = False, inputs=()
) -> Path:
    """Draw the report's per-pose and per-rotation data to a PNG.

    Parameters
    ----------
    report : dict
        From :func:`imucal_cli.use.report.build_report`.
    path : path-like
        The PNG to write.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        matplotlib missing (:data:`PLOT_HINT`), nothing to plot, or the file cannot be written.
    """
    return _save(draw_report(report, where=str(path)), path, force, inputs)


def draw_report(report: dict[str, Any], where: str = "the report"):
    """The report figure (see the module notes) as a matplotlib ``Figure`` (the caller saves
    and closes it); ``where`` names it in the error when there is nothing to plot.

    Raises
    ------
    InputError
        matplotlib missing (:data:`PLOT_HINT`) or nothing to plot.
    """
    panels = []
    for kind, section in report["sensors"].items():
        poses = section["poses"]
        if any(p["magnitude_before"] is not None or p["magnitude_after"] is not None
               for p in poses):  # fmt: skip
            panels.append(("2d", lambda ax, s=section: _magnitude_panel(ax, s)))
        if any(p["residual"] is not None for p in poses):
            panels.append(("2d", lambda ax, s=section: _residual_panel(ax, s)))
        if any(r["angle_error_deg"] is not None for r in section["rotations"]):
            panels.append(("2d", lambda ax, k=kind, s=section: _rotation_panel(ax, k, s)))
        if any(p["direction"] for p in poses):
            panels.append(("3d", lambda ax, s=section: _sphere_panel(ax, s)))
    if not panels:
        raise InputError(
            f"{where}: nothing to plot: the calibration carries no per-pose or per-rotation data"
        )
    plt = pyplot()
    cols = 1 if len(panels) == 1 else 2
    rows = (len(panels) + cols - 1) // cols
    fig = plt.figure(figsize=(6.5 * cols, 4.6 * rows), layout="constrained")
    for i, (kind, draw) in enumerate(panels):
        ax = fig.add_subplot(rows, cols, i + 1, **({"projection": "3d"} if kind == "3d" else {}))
        draw(ax)
        ax.set_title(f"({'abcdefgh'[i]}) {ax.get_title()}")
    title = "imucal calibration report"
    for key in ("sensor", "session", "created"):
        if report.get(key):
            title += f" | {report[key]}"
    fig.suptitle(title)
    return fig


def noise_figure(result, path: str | os.PathLike[str], *, force: bool = False, inputs=()) -> Path:
    """Allan deviation per axis (one panel per sensor) with the fitted lines.

    Parameters
    ----------
    result : imucal_cli.use.noise.NoiseReport
    path : path-like
        The PNG to write.

    Returns
    -------
    Path
    """
    plt = pyplot()
    n = len(result.sensors)
    fig, axes = plt.subplots(1, n, figsize=(6.5 * n, 5), layout="constrained", squeeze=False)
    colors = ("tab:red", "tab:green", "tab:blue", "tab:purple", "tab:orange", "tab:brown")
    for ax, s in zip(axes[0], result.sensors, strict=True):
        rw = "VRW" if s.kind == "accel" else "ARW"
        rw_unit = "m/s/sqrt(s)" if s.kind == "accel" else "rad/sqrt(s)"
        for i, (name, a) in enumerate(zip(s.axes, s.noise, strict=True)):
            c = colors[i % len(colors)]
            tau, adev = a.curve.tau_s, a.curve.adev
            ax.loglog(tau, adev, "-", color=c, label=f"{name}")
            if a.random_walk is not None:
                ax.loglog(tau, a.random_walk / np.sqrt(tau), ":", color=c, lw=1,
                          label=f"{name}: {rw} N = {a.random_walk:.3g} {rw_unit}")  # fmt: skip
            marker = "v" if a.bias_instability_bound else "o"
            ax.plot(a.bias_instability_tau_s, 0.664 * a.bias_instability, marker, color=c,
                    label=f"{name}: B = {a.bias_instability:.3g} {s.units}"
                    + (" (upper bound)" if a.bias_instability_bound else ""))  # fmt: skip
            if a.rate_random_walk is not None:
                ax.loglog(tau, a.rate_random_walk * np.sqrt(tau / 3.0), "--", color=c, lw=1)
        ax.set_title(f"{s.kind}: Allan deviation ({s.basis})")
        ax.set_xlabel("averaging time tau  [s]")
        ax.set_ylabel(f"Allan deviation  [{s.units}]")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(
        f"{result.session}: {result.span}, {result.duration_s / 60:.1f} min at "
        f"{result.rate_hz:.4g} Hz"
    )
    return _save(fig, path, force, inputs)
