"""The vehicle's two clocks: lockstep (default) and real time (docs/design.md, "Time").

Both run the same tick: HEARTBEAT to the controller on every whole second of sim time, then
the tick's state (:mod:`tfl_mav.sitl.state_report`), then wait for the controller's command, then
integrate one control period. They differ only in what they wait for.

**Lockstep** (:class:`LockstepClock`). Tick k: send ``ODOMETRY`` (``time_usec`` = k·T,
LOCAL_NED pose, BODY_FRD twist) and ``ESC_TELEMETRY_1_TO_4`` (true rotor speed as the ESC
measures it) in one datagram, ODOMETRY first (:meth:`~tfl_mav.link.transport.Link.send_many`),
wait for ``HIL_ACTUATOR_CONTROLS`` whose ``time_usec`` equals k·T, apply it, integrate to
k+1. Replies for another ``time_usec`` are counted (``stale_controls``) and ignored. No reply
within ``resend_interval_s`` (wall time, default 5 ms, ~10 idle round trips) sends the state
again, quietly (``lockstep_resends``): a lost datagram costs milliseconds, not the timeout
(the controller answers a resent state with the same command, never a second step). Further
resends of the same tick back off, doubling up to 4× that (the ~20 ms that keeps a flood's
stall near 1×), so a stalled controller is not sent 200 states a second. Measured under load
(bench/bench_lockstep.py's full loop, 2 cores, load 5): ~0.1 % of ticks resent, so a
longer first interval would buy nothing and cost every lost datagram more. No reply within
``lockstep_timeout_s`` is counted (``lockstep_timeouts``) and announced by STATUSTEXT (rate
limited, with the count suppressed); the tick is never skipped, so a lockstep run is
deterministic and runs as fast as both processes allow. The control port's HEARTBEAT is
paced by sim time (every 1 s of it), so the control port's traffic is a pure function of the
scenario and the controller's replies. The loop is serial, so only the work from the reply
to the next state delays it: that stretch is apply, integrate, the power model and the crash
check, then the state on the wire; the recorder's hooks are queued meanwhile and handed
over, in order, with the GCS port's traffic, while the controller computes
(bench/bench_vehicle_tick.py times both stretches).

**Real time** (:class:`RealtimeClock`). Sim time starts only once commands flow: after the
controller's HEARTBEAT the vehicle sends the t = 0 state every 10 ms (time not advancing,
``start_wait_states``) until the first valid HIL_ACTUATOR_CONTROLS for it is applied, so a
controller still warming up costs nothing. Then physics follows the wall clock; the latest
valid command is held (zero-order hold, :class:`HeldCommand`); replies not newer than the
held one are ``stale``, replies applied after their own tick was integrated are ``late``
(``late_controls``), and the vehicle keeps histograms of the command age at application and
of the held command's age at every control period (``command_age``, ``held_age``). The
rotors start at hover thrust (part of the initial state). If, after the first command, no
valid command arrives for ``command_timeout_s`` the vehicle does what
a real ESC does when its signal stops: **the motors are cut to zero thrust** (counted in
``command_timeouts``, STATUSTEXT EMERGENCY); the next valid command restores them. Falling
behind the wall clock by more than 0.1 s re-anchors the clock (counted in ``overruns``)
instead of racing to catch up.

The clocks are pacing policy only, as PX4's lockstep scheduler holds sim time and not the
simulator's loop: :class:`~tfl_mav.sitl.vehicle.Vehicle` runs the loop and owns what it
drives (simulator, links, recorder hand-off, counters, STATUSTEXT), and asks its clock only
*when*: when a silent tick's state is resent, reported or given up
(:meth:`LockstepClock.silence`), when the next control period is due and when silence cuts
the motors, ends the run or re-anchors the clock (:class:`RealtimeClock`). Each clock's
state is its own (the current tick's wait, the anchor) and its decisions are small methods
of the wall time it is given, so pacing can change without touching what goes on the wire.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntFlag

__all__ = ["GCS_POLL_S", "RESEND_SPAN", "START_RESEND_S", "WAIT_SLICE_S", "HeldCommand",
           "LockstepClock", "RealtimeClock", "Silence"]

WAIT_SLICE_S = 0.05   # longest uninterrupted wait: bounds the reaction to Vehicle.stop()
_OVERRUN_S = 0.1      # real time: re-anchor the clock when this far behind
START_RESEND_S = 0.01  # real time: the t = 0 state is resent this often until commands flow
RESEND_SPAN = 4       # lockstep: later resends of one tick back off to 4 × the first interval
GCS_POLL_S = 0.01     # lockstep: the GCS port is read this often (wall), not every tick


@dataclass
class HeldCommand:
    """The rotor command the motors hold, and since when.

    Written by :class:`~tfl_mav.sitl.commands.ActuatorControls` when it applies or cuts a command;
    read by the vehicle's real-time loop (how long the controller has been silent, which it
    hands to :class:`RealtimeClock`) and the GCS telemetry (motor health).
    """

    time_usec: int = -1       # time_usec of the newest applied HIL_ACTUATOR_CONTROLS (-1: none)
    since_s: float = 0.0      # wall time (time.monotonic) it was applied
    motors_cut: bool = False  # real time: cut to zero thrust after command_timeout_s silence
    armed: bool = True        # False after a disarming command (zero thrust)
    # A GCS disarm overrode the command to zero thrust: set at the disarm and whenever a
    # command is applied while disarmed, cleared only by a command applied after the GCS
    # armed again (until then the motors still hold the zero, whatever time_usec says).
    killed: bool = False

    @property
    def driven(self) -> bool:
        """The motors are driven by a command (or, before the first, by the initial hover);
        False when cut, disarmed by the controller or killed by a GCS."""
        return not (self.motors_cut or self.killed or not self.armed)

    @property
    def applied_usec(self) -> int:
        """What ACTUATOR_OUTPUT_STATUS.time_usec says the motors held: this command's
        time_usec, or 0 when none drives them (none yet, cut, disarmed, killed)."""
        return 0 if self.time_usec < 0 or not self.driven else self.time_usec


class Silence(IntFlag):
    """What a lockstep tick's silence calls for now (:meth:`LockstepClock.silence`); the
    vehicle acts in this order: LOST ends the run, TIMED_OUT is counted and announced, RESEND
    sends the state again."""

    NOTHING = 0
    LOST = 1        # silent past peer_timeout_s: the controller is gone
    TIMED_OUT = 2   # silent for another timeout_s: count, STATUSTEXT, HEARTBEAT
    RESEND = 4      # the state again (the resend interval backs off, doubling)


_NOTHING, _LOST, _TIMED_OUT, _RESEND = (Silence.NOTHING, Silence.LOST, Silence.TIMED_OUT,
                                        Silence.RESEND)


class LockstepClock:
    """Lockstep pacing: sim time advances only when the controller has answered the current
    tick; this says how long to wait and what a silence calls for.

    Its state is the current tick's wait (wall times, ``time.monotonic`` seconds), set by
    :meth:`start` and advanced by :meth:`silence`.
    """

    __slots__ = ("_deadline_s", "_interval_s", "_resend_at_s", "_since_s", "peer_timeout_s",
                 "resend_max_s", "resend_s", "timeout_s")

    def __init__(self, timeout_s: float, resend_s: float = 0.005,
                 peer_timeout_s: float | None = None) -> None:
        self.timeout_s = timeout_s   # wall seconds without a reply before reporting it
        # wall seconds without a reply before the run ends (PEER_LOST); None: wait for a
        # restarted controller however long it takes
        self.peer_timeout_s = peer_timeout_s
        self.resend_s = min(resend_s, timeout_s)   # wall seconds before the first resend
        self.resend_max_s = min(RESEND_SPAN * resend_s, timeout_s)   # ... the later ones
        self._since_s = self._deadline_s = self._resend_at_s = 0.0
        self._interval_s = self.resend_s

    def start(self, now_s: float) -> None:
        """The tick's state went out at wall time ``now_s``: its wait begins."""
        self._since_s = now_s
        self._deadline_s = now_s + self.timeout_s
        self._interval_s = self.resend_s
        self._resend_at_s = now_s + self.resend_s

    def slice_s(self, now_s: float) -> float:
        """How long the next receive may block: until the next resend, at most
        ``WAIT_SLICE_S`` (the reaction time to a stop)."""
        wait_s = self._resend_at_s - now_s
        return wait_s if wait_s < WAIT_SLICE_S else WAIT_SLICE_S

    def silence(self, now_s: float) -> Silence:
        """No reply yet at ``now_s``: what is due (and the next deadlines, if any fired)."""
        peer_timeout = self.peer_timeout_s
        if peer_timeout is not None and now_s - self._since_s > peer_timeout:
            return _LOST
        due = _NOTHING
        if now_s >= self._deadline_s:
            due |= _TIMED_OUT
            self._deadline_s = now_s + self.timeout_s
        if now_s >= self._resend_at_s:
            due |= _RESEND
            self._interval_s = min(2.0 * self._interval_s, self.resend_max_s)   # as TCP does
            self._resend_at_s = now_s + self._interval_s
        return due

    def lost_reason(self, now_s: float) -> str:
        """Why the run ends PEER_LOST at ``now_s``."""
        return (f"no HIL_ACTUATOR_CONTROLS for {now_s - self._since_s:.1f} s (over "
                f"--peer-timeout {self.peer_timeout_s:g} s): the controller is gone")

    def timeout_text(self, time_usec: int) -> str:
        """The STATUSTEXT for a tick whose reply is ``timeout_s`` late."""
        return (f"lockstep: no HIL_ACTUATOR_CONTROLS for time_usec {time_usec} "
                f"within {self.timeout_s:g} s; state resent every "
                f"{1000 * self.resend_s:g}-{1000 * self.resend_max_s:g} ms")


