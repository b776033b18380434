"""The simulated person in this process (:mod:`bench.person`): a refit takes as long in the
device's time as it computes, as at the bench.

The guided capture refits the session in a thread beside the stream.  In this process the
stream runs 50-300 times faster than the device's clock, so a refit left in a thread answered
5-30 s of device time after it was asked: with a pose every 3-4 s each answer was about steps
the person had already gone past (stale), the capture re-checked instead of saying done, and
``bench adaptive``'s imu_tk-style plan took 283 s instead of 137 s on part 2700, by the load of
the machine.  Here each refit is made slow (a quarter of a second more, a slow computer) and
what the capture did is counted in device time: no answer about steps already gone past,
"done" on the first refit that met the targets, and no answer sooner than its computing.
"""

from __future__ import annotations

import time

import bench.person as person_module
from bench.adaptive import imu_tk_plan
from imucal_cli.capture.guided.adaptive import AdaptiveState

#: The refit's extra wall time, s: far below a pose (2 s hold, 1-2 s turn), and 10-75 s of
#: device time if the stream ran on beside it.
SLOW_S = 0.25


def test_a_slow_refit_answers_before_the_person_has_moved_on(monkeypatch):
    real = person_module.refit
    took: list[float] = []

    def slow(session, cfg):
        tic = time.perf_counter()
        time.sleep(SLOW_S)
        result = real(session, cfg)
        took.append(time.perf_counter() - tic)
        return result

    stale: list[bool] = []
    apply = AdaptiveState.apply_refit

    def counted(self, result, last, version=None):
        stale.append(version is not None and version != self.version)
        return apply(self, result, last, version)

    monkeypatch.setattr(person_module, "refit", slow)
    monkeypatch.setattr(AdaptiveState, "apply_refit", counted)
    plan = imu_tk_plan(poses=12, rest_s=10.0)
    out = person_module.follow(2701, "accel=0.5%,gyro=1%", plan=plan, propose=False,
                               min_hold_s=2.0, max_s=300)  # fmt: skip
    text = "\n".join(out.lines)
    # each refit answered about the steps as they were (before: 5 of 6 answers stale)
    assert stale and not any(stale), (stale, out.lines[-12:])
    assert "without the last steps" not in text
    # so "done" came with the refit after the pose that met the targets, before the plan ended
    # (before: only after the plan's 13th pose)
    assert out.seconds is not None and out.poses < len(plan.steps), (out.poses, out.seconds)
    assert len(stale) == out.poses, (len(stale), out.poses)  # one refit a pose, none dropped
    # and no refit answered sooner than it computed (device time s against wall s)
    assert len(out.refits) == len(took)
    assert all(answered - asked >= t for (asked, answered), t in zip(out.refits, took,
                                                                     strict=True))  # fmt: skip
