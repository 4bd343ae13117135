"""The vehicle's clocks as pacing policy: given wall times, what each decides.

The loops that act on these decisions (send, count, announce) are the vehicle's and are
flown over real UDP in tests/system (test_vehicle, test_realtime, test_lockstep_loss).
"""

from __future__ import annotations

import ast
import itertools
from pathlib import Path

import pytest

from tfl_mav.sitl.clock import WAIT_SLICE_S, LockstepClock, RealtimeClock, Silence

CLOCK = Path(__file__).resolve().parents[2] / "sitl" / "clock.py"


def test_the_clocks_hold_no_vehicle_part() -> None:
    """Policy only: the clock module imports no link, simulator or vehicle, so it cannot
    drive one."""
    tree = ast.parse(CLOCK.read_text())
    imported = {node.module for node in ast.walk(tree)
                if isinstance(node, ast.ImportFrom) and node.module} | {
        a.name for node in ast.walk(tree) if isinstance(node, ast.Import) for a in node.names}
    assert imported <= {"__future__", "dataclasses", "enum"}, imported


def test_lockstep_resends_back_off_to_four_times_the_first_interval() -> None:
    clock = LockstepClock(timeout_s=2.0, resend_s=0.005)
    clock.start(100.0)
    assert clock.slice_s(100.0) == pytest.approx(0.005)
    assert clock.silence(100.004) is Silence.NOTHING
    resent = [t for t in (100.0 + 0.001 * i for i in range(1, 120))
              if clock.silence(t) & Silence.RESEND]
    gaps_ms = [round(1000 * (b - a)) for a, b in itertools.pairwise(resent)]
    # first at 5 ms, then 10, then 20 (4 × 5 ms) for good
    assert round(1000 * (resent[0] - 100.0)) == 5
    assert gaps_ms[:2] == [10, 20] and set(gaps_ms[2:]) == {20}


def test_lockstep_slice_never_exceeds_the_stop_reaction() -> None:
    clock = LockstepClock(timeout_s=2.0, resend_s=1.0)
    clock.start(0.0)
    assert clock.slice_s(0.0) == WAIT_SLICE_S
    assert clock.slice_s(0.99) == pytest.approx(0.01)


def test_lockstep_timeout_repeats_every_timeout_and_a_new_tick_resets_it() -> None:
    clock = LockstepClock(timeout_s=0.25, resend_s=0.005)   # binary fractions: exact sums
    clock.start(0.0)
    timed_out = [t for t in (0.0625 * i for i in range(1, 14)) if clock.silence(t)
                 & Silence.TIMED_OUT]
    assert timed_out == [0.25, 0.5, 0.75]
    clock.start(1.0)                      # the next tick's state went out
    assert not clock.silence(1.125) & Silence.TIMED_OUT
    assert clock.silence(1.25) & Silence.TIMED_OUT
    assert "time_usec 7000 within 0.25 s; state resent every 5-20 ms" in \
        clock.timeout_text(7000)


def test_lockstep_gives_up_only_past_the_peer_timeout() -> None:
    patient = LockstepClock(timeout_s=0.5)
    patient.start(0.0)
    assert not patient.silence(1e6) & Silence.LOST      # None: waits however long
    clock = LockstepClock(timeout_s=0.5, peer_timeout_s=3.0)
    clock.start(10.0)
    assert not clock.silence(12.9) & Silence.LOST
    assert clock.silence(13.1) is Silence.LOST
    assert clock.lost_reason(13.1) == ("no HIL_ACTUATOR_CONTROLS for 3.1 s (over "
                                       "--peer-timeout 3 s): the controller is gone")


def test_resend_interval_is_capped_by_the_timeout() -> None:
    clock = LockstepClock(timeout_s=0.01, resend_s=0.05)
    assert (clock.resend_s, clock.resend_max_s) == (0.01, 0.01)


def test_realtime_periods_follow_the_anchor_and_an_overrun_moves_it() -> None:
    clock = RealtimeClock(control_dt_s=0.001, command_timeout_s=0.25)
    clock.start(50.0)
    assert clock.due_s(0) == pytest.approx(50.001)
    assert clock.due_s(9) == pytest.approx(50.010)
    assert clock.overrun(50.05, clock.due_s(9), 10) is None       # 40 ms late: keeps pace
    assert clock.due_s(10) == pytest.approx(50.011)
    text = clock.overrun(50.2, 50.011, 11)                          # 189 ms late
    assert text == ("real time: physics fell 0.189 s behind the wall clock; "
                    "clock re-anchored")
    assert clock.due_s(11) == pytest.approx(50.201)                 # tick 11 starts now


def test_realtime_silence_cuts_once_and_ends_the_run_only_when_cut() -> None:
    clock = RealtimeClock(control_dt_s=0.001, command_timeout_s=0.25, peer_timeout_s=2.0)
    assert not clock.cuts_motors(0.25, motors_cut=False)
    assert clock.cuts_motors(0.26, motors_cut=False)
    assert not clock.cuts_motors(5.0, motors_cut=True)              # already cut
    assert clock.lost_reason(2.5, motors_cut=False) is None
    assert clock.lost_reason(1.9, motors_cut=True) is None
    assert clock.lost_reason(2.5, motors_cut=True) == (
        "no valid HIL_ACTUATOR_CONTROLS for 2.5 s (over --peer-timeout 2 s): the "
        "controller is gone")
    assert RealtimeClock(0.001, 0.25).lost_reason(1e6, motors_cut=True) is None
