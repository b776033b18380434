"""`imucal report --plot` and the figures module: a PNG is written from what the calibration
stores (per-pose magnitudes and residuals, per-rotation angle errors, pose directions); without
matplotlib the command fails with one line of advice."""

from __future__ import annotations

import json
import sys

import pytest

from imucal_cli.use.plots import PLOT_HINT, report_figure

from .test_report import (
    _assert_one_line_error,
    full_calibration,
    minimal_calibration,
    run_imucal,
    write_json,
)

PNG = b"\x89PNG\r\n\x1a\n"


def _is_png(path) -> bool:
    return path.stat().st_size > 10_000 and path.read_bytes()[:8] == PNG


def test_report_plot_writes_a_png(tmp_path, capsys, monkeypatch):
    pytest.importorskip("matplotlib")
    cal = write_json(tmp_path / "cal.json", full_calibration())
    png = tmp_path / "report.png"
    code, out, err = run_imucal(["report", str(cal), "--plot", str(png)], capsys, monkeypatch)
    assert code == 0, err
    assert _is_png(png) and f"wrote {png}" in out
    # --json stays pure JSON with --plot.
    png.unlink()
    code, out, err = run_imucal(
        ["report", str(cal), "--plot", str(png), "--json"], capsys, monkeypatch
    )
    assert code == 0 and json.loads(out)["format"] == "imucal-report" and _is_png(png)


def test_gyro_rotation_panel(tmp_path):
    """A calibration with a gyro section and its rotations: the angle-error panel is drawn."""
    pytest.importorskip("matplotlib")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from imucal_cli.formats.calibration import calibration_from_json
    from imucal_cli.use.report.build import build_report

    document = full_calibration()
    document["gyro"] = {
        "solver": "gyro-dynamic", "units": "rad/s", "bias": [1.0, -2.0, 0.5],
        "matrix": [[1e-3, 0, 0], [0, 1e-3, 0], [0, 0, 1e-3]], "residual_rms": 0.01,
        "rotations": [
            {"segment": f"{i:04d}", "label": f"turn {i}", "known_angle_deg": 90.0,
             "measured_angle_deg": 90.0 + 0.01 * i, "angle_error_deg": 0.01 * i}
            for i in range(6)
        ],
    }  # fmt: skip
    report = build_report(calibration_from_json(json.dumps(document), "g.json"))
    titles = []
    real_close = plt.close
    monkey_fig = []

    def spy(fig=None):
        if fig is not None:
            monkey_fig.append([ax.get_title() for ax in fig.axes])
        real_close(fig)

    plt.close = spy
    try:
        report_figure(report, tmp_path / "g.png")
    finally:
        plt.close = real_close
    titles = monkey_fig[0]
    assert _is_png(tmp_path / "g.png")
    assert titles[0].startswith("(a) |a| per pose") and "mg" in titles[0]
    assert titles[1].startswith("(b) |a| - g per pose")
    assert titles[2].startswith("(c) measured gravity directions")
    assert titles[3].startswith("(d) gyro: angle error per rotation")


def test_nothing_to_plot_is_one_line(tmp_path, capsys, monkeypatch):
    pytest.importorskip("matplotlib")
    cal = write_json(tmp_path / "min.json", minimal_calibration())
    code, out, err = run_imucal(
        ["report", str(cal), "--plot", str(tmp_path / "x.png")], capsys, monkeypatch
    )
    _assert_one_line_error(code, out, err, "nothing to plot")
    assert not (tmp_path / "x.png").exists()


def test_without_matplotlib_one_line_of_advice(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    monkeypatch.setitem(sys.modules, "matplotlib.pyplot", None)
    cal = write_json(tmp_path / "cal.json", full_calibration())
    code, out, err = run_imucal(
        ["report", str(cal), "--plot", str(tmp_path / "x.png")], capsys, monkeypatch
    )
    _assert_one_line_error(code, out, err, PLOT_HINT)
    assert err.strip() == f"imucal: error: {PLOT_HINT}"


def test_factorization_magnitude_panel_has_no_empty_series_and_shows_g(tmp_path):
    """The factorization solver stores no |a| before calibration: no empty "before" series, and
    the y axis includes the g line even when every pose lies on one side of it."""
    pytest.importorskip("matplotlib")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from imucal_cli.formats.calibration import calibration_from_json
    from imucal_cli.use.report.build import STANDARD_GRAVITY, build_report

    document = full_calibration()
    accel = document["accel"]
    accel["solver"] = "factorization"
    for i, pose in enumerate(accel["poses"]):
        pose["magnitude_before"] = None
        pose["magnitude_after"] = STANDARD_GRAVITY + 0.002 + 0.0001 * i  # all above g
    accel.pop("rms_before")
    report = build_report(calibration_from_json(json.dumps(document), "f.json"))
    seen = []
    real_close = plt.close

    def spy(fig=None):
        if fig is not None:
            ax = fig.axes[0]
            seen.append(([line.get_label() for line in ax.get_lines()], ax.get_ylim()))
        real_close(fig)

    plt.close = spy
    try:
        report_figure(report, tmp_path / "f.png")
    finally:
        plt.close = real_close
    labels, (lo, hi) = seen[0]
    assert "before calibration" not in labels and "after calibration" in labels
    assert lo < STANDARD_GRAVITY < hi
    assert hi - lo < 0.01  # still zoomed enough to see the spread of the poses
