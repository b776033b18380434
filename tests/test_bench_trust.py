"""The trust benches' rows run on a small scale (``python -m bench --only trust`` and
``trust-gyro`` run them at scale): each row function returns rows of the shape its table
prints, so a change of the calibration model that breaks a bench breaks here first (the
leave-one-rotation-out rows read the parameters as dicts after the typed model, and the bench
crashed there unseen)."""

from __future__ import annotations

import pytest

from bench import trust, trust_gyro


@pytest.fixture()
def one_recording(monkeypatch):
    """The leave-one-out rows on one of the shipped recordings (an MPU-9150, 21 turns)."""
    if not (trust_gyro.DATA / "mikoff_mpu9150" / "imu0.log").exists():
        pytest.skip(f"{trust_gyro.DATA} not found")
    for module in (trust, trust_gyro):
        monkeypatch.setattr(module, "REAL", {k: v for k, v in module.REAL.items()
                                             if k == "mikoff imu0"})  # fmt: skip


def test_gyro_leave_one_rotation_out_rows(one_recording):
    [(name, k, state, counts)] = trust_gyro.loo_rows()
    assert name == "mikoff imu0" and k == 21 and state == "saved"
    assert counts["saved wrong"] == 0 and counts["converged"] + counts["refused"] == k


def test_accel_leave_one_pose_out_rows(one_recording):
    [(name, k, solver, counts)] = trust.loo_rows()
    assert name == "mikoff imu0" and k == 22 and solver == "gravity"
    assert counts["saved wrong"] == 0 and counts["converged"] + counts["refused"] == k


def test_captured_coverage_rows_of_one_seed():
    rows = trust_gyro.captured_coverage_rows(1)
    assert [r["seeds"] for r in rows] == [1, 1, 1]
    assert all(0.0 <= r["coverage"] <= 1.0 and r["far"] == 0 for r in rows), rows


def test_ferraris_rows_of_two_seeds():
    rows = trust.ferraris_rows(2)
    assert rows["seeds"] == 2 and rows["refused"] == 0
    assert [name for name, *_ in rows["groups"]] == [name for name, _ in trust.GROUPS]
    # two sessions' 24 intervals: an honest 95 % misses at most a few
    assert rows["coverage"] >= 0.75 and all(0 < z < 3 for *_, z in rows["groups"]), rows
