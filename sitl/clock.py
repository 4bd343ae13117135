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

A clock drives the vehicle only through :class:`Paced`, so pacing can change without
touching what goes on the wire.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Protocol

from tfl_mav.link.dialect import mav
from tfl_mav.link.transport import Link
from tfl_mav.sitl.results import ExitStatus, VehicleStats
from tfl_mav.sitl.simulator import Simulator

__all__ = ["GCS_POLL_S", "RESEND_SPAN", "START_RESEND_S", "WAIT_SLICE_S", "Clock", "HeldCommand",
           "LockstepClock", "Paced", "RealtimeClock"]

WAIT_SLICE_S = 0.05   # longest uninterrupted wait: bounds the reaction to Vehicle.stop()
_OVERRUN_S = 0.1      # real time: re-anchor the clock when this far behind
START_RESEND_S = 0.01  # real time: the t = 0 state is resent this often until commands flow
RESEND_SPAN = 4       # lockstep: later resends of one tick back off to 4 × the first interval
GCS_POLL_S = 0.01     # lockstep: the GCS port is read this often (wall), not every tick
_monotonic = time.monotonic


@dataclass
class HeldCommand:
    """The rotor command the motors hold, and since when.

    Written by :class:`~tfl_mav.sitl.commands.ActuatorControls` when it applies or cuts a command;
    read by the clocks (real time: how long the controller has been silent) and the GCS
    telemetry (motor health).
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


class Paced(Protocol):
    """What a clock drives (implemented by :class:`~tfl_mav.sitl.vehicle.Vehicle`)."""

    sim: Simulator
    stats: VehicleStats
    held: HeldCommand
    control_link: Link

    def send_heartbeat(self) -> None:
        """HEARTBEAT to the controller."""

    def publish_state(self) -> None:
        """Build the current tick's state and send it to the controller."""

    def resend_state(self) -> None:
        """Send the current tick's state again."""

    def dispatch(self, msg: Any, awaited_usec: int | None) -> bool:
        """Handle one message from the control port; True if it is the reply that completes
        the awaited tick (lockstep, ``awaited_usec`` given)."""

    def gcs_periodic(self) -> None:
        """GCS telemetry and HEARTBEAT, if due (nothing without a GCS)."""

    def serve_gcs(self) -> None:
        """Handle what the GCS sent (nothing without a GCS)."""

    def wait(self, timeout_s: float) -> None:
        """Sleep until a datagram arrives on either port or ``timeout_s`` passes."""

    def stopped(self) -> bool:
        """True once a stop was requested."""

    def step(self) -> str | None:
        """Integrate one control period; the crash reason, if any."""

    def defer_recording(self, defer: bool) -> None:
        """Queue the recorder hooks (True) or hand them over and call them at once again."""

    def hand_off(self) -> None:
        """Call the queued recorder hooks, in order (the simulator is as it was queued)."""

    def status(self, severity: int, text: str, *, key: str | None = None) -> None:
        """STATUSTEXT to both peers (rate-limited per ``key``)."""

    def cut_motors(self, silent_s: float, timeout_s: float) -> None:
        """Real-time link loss: zero thrust until the next valid command."""


class Clock(Protocol):
    def run(self, n_ticks: float) -> tuple[ExitStatus, str]:
        """Fly ``n_ticks`` control periods (``math.inf``: until stopped or crashed)."""
        ...


