"""Which vehicle states the daemon may fly: each complete state classified as it arrives.

Why its own module: this is the daemon's defence against lost, late, repeated, reordered and
forged states and against a restarted simulator, and it is a small state machine over times
alone (no law, no link), easier to read, test and fuzz (tools/harness/fuzz.py predicts it) apart.

**Degrade, don't fall.** Each complete state is classified against the newest state accepted
so far (the *watermark*), into exactly one of: :data:`FRESH` (newer, by a plausible step),
:data:`REPEATED` (the watermark's time again, e.g. a lockstep resend after a lost reply: the
daemon answers it with the same command, the law is not rerun), :data:`OLD` (older, by at
most ``BACKSTEP_S``: reordered, dropped) and :data:`IMPLAUSIBLE` (see below).

**Implausible time.** A state more than ``AHEAD_S`` of sim time ahead of the watermark
(plus, in real time, the wall time elapsed since the watermark arrived), or more than
``BACKSTEP_S`` behind it, is not a successor of the flight being flown: it is counted,
not controlled, and does not move the watermark. One forged or corrupted datagram (say
time_usec = 2^63) therefore cannot lock the daemon out of the genuine states that follow.

**Restart** (:data:`RESTART`). ``JUMP_CONFIRM`` implausible states in a row that are
plausible successors of each other (0 ≤ Δt ≤ ``AHEAD_S``; a restarted simulator's t = 0
state and its resend, or a vehicle that jumped ahead while we were away) are a new time
line: the daemon rebuilds its flight computer and flies the new flight from that state. So
are ``RESTART_OLD_STATES`` old states in a row *at one time* (a restart less than
``BACKSTEP_S`` into a flight: the new vehicle resends its first state until answered). Old
states at varying times are reordering (a relay stalled for tens of ms and then released a
shuffled burst): never a restart.
"""

from __future__ import annotations

import time

__all__ = ["AHEAD_S", "BACKSTEP_S", "FRESH", "IMPLAUSIBLE", "JUMP_CONFIRM", "OLD", "REPEATED",
           "RESTART", "RESTART_OLD_STATES", "Arrivals"]

BACKSTEP_S = 0.2                 # older by more than this: not reordering, implausible
AHEAD_S = 1.0                    # newer by more (+ wall elapsed in real time): implausible
JUMP_CONFIRM = 2                 # consistent implausible states in a row: a new time line
RESTART_OLD_STATES = 25          # ... or this many old states in a row at one time

FRESH, REPEATED, OLD, IMPLAUSIBLE, RESTART = range(5)


class Arrivals:
    """The watermark and the restart rule of one flight (module docstring).

    :meth:`classify` answers one of :data:`FRESH` (the watermark has moved to it),
    :data:`REPEATED`, :data:`OLD`, :data:`IMPLAUSIBLE` or :data:`RESTART` (a new time line:
    the caller starts a new flight, :meth:`reset`, then :meth:`accept` the state).
    """

    __slots__ = ("jump_usec", "jumps_in_row", "newest_usec", "newest_wall", "old_in_row",
                 "old_usec", "realtime", "wall")

    def __init__(self, realtime: bool) -> None:
        self.realtime = realtime      # real time: the plausible step grows with wall time
        self.newest_usec = -1         # the watermark: newest fresh state accepted
        self.newest_wall = 0.0        # monotonic wall time it arrived (real time only)
        self.jump_usec = -1           # the last implausible state, if the last one was
        self.jumps_in_row = 0
        self.old_in_row = 0
        self.old_usec = -1            # time of the old states in a row (a waiting vehicle's)
        self.wall = 0.0               # when the last state classified arrived (real time)

    def classify(self, t_usec: int) -> int:
        """Classify the complete state of time ``t_usec`` (µs of sim time)."""
        w = self.newest_usec
        now = self.wall = time.monotonic() if self.realtime else 0.0   # only real time reads it
        if w >= 0:
            ahead_usec = AHEAD_S * 1e6
            if t_usec == w:
                self.jumps_in_row = 0
                return REPEATED
            if w - BACKSTEP_S * 1e6 <= t_usec < w:
                self.jumps_in_row = 0
                same = self.old_in_row > 0 and t_usec == self.old_usec
                self.old_in_row = self.old_in_row + 1 if same else 1
                self.old_usec = t_usec
                return OLD if self.old_in_row < RESTART_OLD_STATES else RESTART
            limit = ahead_usec + ((now - self.newest_wall) * 1e6 if self.realtime else 0.0)
            if not w < t_usec <= w + limit:
                j = self.jump_usec
                chained = self.jumps_in_row > 0 and 0 <= t_usec - j <= ahead_usec
                self.jumps_in_row = self.jumps_in_row + 1 if chained else 1
                self.jump_usec = t_usec
                return IMPLAUSIBLE if self.jumps_in_row < JUMP_CONFIRM else RESTART
        self.jumps_in_row = 0
        self.old_in_row = 0
        self.newest_usec = t_usec
        self.newest_wall = now
        return FRESH

    def accept(self, t_usec: int) -> None:
        """Move the watermark to the state just classified (``t_usec``), e.g. the first
        state of a new time line after :data:`RESTART` and :meth:`reset`."""
        self.jumps_in_row = 0
        self.old_in_row = 0
        self.newest_usec = t_usec
        self.newest_wall = self.wall

    def forget_watermark(self) -> None:
        """No watermark, the rows counted kept: a start held at t = 0 sees the vehicle's
        resend of t = 0 as fresh again."""
        self.newest_usec = -1

    def reset(self) -> None:
        """A new flight: no watermark (the next state is fresh), no rows counted."""
        self.newest_usec = -1
        self.jumps_in_row = 0
        self.old_in_row = 0
