"""A recorder child's CPU priority: below its flight process, and idle where that is safe.

Why (measured with ``bench/bench_lockstep.py``): a lockstep flight is a serial chain,
sim → daemon → sim, and each hop is a wake-up. On 2 cores the two recorder children are
busy most of the time, and a woken flight process waited a median ~60 µs (p90 ~150 µs)
for the CPU a *niced* child was running: ``nice`` sets a share, not a latency, so the
scheduler (CFS/EEVDF) lets the child finish its turn. A ``SCHED_IDLE`` child is different:
a CPU running only idle tasks counts as free when the woken task is placed, and a normal
task preempts an idle one at once. Wake-ups then cost ~5 µs, as with no recorder at all.

The price of ``SCHED_IDLE``: a task that only gets CPU nobody else wants starves while
anything else is busy. In lockstep that would stall the flight (its recorder's pipe fills
and the flight waits for it — see :mod:`~tfl_mav.flightlog.recorder_process`) for as long
as another program keeps both cores busy. So the child is made idle only when it can be
*promoted* back to ``SCHED_OTHER`` at its nice value (:func:`can_promote`: root,
``CAP_SYS_NICE``, or a high enough ``RLIMIT_NICE``; Linux refuses that step otherwise), and
the parent promotes it the first time the child falls behind (:meth:`Priority.promote`).
In real time the child stays niced: there a starved child drops records instead of
slowing anything, and dropping is worse than a few µs of wake-up.
"""

from __future__ import annotations

import contextlib
import os
import resource
import sys

__all__ = ["IDLE_ENV", "NICE_INCREMENT", "Priority", "can_promote", "idle_enabled"]

IDLE_ENV = "TFL_MAV_RECORDER_IDLE"
"""``0``: never make a recorder child idle (niced only, as in real time): for A/B runs
(``bench/bench_lockstep.py``) or a machine where an idle child is not wanted. ``1`` or
unset: idle in lockstep where it can be promoted back."""

NICE_INCREMENT = 10
"""The child runs this much nicer than the flight process. Why: on 2 cores a flight is 4
processes (sim, daemon, two recorder children) and the loop is the serial sim ↔ daemon
chain; the children only need to keep up on average (the pipe buffers a backlog), so when
the CPU is contended the chain should win it. At equal priority a child's batch work
(decode, JSON, protobuf, writing: milliseconds per 10 ms batch) delayed a real-time loop's
wake-up on a busy machine and crashed the paper flight; in lockstep a child that falls
behind fills the pipe and the flight waits ("Backpressure"), so it cannot be starved."""

_CAP_SYS_NICE = 23          # linux/capability.h


def _has_cap_sys_nice() -> bool:
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("CapEff:"):
                    return bool(int(line.split()[1], 16) >> _CAP_SYS_NICE & 1)
    except (OSError, ValueError):
        pass
    return False


def idle_enabled() -> bool:
    """:data:`IDLE_ENV` read: True unless it is ``0``; any value but ``0``/``1`` gets a
    one-line warning on stderr and the default."""
    value = os.environ.get(IDLE_ENV, "1").strip()
    if value not in ("0", "1"):
        print(f"tfl-mav: warning: {IDLE_ENV}={value!r}: expected 0 or 1; using 1 "
              "(recorder children idle in lockstep)", file=sys.stderr)
    return value != "0"


def can_promote(nice: int) -> bool:
    """Whether this process may move a ``SCHED_IDLE`` task of ours back to ``SCHED_OTHER``
    at ``nice``: the kernel's ``can_nice`` rule (``RLIMIT_NICE`` ≥ 20 − nice, or
    ``CAP_SYS_NICE``)."""
    if not hasattr(os, "SCHED_IDLE"):
        return False
    limit = resource.getrlimit(resource.RLIMIT_NICE)[0] \
        if hasattr(resource, "RLIMIT_NICE") else 0
    if limit == resource.RLIM_INFINITY or limit >= 20 - nice:
        return True
    return _has_cap_sys_nice()


class Priority:
    """The priority of one child process ``pid``: :data:`NICE_INCREMENT` nicer than this
    process; :meth:`go_idle` makes it ``SCHED_IDLE`` too, if it can be promoted back (see
    the module docstring). Never raises: a priority the system refuses leaves the child
    as it was."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.idle = False          # the child is SCHED_IDLE now
        self.promoted = False      # it was idle and was promoted back
        nice = min(19, os.getpriority(os.PRIO_PROCESS, 0) + NICE_INCREMENT)
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, pid, nice)

    def go_idle(self) -> bool:
        """``SCHED_IDLE`` from now until :meth:`promote`, if the system lets it be
        promoted back and :data:`IDLE_ENV` allows it. Call it once the child has started:
        an idle child's imports would wait for a busy machine to go quiet. True if the
        child is idle."""
        if not self.idle and not self.promoted and idle_enabled():
            with contextlib.suppress(OSError):
                if can_promote(os.getpriority(os.PRIO_PROCESS, self.pid)):
                    self.idle = _set_policy(self.pid, os.SCHED_IDLE) > 0
        return self.idle

    def promote(self) -> bool:
        """Back to ``SCHED_OTHER`` at its nice value, for the rest of its life: the child fell
        behind (its pipe stayed full), or the flight is over and waits for it. True if
        this call promoted it."""
        if not self.idle:
            return False
        self.idle = False
        self.promoted = _set_policy(self.pid, os.SCHED_OTHER) > 0
        return self.promoted


def _set_policy(pid: int, policy: int) -> int:
    """``policy`` for every thread of process ``pid`` (the policy is per thread, and the
    child's recorder starts a flush thread before it reports ready); the number of threads
    set (0: the process is gone or refused)."""
    try:
        tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except (OSError, ValueError):
        tids = [pid]
    done = 0
    for tid in tids:
        with contextlib.suppress(OSError):       # a thread (or the child) just ended
            os.sched_setscheduler(tid, policy, os.sched_param(0))
            done += 1
    return done
