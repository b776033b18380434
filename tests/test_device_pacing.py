"""`simulate --serve` pacing without a pseudo-terminal: the schedule of the virtual device
(on a timer, cut short by Enter, or held until Enter with --step)."""

from __future__ import annotations

from imucal_cli.plans import load_plan
from imucal_cli.simulate.device import Hold, _Schedule, stream_with_holds

HOLDS = [Hold(0, 10, "face +Z up"), Hold(15, 25, "face -Z up"), Hold(30, 40, "face +X up")]


def _run(schedule: _Schedule, presses: set[int], limit: int = 200) -> list[int]:
    """Sample indices sent; Enter is pressed just before line k for k in ``presses``."""
    pressed = {"now": False}
    schedule.next_pose = lambda: pressed.pop("now", False)
    sent = []
    while len(sent) < limit:
        if len(sent) in presses:
            pressed["now"] = True
        i = schedule.next_index()
        if i is None:
            break
        sent.append(i)
        schedule.k += 1
    return sent


def _schedule(step: bool, said: list[str]) -> _Schedule:
    return _Schedule(40, HOLDS, loop=False, step=step, next_pose=None, say=said.append,
                     rate_hz=10.0)  # fmt: skip


def test_timer_plays_the_plan_in_order_and_says_each_pose():
    said: list[str] = []
    sent = _run(_schedule(False, said), set())
    assert sent == list(range(40))
    assert len(said) == 3 and "pose 1/3: face +Z up" in said[0] and "Enter here: now" in said[0]
    assert "held 1 s" in said[1]  # 10 samples at 10 Hz


def test_enter_cuts_the_current_hold_short():
    sent = _run(_schedule(False, []), {5})
    assert sent == [*range(5), *range(10, 40)]


def test_step_holds_each_pose_until_enter_replaying_its_samples():
    said: list[str] = []
    sent = _run(_schedule(True, said), {25, 60, 90})
    # the first hold's 10 samples, then 15 more from it (replayed) until Enter at line 25
    assert sent[:10] == list(range(10)) and set(sent[10:25]) <= set(range(10))
    assert sent[25:30] == list(range(10, 15))  # the turn to the next pose
    assert sent[30:40] == list(range(15, 25)) and set(sent[40:60]) <= set(range(15, 25))
    assert sent[60:65] == list(range(25, 30))
    assert set(sent[75:90]) <= set(range(30, 40)) and len(sent) == 90  # ends on the last Enter
    assert "held until Enter here" in said[0]


def test_a_paused_hold_is_replayed_mirrored():
    """Issue 24.1/24.7 (bench live, warm-up guided: exit 3): a paused hold replayed from its
    start made a warm-up's temperature and biases jump back from 40 to 5 C, a motion to the
    capture, and its 2-minute hold never completed.  Replayed backwards and forwards, the
    stream goes on from the last sample without a jump."""
    sent = _run(_schedule(True, []), {60})
    assert sent[:10] == list(range(10))
    assert sent[10:28] == [*range(8, -1, -1), *range(1, 10)]  # back to the start, forwards
    assert sent[28:30] == [8, 7]
    assert max(abs(a - b) for a, b in zip(sent[:59], sent[1:60], strict=True)) == 1

def test_holds_of_the_streams():
    _, _, _, holds = stream_with_holds("six", hold_s=2.0)
    assert [h.label for h in holds] == ["face +Z up", "face -Z up", "face +X up", "face -X up",
                                        "face +Y up", "face -Y up"]  # fmt: skip
    assert holds[0].start == 0 and all(h.stop - h.start >= 200 for h in holds)
    _, _, _, holds = stream_with_holds("hwangbo-iron", hold_s=1.0)
    steps = load_plan("hwangbo-iron").static_steps  # one hold per still step of the plan
    assert [h.label for h in holds] == [s.label for s in steps]
