"""Gyro results against their truth, per plan and per shipped session (issue 10.2).

For each simulated plan with turns (``imucal simulate``, default options) and each session in
``sessions/``, ``calibrate`` with the default config, then the gyro's error over its stated std
for the 12 parameters of the full model and for the three gains. A result is *covered* when
every ``|error| / std`` is below :data:`COVERED` (4.5 std; 12 parameters); a gyro that the
design does not determine is not saved (``gyro not calibrated``), and then calibrated anyway
(``[gyro] solver = "full"``, as ``--force`` would save it) to check that its stated std cover
its error too. Before: the six faces saved a gain 21 std off, exit 0, no warning.

The truth is compared in the frame the gyro is calibrated in, the calibrated accelerometer's:
a gravity-magnitude fit's upper-triangular gauge (``R`` from the QR decomposition of the true
accelerometer matrix), or the labels' fixture frame (the truth's own).

Part of ``python -m bench --only trust-gyro`` (seeds per plan: ``--seeds`` / 40, at least 3).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import read_session

ROOT = Path(__file__).resolve().parent.parent
SESSIONS = ROOT / "sessions"
IMUCAL = str(Path(sys.executable).with_name("imucal"))
COVERED = 4.5
#: Plans with turns between still periods, as ``imucal simulate`` arguments.
PLANS = {
    "six": ["--plan", "six"],
    "qureshi18": ["--plan", "qureshi18"],
    "random:20": ["--plan", "random:20"],
    "free:12": ["--plan", "free:12", "--still", "2"],
    "qureshi-axes:6": ["--plan", "qureshi-axes", "--rotations-per-axis", "6", "--still", "2"],
}
SHIPPED = ["six-seed3", "qureshi18-seed1", "qureshi18-seed1-si", "random30-seed2"]


@dataclass
class Row:
    """One session's gyro against its truth."""

    name: str
    accel: str
    saved: bool  # calibrated by the default config (else: why not, in ``note``)
    note: str
    z_params: float  # largest |error| / std over the 12 parameters
    z_gains: np.ndarray  # error / std of the three gains
    rate_std: float  # stated relative rate std (worst direction)
    gain_error: float  # largest relative gain error

    @property
    def covered(self) -> bool:
        return self.z_params < COVERED and bool(np.all(np.abs(self.z_gains) < COVERED))


def truth_in_frame(accel, truth) -> np.ndarray:
    """The true ``(b, M row-major)`` of the gyro in the frame of the calibrated accelerometer
    ``accel`` (its gauge: upper-triangular, or the labels' frame)."""
    R = np.eye(3)
    if "upper-triangular" in str(accel.gauge or ""):
        Q, U = np.linalg.qr(np.asarray(truth.accel.matrix, float))
        R = (Q * np.sign(np.diag(U))).T  # U with a positive diagonal: calibrated = R a_true
    return np.r_[truth.gyro.bias, (R @ np.asarray(truth.gyro.matrix, float)).ravel()]


def _gains(x: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.linalg.inv(x[3:12].reshape(3, 3)), axis=1)


def _compare(gyro, x_true: np.ndarray) -> tuple[float, np.ndarray, float, float]:
    params = gyro.parameters[:12]
    x = np.array([p.value for p in params])
    std = np.array([p.std for p in params])
    cov = np.diag(std**2)  # the gains' std: from the section's sensitivity_std when present
    J = np.empty((3, 12))
    for i in range(12):
        h = 1e-7 * max(abs(x[i]), 1e-9)
        e = np.zeros(12)
        e[i] = h
        J[:, i] = (_gains(x + e) - _gains(x - e)) / (2 * h)
    g_std = np.asarray(gyro.sensitivity_std or np.sqrt(np.diag(J @ cov @ J.T)))
    z_g = (_gains(x) - _gains(x_true)) / g_std
    rate = np.nan if gyro.rate_std is None else gyro.rate_std.total
    return (float(np.max(np.abs((x - x_true) / std))), z_g, float(rate),
            float(np.max(np.abs(_gains(x) / _gains(x_true) - 1))))  # fmt: skip


def row(name: str, session_path: Path, truth_path: Path) -> Row:
    """Calibrate with the default config; where the gyro is left out, with the full model."""
    session = read_session(session_path)
    truth = read_calibration(truth_path)
    cal = calibrate_session(session, Config())
    saved, note, gyro = cal.gyro is not None, cal.gyro_note or "", cal.gyro
    if gyro is None:
        cfg = Config()
        cfg = replace(cfg, gyro=replace(cfg.gyro, solver="full"))
        gyro = calibrate_session(session, cfg).gyro
    z, zg, rate, err = _compare(gyro, truth_in_frame(cal.accel, truth))
    return Row(name, cal.accel.solver, saved, note, z, zg, rate, err)


def simulate(args: list[str], seed: int, folder: Path) -> tuple[Path, Path]:
    """``imucal simulate ARGS --seed SEED`` into ``folder``: the session and its truth."""
    out = folder / f"s{seed}.h5"
    subprocess.run([IMUCAL, "simulate", *args, "--seed", str(seed), "-o", str(out), "--force"],
                   check=True, capture_output=True, timeout=300)  # fmt: skip
    return out, out.with_suffix(".truth.json")


def plan_rows(plan: str, seeds: list[int]) -> list[Row]:
    with tempfile.TemporaryDirectory() as tmp:
        out = []
        for seed in seeds:
            s, t = simulate(PLANS[plan], seed, Path(tmp))
            out.append(row(f"{plan} seed {seed}", s, t))
        return out


def shipped_rows() -> list[Row]:
    return [row(n, SESSIONS / f"{n}.h5", SESSIONS / f"{n}.truth.json") for n in SHIPPED]


def run(console, n_seeds: int = 3) -> bool:
    """Print the table; True when every gyro's error is covered by its stated std."""
    from rich.table import Table

    table = Table(title=f"Gyro error / stated std, default config, shipped sessions and "
                        f"{n_seeds} seeds per plan (issue 10.2; before: six faces saved a gain "
                        "21 std off)")  # fmt: skip
    for col in ("session", "accel", "gyro saved", "max |err|/std (12)", "gains err/std",
                "rate std %", "max gain err %", "covered"):  # fmt: skip
        table.add_column(col, justify="right")
    rows = shipped_rows()
    for plan in PLANS:
        rows += plan_rows(plan, list(range(1, n_seeds + 1)))
    for r in rows:
        table.add_row(r.name, r.accel, "yes" if r.saved else "no (undetermined)",
                      f"{r.z_params:.2f}", " ".join(f"{v:+.2f}" for v in r.z_gains),
                      f"{100 * r.rate_std:.3g}", f"{100 * r.gain_error:.3g}",
                      "yes" if r.covered else "NO")  # fmt: skip
    console.print(table)
    bad = [r.name for r in rows if not r.covered]
    console.print(f"not covered by the stated std: {len(bad)} of {len(rows)} {bad or ''}")
    return not bad
