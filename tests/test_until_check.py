"""``capture --until``'s "done" is about the session saved (issue 27.1): the guided state
with targets (:class:`~imucal_cli.capture.guided.AdaptiveState`) driven step by step, its
refits returned by hand in the order a slow refit thread would return them (no thread, no
timing): a refit that met the targets without the steps taken since, or before a redo, is
checked with the steps as they are; while it is checked no pose is proposed and a fixed plan
does not end; a failed check lets the guide go on, or the plan end, but never after the
capture ended."""

from __future__ import annotations

import numpy as np

from imucal_cli.capture.guided import AdaptiveOptions, AdaptiveState, GuidedOptions, Refit, adaptive
from imucal_cli.capture.guided.keys import Command
from imucal_cli.capture.guided.matching import Taken
from imucal_cli.formats.targets import parse_until
from imucal_cli.plans import Plan, Step


class Verdict:
    """A target status whose ``met`` the test sets (the refit's calibration is not read)."""

    def __init__(self, met: bool) -> None:
        self.met, self.std, self.ratio, self.target = met, None, 1.0, None


class Harness:
    """An :class:`AdaptiveState` whose refit requests are recorded and returned by hand."""

    def __init__(self, monkeypatch, steps: list[Step], *, propose: bool) -> None:
        self.met_next = True
        self.proposals = 0
        monkeypatch.setattr(adaptive, "measure",
                            lambda cal, targets, notes=None: [Verdict(self.met_next)])
        monkeypatch.setattr(adaptive, "brief", lambda statuses: "-")
        monkeypatch.setattr(AdaptiveState, "_update_factors", lambda state: None)

        def request(state) -> None:  # the session is not built: only its version matters
            job = (None, state.version)
            if state.pending is not None:
                state.queued = job
            else:
                state.pending = job

        def propose_one(state) -> None:  # as the guide's: a pending step appended
            self.proposals += 1
            state.steps.append(Step("static", "proposed", up=np.eye(3)[len(state.steps) % 3]))
            state.status.append("pending")

        monkeypatch.setattr(AdaptiveState, "request_refit", request)
        monkeypatch.setattr(AdaptiveState, "add_proposal", propose_one)
        opt = AdaptiveOptions(parse_until("accel=0.5%"), refit=lambda s: Refit(None),
                              propose=propose)  # fmt: skip
        self.state = AdaptiveState(Plan("test", tuple(steps)), GuidedOptions(), 0,
                                   lambda *a, **k: None, opt)  # fmt: skip

    def take(self, i: int, kind: str = "static") -> None:
        up = np.eye(3)[i % 3]
        self.state.take(Taken(i, kind, 10 * i, 10 * i + 5, up if kind == "static" else None))
        self.state.after_step()

    def refit_returns(self, met: bool) -> None:
        """The running refit ends (and the waiting one starts), as ``poll_refit`` does."""
        st = self.state
        _, version = st.pending
        st.pending, st.queued = st.queued, None
        self.met_next = met
        st.apply_refit(Refit(None), 1.0, version)


def faces(n: int) -> list[Step]:
    return [Step("static", f"face {i}", up=np.eye(3)[i % 3]) for i in range(n)]


def test_met_on_the_steps_before_the_last_is_checked_with_it(monkeypatch):
    h = Harness(monkeypatch, faces(4), propose=False)
    h.take(0)
    h.take(1)  # the refit of step 0 runs, step 1's waits
    h.refit_returns(met=True)  # met without step 1
    assert not h.state.met and h.state.checking and h.state.end_reason is None
    h.refit_returns(met=True)  # met with every step taken
    assert h.state.met and h.state.end_reason == "every target met"


def test_a_fixed_plan_does_not_end_while_checked_and_ends_when_the_check_fails(monkeypatch):
    h = Harness(monkeypatch, faces(3), propose=False)
    h.take(0)
    h.take(1)
    h.refit_returns(met=True)  # step 0 alone met: checking, step 1's refit running
    h.take(2)  # the plan's last step, while checked
    assert h.state.end_reason is None and h.state.checking
    assert h.state.rot_phase == "pre" and not h.state.holding  # the step's tracking reset
    h.refit_returns(met=True)  # steps 0-1: still stale
    h.refit_returns(met=False)  # all three: the check fails
    assert not h.state.checking and not h.state.met
    assert h.state.end_reason == "every step of the plan done or skipped"
    assert h.state.pending is None and h.state.queued is None


def test_no_proposal_while_checked_and_the_guide_goes_on_when_the_check_fails(monkeypatch):
    h = Harness(monkeypatch, faces(1), propose=True)
    h.take(0)  # the first face; step 1 proposed, step 0's refit running
    h.take(1)  # step 2 proposed; step 1's refit waits
    assert h.proposals == 2
    h.refit_returns(met=True)  # met without step 1: checking
    assert h.state.checking
    h.take(2)  # the proposal made before the check began, taken while checked
    assert h.proposals == 2 and h.state.current() is None  # none made meanwhile
    assert h.state.prompt().phase == "check" and h.state.end_reason is None
    h.refit_returns(met=True)  # steps 0-1: stale again
    h.refit_returns(met=False)  # steps 0-2: the check fails
    assert not h.state.checking and h.proposals == 3  # the guide goes on


def test_a_refit_of_a_redone_step_does_not_say_done(monkeypatch):
    h = Harness(monkeypatch, faces(3), propose=False)
    h.take(0)
    h.take(1)
    h.refit_returns(met=False)  # step 0's; steps 0-1 now running
    h.state.command(Command("redo"))  # step 1 removed: the running refit holds it
    assert [t.step for t in h.state.taken] == [0]
    h.refit_returns(met=True)
    assert not h.state.met and h.state.checking  # the session saved lacks step 1
    h.refit_returns(met=True)  # the steps as they are: met
    assert h.state.met


def test_a_check_that_fails_after_the_capture_ended_proposes_nothing(monkeypatch):
    h = Harness(monkeypatch, faces(1), propose=True)
    h.take(0)
    h.take(1)
    h.refit_returns(met=True)  # checking
    h.take(2)  # nothing pending now
    h.state.command(Command("quit"))  # q
    assert h.state.end_reason is not None
    proposed = h.proposals
    h.refit_returns(met=True)  # steps 0-1
    h.refit_returns(met=False)  # steps 0-2: the check fails after the end
    assert h.proposals == proposed and not h.state.met