class LockstepClock:
    """Sim time advances only when the controller has answered the current tick."""

    def __init__(self, vehicle: Paced, timeout_s: float, resend_s: float = 0.005,
                 peer_timeout_s: float | None = None) -> None:
        self.vehicle = vehicle
        self.timeout_s = timeout_s   # wall seconds without a reply before reporting it
        # wall seconds without a reply before the run ends (PEER_LOST); None: wait for a
        # restarted controller however long it takes
        self.peer_timeout_s = peer_timeout_s
        self.lost = ""               # why the run ended PEER_LOST
        self.resend_s = min(resend_s, timeout_s)   # wall seconds before the first resend
        self.resend_max_s = min(RESEND_SPAN * resend_s, timeout_s)   # ... the later ones
        self._next_gcs_s = 0.0       # wall time the GCS port is next read

    def run(self, n_ticks: float) -> tuple[ExitStatus, str]:
        """The tick, ordered for the critical path: the reply k → apply → integrate → the
        HEARTBEAT if due and the state k+1 on the wire; then, while the controller
        computes, what only reports on the tick (recorder hand-off, GCS). Same messages,
        same order on each port as "state, GCS, wait, step" (the recorder's calls are
        queued in between and handed over in order: :meth:`Paced.hand_off`)."""
        v = self.vehicle
        sim = v.sim
        stats = v.stats
        ticks_per_heartbeat = max(1, round(1.0 / sim.control_dt_s))
        if stats.ticks >= n_ticks:
            return ExitStatus.COMPLETED, f"ran {sim.time_s:.3f} s of sim time"
        v.defer_recording(True)
        # bound once: every tick calls each of them
        gcs_periodic, await_reply = v.gcs_periodic, self._await_reply
        step, publish_state = v.step, v.publish_state
        try:
            if stats.ticks % ticks_per_heartbeat == 0:
                v.send_heartbeat()
            publish_state()
            while True:
                gcs_periodic()
                if not await_reply(sim.time_usec):
                    if self.lost:
                        return ExitStatus.PEER_LOST, self.lost
                    return ExitStatus.STOPPED, "stopped on request"
                # --- critical path: reply consumed → next state sent
                crash = step()
                if crash is not None:
                    return ExitStatus.CRASHED, crash
                ticks = stats.ticks
                if ticks >= n_ticks:
                    return ExitStatus.COMPLETED, f"ran {sim.time_s:.3f} s of sim time"
                if ticks % ticks_per_heartbeat == 0:
                    v.send_heartbeat()
                publish_state()
                # --- the controller computes from here: report on the tick
        finally:
            v.defer_recording(False)

    def _await_reply(self, time_usec: int) -> bool:
        """Block until the reply for ``time_usec`` is consumed; False if stopped.

        The wait is the control link's ``recvfrom`` itself (no select). Before each wait:
        the recorder hand-off, and the GCS port, read every ``GCS_POLL_S`` of wall time,
        not on every tick (a GCS is a person): both while the controller computes, so
        the consumed reply goes straight on to the next state."""
        v = self.vehicle
        ctl = v.control_link
        dispatch = v.dispatch
        now = _monotonic()
        since = now
        deadline = now + self.timeout_s
        interval = self.resend_s
        resend_at = now + interval
        while True:
            v.hand_off()      # the recorder's share of the tick
            if now >= self._next_gcs_s:
                self._next_gcs_s = now + GCS_POLL_S
                v.serve_gcs()
            awaited = time_usec
            # One datagram a pass: the reply comes alone, and the loop reads what follows.
            wait_s = resend_at - now
            for msg in ctl.recv(wait_s if wait_s < WAIT_SLICE_S else WAIT_SLICE_S,
                                drain=False):
                # Handle the whole batch (a command may follow the reply); once the reply
                # is consumed, a duplicate for the same tick is stale (-1 matches nothing).
                if dispatch(msg, awaited):
                    awaited = -1
            if awaited == -1:
                return True
            now = _monotonic()
            if v.stopped():
                return False
            peer_timeout = self.peer_timeout_s
            if peer_timeout is not None and now - since > peer_timeout:
                self.lost = (f"no HIL_ACTUATOR_CONTROLS for {now - since:.1f} s (over "
                             f"--peer-timeout {peer_timeout:g} s): the controller is gone")
                return False
            if now >= deadline:
                v.stats.lockstep_timeouts += 1
                v.status(mav.MAV_SEVERITY_WARNING,
                         f"lockstep: no HIL_ACTUATOR_CONTROLS for time_usec {time_usec} "
                         f"within {self.timeout_s:g} s; state resent every "
                         f"{1000 * self.resend_s:g}-{1000 * self.resend_max_s:g} ms",
                         key="lockstep_timeout")
                v.send_heartbeat()
                deadline = now + self.timeout_s
            if now >= resend_at:
                v.stats.lockstep_resends += 1
                v.resend_state()
                interval = min(2.0 * interval, self.resend_max_s)   # back off, as TCP does
                resend_at = now + interval
                v.gcs_periodic()