class RealtimeClock:
    """Real-time pacing: sim time follows the wall clock from an anchor; this says when the
    next control period is due and what the controller's silence or a late period calls for.

    Its state is the anchor: wall time ``t0`` (``time.monotonic`` seconds) at which tick
    ``k0`` began, so tick k ends at t0 + (k + 1 − k0)·T.
    """

    __slots__ = ("_k0", "_t0_s", "command_timeout_s", "control_dt_s", "peer_timeout_s")

    def __init__(self, control_dt_s: float, command_timeout_s: float,
                 peer_timeout_s: float | None = None) -> None:
        self.control_dt_s = control_dt_s             # T, sim seconds a control period
        self.command_timeout_s = command_timeout_s   # wall seconds of silence → motors cut
        self.peer_timeout_s = peer_timeout_s         # ... → the run ends (None: never)
        self._t0_s = 0.0
        self._k0 = 0

    def start(self, now_s: float) -> None:
        """Sim time starts at wall time ``now_s`` (the first command applied), at tick 0."""
        self._t0_s, self._k0 = now_s, 0

    def due_s(self, ticks: int) -> float:
        """Wall time at which the control period after ``ticks`` periods ends."""
        return self._t0_s + (ticks + 1 - self._k0) * self.control_dt_s

    def cuts_motors(self, silent_s: float, motors_cut: bool) -> bool:
        """Whether ``silent_s`` wall seconds since the last valid command cut the motors now
        (an ESC whose signal stopped)."""
        return not motors_cut and silent_s > self.command_timeout_s

    def lost_reason(self, silent_s: float, motors_cut: bool) -> str | None:
        """Why the run ends PEER_LOST after ``silent_s`` of silence, or None (it goes on)."""
        peer_timeout = self.peer_timeout_s
        if motors_cut and peer_timeout is not None and silent_s > peer_timeout:
            return (f"no valid HIL_ACTUATOR_CONTROLS for {silent_s:.1f} s (over "
                    f"--peer-timeout {peer_timeout:g} s): the controller is gone")
        return None

    def overrun(self, now_s: float, due_s: float, ticks: int) -> str | None:
        """After the period due at ``due_s`` was integrated (``ticks`` periods flown): if it
        ran more than 0.1 s late, re-anchor at ``now_s`` instead of racing to catch up and
        return the STATUSTEXT; else None."""
        if now_s - due_s > _OVERRUN_S:
            self._t0_s, self._k0 = now_s, ticks
            return (f"real time: physics fell {now_s - due_s:.3f} s behind the wall "
                    "clock; clock re-anchored")
        return None