class RealtimeClock:
    """Sim time follows the wall clock; the latest valid command is held."""

    def __init__(self, vehicle: Paced, command_timeout_s: float,
                 peer_timeout_s: float | None = None) -> None:
        self.vehicle = vehicle
        self.command_timeout_s = command_timeout_s   # wall seconds of silence → motors cut
        self.peer_timeout_s = peer_timeout_s         # ... → the run ends (None: never)

    def run(self, n_ticks: float) -> tuple[ExitStatus, str]:
        v = self.vehicle
        sim = v.sim
        stats = v.stats
        held = v.held
        dt = sim.control_dt_s
        ticks_per_heartbeat = max(1, round(1.0 / dt))
        ctl = v.control_link
        if not self._await_first_command():
            return ExitStatus.STOPPED, "stopped on request"
        t0 = time.monotonic()   # sim time starts with the first command applied
        k0 = 0                  # tick at which the clock was last anchored at t0
        first = True
        while stats.ticks < n_ticks:
            if not first:
                if stats.ticks % ticks_per_heartbeat == 0:
                    v.send_heartbeat()
                v.publish_state()
            first = False
            target = t0 + (stats.ticks + 1 - k0) * dt
            while True:
                for msg in ctl.recv(0.0):
                    v.dispatch(msg, None)
                v.gcs_periodic()
                v.serve_gcs()
                if v.stopped():
                    return ExitStatus.STOPPED, "stopped on request"
                now = time.monotonic()
                if now >= target:
                    break
                v.wait(min(WAIT_SLICE_S, target - now))
            if not held.motors_cut and now - held.since_s > self.command_timeout_s:
                v.cut_motors(now - held.since_s, self.command_timeout_s)
            if held.motors_cut and self.peer_timeout_s is not None \
                    and now - held.since_s > self.peer_timeout_s:
                return ExitStatus.PEER_LOST, (
                    f"no valid HIL_ACTUATOR_CONTROLS for {now - held.since_s:.1f} s (over "
                    f"--peer-timeout {self.peer_timeout_s:g} s): the controller is gone")
            stats.held_age.add(sim.time_usec - held.time_usec)
            crash = v.step()
            if crash is not None:
                return ExitStatus.CRASHED, crash
            if now - target > _OVERRUN_S:
                stats.overruns += 1
                t0, k0 = now, stats.ticks
                v.status(mav.MAV_SEVERITY_WARNING,
                         f"real time: physics fell {now - target:.3f} s behind the wall "
                         "clock; clock re-anchored", key="overrun")
        return ExitStatus.COMPLETED, f"ran {sim.time_s:.3f} s of sim time"

    def _await_first_command(self) -> bool:
        """Send the t = 0 state every ``START_RESEND_S`` until a valid command for it is
        applied; False if stopped first. Sim time has not started, so a controller that is
        slow to start costs nothing and the command timeout cannot cut the motors."""
        v = self.vehicle
        ctl = v.control_link
        held = v.held
        next_heartbeat = next_state = 0.0
        first = True
        while held.time_usec < 0:
            now = time.monotonic()
            if now >= next_heartbeat:
                v.send_heartbeat()
                next_heartbeat = now + 1.0
            if now >= next_state:
                if first:
                    v.publish_state()
                    first = False
                else:
                    v.resend_state()
                v.stats.start_wait_states += 1
                next_state = now + START_RESEND_S
            v.wait(min(WAIT_SLICE_S, max(0.0, next_state - time.monotonic())))
            for msg in ctl.recv(0.0):
                v.dispatch(msg, None)
            v.gcs_periodic()
            v.serve_gcs()
            if v.stopped():
                return False
        return True
