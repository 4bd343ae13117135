"""The simulated vehicle's MAVLink endpoint (docs/design.md, "The wire" and "Time").

One :class:`Vehicle` owns a :class:`~tfl_mav.sitl.simulator.Simulator` and two links:

* the **control port** (``listen``): the offboard controller. PX4's convention: before the
  flight the vehicle announces itself by HEARTBEAT to ``announce`` (``tfl-mav sim``:
  127.0.0.1:14540, where mavsdk's ``udpin://:14540`` or ``tfl-mav fly`` listens). The
  controller is the first sender that *identifies as an offboard controller* (HEARTBEAT
  ``type`` ``MAV_TYPE_ONBOARD_CONTROLLER`` or component ``MAV_COMP_ID_ONBOARD_COMPUTER``), or
  whoever ``peer`` pins; any other HEARTBEAT (a GCS saying hello) is refused, counted
  (``controllers_refused``) and told why by STATUSTEXT (at most once a second per sender).
  The pin holds once it sends HIL_ACTUATOR_CONTROLS; a learned candidate that sends none
  within ``lockstep_timeout_s`` of the first state (lockstep) is released
  (``controllers_released``) and the next qualifying sender takes the link. Everything else
  is counted and dropped by :class:`~tfl_mav.link.transport.Link`.
* the optional **GCS port** (``gcs``): a separate socket that sends to a ground station
  (MAVProxy, QGroundControl, mavsdk) and accepts its commands. The controller's STATUSTEXT
  (its safety events: attack detected, safe law, handed back) is forwarded there unchanged,
  so the GCS hears them with the controller's ids and severities.

The vehicle wires the parts together and runs the flight; each part has its own module:

* :mod:`tfl_mav.sitl.clock` — lockstep (default) and real-time pacing (when to step, resend,
  cut the motors), and the held command;
* :mod:`tfl_mav.sitl.commands` — HIL_ACTUATOR_CONTROLS and COMMAND_LONG/COMMAND_INT;
* :mod:`tfl_mav.sitl.state_report` — the per-tick ODOMETRY, ACTUATOR_OUTPUT_STATUS (which command
  the rpm answer) and ESC_TELEMETRY_1_TO_4;
* :mod:`tfl_mav.sitl.gcs` — HEARTBEAT, STATUSTEXT and the GCS telemetry;
* :mod:`tfl_mav.sitl.ground` — what a GCS may command (arm/disarm, mode, parameters, mission, home);
* :mod:`tfl_mav.sitl.results` — the outcome and counters of a run.

**Start.** Until the controller's first HEARTBEAT arrives the vehicle waits: sim time does
not advance, it sends HEARTBEAT at 1 Hz to the GCS and to a pinned ``peer`` (or, with none,
to ``announce``), and it answers commands on either port. The flight starts the moment an
admitted controller's HEARTBEAT arrives.

**End.** The run ends when the duration is reached (:attr:`ExitStatus.COMPLETED`), when the
simulator reports a crash (:attr:`ExitStatus.CRASHED`: STATUSTEXT EMERGENCY with the reason,
HEARTBEAT ``MAV_STATE_EMERGENCY``) or on :meth:`Vehicle.stop` (:attr:`ExitStatus.STOPPED`).
A last HEARTBEAT with ``MAV_STATE_POWEROFF`` (or EMERGENCY after a crash), sent three times
10 ms apart so one lost datagram cannot hide the end, tells both peers.

**Signing** (``key``, 32 bytes): both ports sign everything they send (control port
``link_id`` 0, GCS port ``link_id`` 1) and accept only frames that verify, with one
replay-protection state shared by both ports (:mod:`tfl_mav.link.signing`). The GCS port
is signed too because MAV_CMD_INJECT_FAILURE moves a motor: a GCS without the key still
reads the telemetry but cannot command. Until the controller connects, frames refused for
their signature on the control port are reported by STATUSTEXT (at most once a second), so
a key mismatch is visible at once.

**Recorder hooks.** ``on_frame(direction, raw, msg, time_s)`` is given to both links (every
frame, both directions, exact bytes); ``on_truth(sim)`` is called with the simulator at every
control tick's state: once for the initial state and once after each step.
:func:`truth_hook` makes one from a flight recorder. In lockstep the hooks run off the
critical path (:mod:`tfl_mav.sitl.recording`): the same calls in the same order, only later.

Single-threaded: :meth:`Vehicle.run` must be called from one thread; :meth:`Vehicle.stop` is
safe from any thread or a signal handler.
"""

from __future__ import annotations

import gc
import math
import select
import threading
import time
from collections.abc import Callable
from typing import Any

from tfl_mav.link.dialect import mav
from tfl_mav.link.signing import Signing
from tfl_mav.link.transport import Address, FrameHook, Link
from tfl_mav.scenario import Scenario
from tfl_mav.sitl.clock import (
    GCS_POLL_S,
    START_RESEND_S,
    WAIT_SLICE_S,
    HeldCommand,
    LockstepClock,
    RealtimeClock,
    Silence,
)
from tfl_mav.sitl.commands import CONTROL_TOLERANCE, ActuatorControls, CommandHandler, Outcome
from tfl_mav.sitl.gcs import FlightStatus, GcsTelemetry, Origin, StatusText
from tfl_mav.sitl.ground import GroundCommands
from tfl_mav.sitl.power import PowerModel
from tfl_mav.sitl.recording import HandOff, TruthSink, truth_hook
from tfl_mav.sitl.results import ExitStatus, VehicleResult, VehicleStats
from tfl_mav.sitl.simulator import Simulator
from tfl_mav.sitl.state_report import StateReport

__all__ = [
    "CONTROL_TOLERANCE",
    "ExitStatus",
    "TruthSink",
    "Vehicle",
    "VehicleResult",
    "VehicleStats",
    "truth_hook",
]

_ID_HEARTBEAT = mav.MAVLINK_MSG_ID_HEARTBEAT
_ID_HIL_ACTUATOR_CONTROLS = mav.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS
# The daemon's own telemetry (tfl_mav.controller.daemon, ≤ 50 Hz): the vehicle only records it, so
# the control link checks and counts those frames but does not decode them.
_IGNORED_IDS = (mav.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT, mav.MAVLINK_MSG_ID_DEBUG_FLOAT_ARRAY)
_ID_STATUSTEXT = mav.MAVLINK_MSG_ID_STATUSTEXT
_STALE = Outcome.STALE   # an Enum member through its class costs ~10× a global (3.11)
_CONTROL_LINK_ID, _GCS_LINK_ID = 0, 1      # MAVLink signing link ids of our two ports
_FINAL_HEARTBEATS, _FINAL_HEARTBEAT_GAP_S = 3, 0.01   # the last HEARTBEAT, sent 3 times
_REFUSAL_INTERVAL_S = 1.0                   # STATUSTEXT to one refused sender at most 1/s
_LOST, _TIMED_OUT, _RESEND = Silence.LOST, Silence.TIMED_OUT, Silence.RESEND
_monotonic = time.monotonic


class Vehicle:
    """A simulated quadrotor on UDP. See the module docstring for the protocol."""

    def __init__(self, scenario: Scenario, *, listen: Address,
                 gcs: Address | None = None, peer: Address | None = None,
                 announce: Address | None = None, origin: Origin | None = None,
                 realtime: bool = False, lockstep_timeout_s: float = 2.0,
                 resend_interval_s: float = 0.005,
                 command_timeout_s: float = 0.25, gcs_rate_hz: float = 50.0,
                 allow_failure_injection: bool = True, sysid: int = 1, compid: int = 1,
                 key: bytes | None = None, on_frame: FrameHook | None = None,
                 on_truth: Callable[[Simulator], None] | None = None,
                 on_status: Callable[[int, str], None] | None = None,
                 on_frames: Callable[..., None] | None = None,
                 peer_timeout_s: float | None = None) -> None:
        """Bind the sockets (raises :class:`~tfl_mav.link.transport.LinkError`) and build the sim.

        ``listen``: control port to bind (port 0 = ephemeral, see :attr:`listen_address`).
        ``gcs``: where a ground station listens, or None. ``peer``: pin the controller's
        address instead of learning it. ``announce``: where to send HEARTBEAT before a
        controller is known (PX4: the API port), or None. ``origin``: the local frame's
        place on Earth (GLOBAL_POSITION_INT, HOME_POSITION). ``lockstep_timeout_s``/
        ``command_timeout_s``/``resend_interval_s``: wall seconds (see :mod:`tfl_mav.sitl.clock`).
        ``gcs_rate_hz``: GCS telemetry rate, at most
        50 Hz. ``key``: 32-byte MAVLink 2 signing secret for both ports, or None (unsigned).
        ``on_status(severity, text)`` sees every STATUSTEXT the vehicle sends.
        ``peer_timeout_s``: end the flight (:attr:`ExitStatus.PEER_LOST`) when the
        controller has sent no command for this many wall seconds; None (default) waits
        for a restarted controller.
        ``on_frames(direction, raws, msgs, time_s)``: beside ``on_frame``, a datagram's
        per-tick frames in one call (e.g. ``RecorderProcess.on_frames``: one hand-off item
        a datagram, not one a frame).
        """
        for name, value in (("lockstep_timeout_s", lockstep_timeout_s),
                            ("command_timeout_s", command_timeout_s),
                            ("resend_interval_s", resend_interval_s),
                            ("peer_timeout_s", 1.0 if peer_timeout_s is None
                             else peer_timeout_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: must be a positive number of seconds, got {value}")
        if not (math.isfinite(gcs_rate_hz) and 0 < gcs_rate_hz <= 50):
            raise ValueError(f"gcs_rate_hz: must be in (0, 50] Hz, got {gcs_rate_hz}")
        self.scenario = scenario
        self.sim = Simulator(scenario)
        self.recording = HandOff(self.sim, on_frame, on_truth,
                                 on_frames if on_frame is not None else None)
        hook = self.recording.frame if on_frame is not None else None
        # The links.
        self.signing = Signing(key) if key is not None else None
        self.announce = announce
        self._pinned = peer is not None
        self._refused_at: dict[Address, float] = {}   # sender → wall time last told why
        self._confirmed = False      # the controller has sent HIL_ACTUATOR_CONTROLS
        self._flight_wall0 = 0.0
        self.lockstep_timeout_s = lockstep_timeout_s
        self.control_link = Link.listen(listen, src_system=sysid, src_component=compid,
                                        peer=peer, on_frame=hook, signing=self.signing,
                                        link_id=_CONTROL_LINK_ID, admit=self._admit,
                                        skim_ids=_IGNORED_IDS)
        self.gcs_link: Link | None = None
        if gcs is not None:
            try:
                self.gcs_link = Link.connect(gcs, src_system=sysid, src_component=compid,
                                             on_frame=hook, signing=self.signing,
                                             link_id=_GCS_LINK_ID)
            except Exception:
                self.control_link.close()
                raise
        self._fds = [link.fileno() for link in (self.control_link, self.gcs_link) if link]
        if self.recording.on_frames is not None:
            for link in (self.control_link, self.gcs_link):
                if link is not None:
                    link.on_frames = self.recording.frames
        self.stats = VehicleStats(control_link=self.control_link.stats,
                                  gcs_link=self.gcs_link.stats if self.gcs_link else None)
        v = scenario.vehicle
        self.power = PowerModel(drag_thrust_ratio_m=v.drag_thrust_ratio_m, k_f=v.k_f)
        self.power.step(self.sim.motors.omega_radps, 0.0)
        # The parts (each module's docstring says what it does on the wire).
        self.flight = FlightStatus()
        self.held = HeldCommand()
        self.statustext = StatusText((self.control_link, self.gcs_link), self.stats, on_status)
        self.report = StateReport(self.sim, self.power, scenario.sensors)
        self.controls = ActuatorControls(self.sim, stats=self.stats, held=self.held,
                                         flight=self.flight, status=self.statustext)
        self.commands = CommandHandler(self.sim, stats=self.stats, status=self.statustext,
                                       sysid=sysid, compid=compid,
                                       allow_failure_injection=allow_failure_injection)
        self.origin = origin or Origin()
        self.ground = GroundCommands(scenario, self.sim, flight=self.flight, stats=self.stats,
                                     status=self.statustext, origin=self.origin, sysid=sysid,
                                     compid=compid, held=self.held)
        self.ground.register(self.commands)
        self.sim.attacker.on_nonfinite = self._attack_nonfinite
        self.commands.routes[_ID_STATUSTEXT] = self._forward_statustext
        self.gcs = (GcsTelemetry(self.gcs_link, 1.0 / gcs_rate_hz, sim=self.sim,
                                 power=self.power, stats=self.stats, held=self.held,
                                 flight=self.flight, report=self.report, origin=self.origin,
                                 sim_time=not realtime)
                    if self.gcs_link is not None else None)
        self.clock: LockstepClock | RealtimeClock = (
            RealtimeClock(self.sim.control_dt_s, command_timeout_s, peer_timeout_s) if realtime
            else LockstepClock(lockstep_timeout_s, resend_interval_s, peer_timeout_s))
        self._next_gcs_s = 0.0       # lockstep: wall time the GCS port is next read
        # The run's phase.
        self._stop = threading.Event()
        self._external_stop: threading.Event | None = None
        self._ran = False
        self._controller_seen = False
        self._flying = False
        self._refused_reported = 0   # signing refusals already announced before the flight

    # ------------------------------------------------------------------ lifecycle
    @property
    def on_truth(self) -> Callable[[Simulator], None] | None:
        return self.recording.on_truth

    @on_truth.setter
    def on_truth(self, hook: Callable[[Simulator], None] | None) -> None:
        self.recording.on_truth = hook

    @property
    def listen_address(self) -> Address:
        """The control port actually bound (resolves an ephemeral port 0)."""
        return self.control_link.local_address

    @property
    def gcs_local_address(self) -> Address | None:
        """The GCS socket's own address (where a GCS's replies arrive), or None."""
        return self.gcs_link.local_address if self.gcs_link is not None else None

    @property
    def controller_address(self) -> Address | None:
        """The controller's address once known (learned or pinned)."""
        return self.control_link.peer

    def stop(self) -> None:
        """Ask :meth:`run` to end soon (within ~50 ms). Safe from threads and signals."""
        self._stop.set()

    def close(self) -> None:
        self.control_link.close()
        if self.gcs_link is not None:
            self.gcs_link.close()

    def __enter__(self) -> Vehicle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def run(self, duration_s: float | None = None, *,
            stop_event: threading.Event | None = None) -> VehicleResult:
        """Wait for the controller, then fly until ``duration_s`` of sim time (None: the
        scenario's ``run.duration_s``; ``math.inf``: until stopped), a crash, or a stop
        (:meth:`stop` or ``stop_event``). Can be called once per vehicle."""
        if self._ran:
            raise RuntimeError("Vehicle.run: a vehicle flies once; build a new one")
        self._ran = True
        self._external_stop = stop_event
        duration = self.scenario.run.duration_s if duration_s is None else duration_s
        if not duration > 0:
            raise ValueError(f"duration_s: must be > 0 (or math.inf), got {duration}")
        n_ticks = (math.inf if math.isinf(duration)
                   else max(1, round(duration / self.sim.control_dt_s)))
        if not self._await_controller():
            return self._finish(ExitStatus.STOPPED, "stopped before the controller connected",
                                0.0)
        self._flying = True
        self.flight.system_status = mav.MAV_STATE_ACTIVE
        # Everything built so far lives for the whole flight: out of the collector's sight,
        # so a full collection in flight walks only what the flight allocates (one took
        # ~20 ms, 100+ lockstep ticks or 20 real-time ones, in a 1.5 s paper flight).
        # freeze() alone costs nothing (no collection first: in a big host process, e.g.
        # a test run flying vehicles in threads, that took ~0.2 s and the real-time clock
        # would start that late); what it keeps of today's garbage is freed after the flight.
        gc.freeze()
        try:
            wall0 = self._flight_wall0 = time.monotonic()
            if self.on_truth is not None:
                self.on_truth(self.sim)
            status, reason = self.fly(n_ticks)
        finally:
            gc.unfreeze()
        return self._finish(status, reason, time.monotonic() - wall0)

    def stopped(self) -> bool:
        ext = self._external_stop
        return self._stop.is_set() or (ext is not None and ext.is_set())

    # ------------------------------------------------------------------ phases
    def _await_controller(self) -> bool:
        """Before the flight: HEARTBEAT at 1 Hz to the GCS (and a pinned peer), answer
        commands, until the controller's first HEARTBEAT. False if stopped first."""
        next_heartbeat = 0.0
        ctl = self.control_link
        while not self._controller_seen:
            if self.stopped():
                return False
            now = time.monotonic()
            if now >= next_heartbeat:
                hb = self.flight.heartbeat()
                if ctl.peer is not None:
                    ctl.send(hb)
                elif self.announce is not None:
                    ctl.send_to(self.announce, hb)
                if self.gcs_link is not None:
                    self.gcs_link.send(hb)
                next_heartbeat = now + 1.0
            self._wait(min(WAIT_SLICE_S, max(0.0, next_heartbeat - time.monotonic())))
            for msg in ctl.recv(0.0):
                self.dispatch(msg, None)
            self._serve_gcs()
            if self.signing is not None:
                self._report_refused_signatures()
        host, port = ctl.peer or ("?", 0)
        self.status(mav.MAV_SEVERITY_INFO, f"controller {host}:{port} (sysid "
                                           f"{ctl.peer_sysid}) connected: flight starts")
        return True

    def _admit(self, heartbeat: Any, sender: Address) -> str | None:
        """Link admission: None if ``sender`` may become the controller, else why not."""
        if self._pinned:
            return None    # --peer: the operator said who the controller is
        kind = heartbeat.type
        comp = heartbeat.get_srcComponent()
        if kind == mav.MAV_TYPE_ONBOARD_CONTROLLER or comp == mav.MAV_COMP_ID_ONBOARD_COMPUTER:
            return None
        self.stats.controllers_refused += 1
        reason = (f"HEARTBEAT type {kind}, component {comp} is not an offboard controller "
                  f"(type {mav.MAV_TYPE_ONBOARD_CONTROLLER} or component "
                  f"{mav.MAV_COMP_ID_ONBOARD_COMPUTER}); use the GCS port for commands")
        now = time.monotonic()
        if now - self._refused_at.get(sender, -math.inf) >= _REFUSAL_INTERVAL_S:
            self._refused_at[sender] = now
            text = f"control port: {sender[0]}:{sender[1]} refused as controller: {reason}"
            for msg in self.statustext.messages(mav.MAV_SEVERITY_WARNING, text):
                self.control_link.send_to(sender, msg)
            if self.statustext.on_status is not None:
                self.statustext.on_status(mav.MAV_SEVERITY_WARNING, text)
        return reason

    def _release_silent_candidate(self) -> None:
        """Lockstep, first tick: a learned controller that identified itself but sends no
        HIL_ACTUATOR_CONTROLS (e.g. mavsdk as a companion computer) lets go of the link."""
        ctl = self.control_link
        if (self._confirmed or self._pinned or ctl.peer is None or self.stats.ticks
                or time.monotonic() - self._flight_wall0 < self.lockstep_timeout_s):
            return
        host, port = ctl.peer
        self.stats.controllers_released += 1
        self.status(mav.MAV_SEVERITY_WARNING,
                    f"control port: {host}:{port} sent no HIL_ACTUATOR_CONTROLS within "
                    f"{self.lockstep_timeout_s:g} s; released, waiting for a controller")
        ctl.peer = None
        ctl.peer_sysid = None
        self._flight_wall0 = time.monotonic()

    def _report_refused_signatures(self) -> None:
        """Before the flight: say so when would-be controllers' frames fail signing."""
        st = self.control_link.stats
        refused = st.unsigned + st.bad_signature + st.replayed + st.bad_timestamp
        if refused > self._refused_reported:
            self._refused_reported = refused
            self.status(mav.MAV_SEVERITY_WARNING,
                        f"control port: {refused} frames refused by signing (bad_signature "
                        f"{st.bad_signature}, unsigned {st.unsigned}, replayed {st.replayed}, "
                        f"bad_timestamp {st.bad_timestamp}); same --key-file on both sides?",
                        key="signing")

    def _finish(self, status: ExitStatus, reason: str, wall_s: float) -> VehicleResult:
        if status is ExitStatus.CRASHED:
            self.flight.system_status = mav.MAV_STATE_EMERGENCY
            self.status(mav.MAV_SEVERITY_EMERGENCY, f"crashed: {reason}")
        else:
            self.flight.system_status = mav.MAV_STATE_POWEROFF
            self.status(mav.MAV_SEVERITY_INFO,
                        f"simulation ended at t = {self.sim.time_s:.3f} s: {status.value}")
        hb = self.flight.heartbeat()
        for i in range(_FINAL_HEARTBEATS):   # a lost datagram must not hide the end
            if i:
                time.sleep(_FINAL_HEARTBEAT_GAP_S)
            for link in (self.control_link, self.gcs_link):
                if link is not None and link.peer is not None:
                    link.send(hb)
        return VehicleResult(status, reason, self.stats.ticks, self.sim.time_s, wall_s)

    # ------------------------------------------------------------------ the flight's loop
    def fly(self, n_ticks: float) -> tuple[ExitStatus, str]:
        """Fly on until ``n_ticks`` control periods in all (``math.inf``: until stopped or
        crashed), paced by :attr:`clock`: how the run ended and why. :meth:`run` calls it
        once the controller is connected."""
        clock = self.clock
        if isinstance(clock, LockstepClock):
            return self._fly_lockstep(clock, n_ticks)
        return self._fly_realtime(clock, n_ticks)

    def _fly_lockstep(self, clock: LockstepClock, n_ticks: float) -> tuple[ExitStatus, str]:
        """The tick, ordered for the critical path: the reply k → apply → integrate → the
        HEARTBEAT if due and the state k+1 on the wire; then, while the controller
        computes, what only reports on the tick (recorder hand-off, GCS). Same messages,
        same order on each port as "state, GCS, wait, step" (the recorder's calls are
        queued in between and handed over in order: :class:`HandOff`)."""
        sim = self.sim
        stats = self.stats
        ticks_per_heartbeat = max(1, round(1.0 / sim.control_dt_s))
        if stats.ticks >= n_ticks:
            return ExitStatus.COMPLETED, f"ran {sim.time_s:.3f} s of sim time"
        recording = self.recording
        recording.defer(True)
        # bound once: every tick calls each of them
        gcs_periodic, await_reply = self._gcs_periodic, self._await_reply
        step, publish_state = self.step, self.publish_state
        try:
            if stats.ticks % ticks_per_heartbeat == 0:
                self._send_heartbeat()
            publish_state()
            while True:
                gcs_periodic()
                ended = await_reply(clock, sim.time_usec)
                if ended is not None:
                    return ended
                # --- critical path: reply consumed → next state sent
                crash = step()
                if crash is not None:
                    return ExitStatus.CRASHED, crash
                ticks = stats.ticks
                if ticks >= n_ticks:
                    return ExitStatus.COMPLETED, f"ran {sim.time_s:.3f} s of sim time"
                if ticks % ticks_per_heartbeat == 0:
                    self._send_heartbeat()
                publish_state()
                # --- the controller computes from here: report on the tick
        finally:
            recording.defer(False)

    def _await_reply(self, clock: LockstepClock,
                     time_usec: int) -> tuple[ExitStatus, str] | None:
        """Block until the reply for ``time_usec`` is consumed (None), or the run's end
        (stopped, or the controller gone) and why.

        The wait is the control link's ``recvfrom`` itself (no select). Before each wait:
        the recorder hand-off, and the GCS port, read every ``GCS_POLL_S`` of wall time,
        not on every tick (a GCS is a person): both while the controller computes, so
        the consumed reply goes straight on to the next state. Between waits the clock
        says what the silence calls for (resend, report, give up)."""
        ctl = self.control_link
        dispatch = self.dispatch
        flush = self.recording.flush
        now = _monotonic()
        clock.start(now)
        while True:
            flush()      # the recorder's share of the tick
            if now >= self._next_gcs_s:
                self._next_gcs_s = now + GCS_POLL_S
                self._serve_gcs()
            awaited = time_usec
            # One datagram a pass: the reply comes alone, and the loop reads what follows.
            for msg in ctl.recv(clock.slice_s(now), drain=False):
                # Handle the whole batch (a command may follow the reply); once the reply
                # is consumed, a duplicate for the same tick is stale (-1 matches nothing).
                if dispatch(msg, awaited):
                    awaited = -1
            if awaited == -1:
                return None
            now = _monotonic()
            if self.stopped():
                return ExitStatus.STOPPED, "stopped on request"
            due = clock.silence(now)
            if not due:
                continue
            if due & _LOST:
                return ExitStatus.PEER_LOST, clock.lost_reason(now)
            if due & _TIMED_OUT:
                self.stats.lockstep_timeouts += 1
                self.status(mav.MAV_SEVERITY_WARNING, clock.timeout_text(time_usec),
                            key="lockstep_timeout")
                self._send_heartbeat()
            if due & _RESEND:
                self.stats.lockstep_resends += 1
                self._resend_state()
                self._gcs_periodic()

    def _fly_realtime(self, clock: RealtimeClock, n_ticks: float) -> tuple[ExitStatus, str]:
        """Physics follows the wall clock from the first applied command; the latest valid
        command is held, silence cuts the motors (and, past ``peer_timeout_s``, ends the
        run), a period more than 0.1 s late re-anchors the clock."""
        sim = self.sim
        stats = self.stats
        held = self.held
        ticks_per_heartbeat = max(1, round(1.0 / sim.control_dt_s))
        ctl = self.control_link
        if not self._await_first_command():
            return ExitStatus.STOPPED, "stopped on request"
        clock.start(time.monotonic())   # sim time starts with the first command applied
        first = True
        while stats.ticks < n_ticks:
            if not first:
                if stats.ticks % ticks_per_heartbeat == 0:
                    self._send_heartbeat()
                self.publish_state()
            first = False
            due_s = clock.due_s(stats.ticks)
            while True:
                for msg in ctl.recv(0.0):
                    self.dispatch(msg, None)
                self._gcs_periodic()
                self._serve_gcs()
                if self.stopped():
                    return ExitStatus.STOPPED, "stopped on request"
                now = time.monotonic()
                if now >= due_s:
                    break
                self._wait(min(WAIT_SLICE_S, due_s - now))
            silent_s = now - held.since_s
            if clock.cuts_motors(silent_s, held.motors_cut):
                self.controls.cut_motors(silent_s, clock.command_timeout_s)
            lost = clock.lost_reason(silent_s, held.motors_cut)
            if lost is not None:
                return ExitStatus.PEER_LOST, lost
            stats.held_age.add(sim.time_usec - held.time_usec)
            crash = self.step()
            if crash is not None:
                return ExitStatus.CRASHED, crash
            overrun = clock.overrun(now, due_s, stats.ticks)
            if overrun is not None:
                stats.overruns += 1
                self.status(mav.MAV_SEVERITY_WARNING, overrun, key="overrun")
        return ExitStatus.COMPLETED, f"ran {sim.time_s:.3f} s of sim time"

    def _await_first_command(self) -> bool:
        """Real time: send the t = 0 state every ``START_RESEND_S`` until a valid command
        for it is applied; False if stopped first. Sim time has not started, so a controller
        that is slow to start costs nothing and the command timeout cannot cut the motors."""
        ctl = self.control_link
        held = self.held
        next_heartbeat = next_state = 0.0
        first = True
        while held.time_usec < 0:
            now = time.monotonic()
            if now >= next_heartbeat:
                self._send_heartbeat()
                next_heartbeat = now + 1.0
            if now >= next_state:
                if first:
                    self.publish_state()
                    first = False
                else:
                    self._resend_state()
                self.stats.start_wait_states += 1
                next_state = now + START_RESEND_S
            self._wait(min(WAIT_SLICE_S, max(0.0, next_state - time.monotonic())))
            for msg in ctl.recv(0.0):
                self.dispatch(msg, None)
            self._gcs_periodic()
            self._serve_gcs()
            if self.stopped():
                return False
        return True

    # ------------------------------------------------------------------ the tick's parts
    def _send_heartbeat(self) -> None:
        self.control_link.send(self.flight.heartbeat())

    def publish_state(self) -> None:
        """ODOMETRY, ACTUATOR_OUTPUT_STATUS, ESC_TELEMETRY_1_TO_4 of the current tick to the
        controller (:mod:`tfl_mav.sitl.state_report`)."""
        held = self.held
        latest = self.report.build(held.applied_usec, held.driven)
        if not self._confirmed:      # _resend_state's body: one call less every tick
            self._release_silent_candidate()
        self.control_link.send_many(latest)
        self.stats.states_sent += 1

    def _resend_state(self) -> None:
        """The current tick's messages again, in order, in one datagram."""
        assert self.report.latest is not None
        if not self._confirmed:
            self._release_silent_candidate()
        self.control_link.send_many(self.report.latest)
        self.stats.states_sent += 1

    def dispatch(self, msg: Any, awaited_usec: int | None) -> bool:
        """Handle one message from the control port; True if it is a HIL_ACTUATOR_CONTROLS
        that completes the awaited tick (applied or rejected, not stale)."""
        mid = msg.get_msgId()
        if mid == _ID_HIL_ACTUATOR_CONTROLS:
            if not self._flying:
                self.stats.stale_controls += 1
                return False
            self._confirmed = True
            return self.controls.on_controls(msg, awaited_usec) is not _STALE
        if mid == _ID_HEARTBEAT:
            self._controller_seen = True
        else:
            route = self.commands.routes.get(mid)
            if route is not None:
                route(self.control_link, msg)
        return False

    def _attack_nonfinite(self, _t_s: float, text: str) -> None:
        """The attack expression left its domain mid-flight: said once, not flown silently."""
        self.status(mav.MAV_SEVERITY_WARNING, text)

    def _forward_statustext(self, link: Link, msg: Any) -> None:
        """The controller's STATUSTEXT (its safety events: attack detected, safe law
        engaged, handed back, failsafe) on to the GCS, as PX4 forwards a companion's: the
        frame unchanged (MAVLink routing), so the GCS sees the controller's own ids,
        severity and signature."""
        gcs = self.gcs_link
        if link is self.control_link and gcs is not None and gcs.peer is not None:
            gcs.send_raw(bytes(msg.get_msgbuf()))

    def _gcs_periodic(self) -> None:
        gcs = self.gcs
        if gcs is not None:
            gcs.periodic()

    def _serve_gcs(self) -> None:
        gcs = self.gcs_link
        if gcs is None:
            return
        routes = self.commands.routes
        for msg in gcs.recv(0.0):
            route = routes.get(msg.get_msgId())
            if route is not None:
                route(gcs, msg)

    def _wait(self, timeout_s: float) -> None:
        if timeout_s > 0.0:
            select.select(self._fds, [], [], timeout_s)

    def step(self) -> str | None:
        sim = self.sim
        sim.step_control_period()
        self.stats.ticks += 1
        self.power.step(sim.motors.omega_radps, sim.control_dt_s)   # the next ESC report
        if self.recording.on_truth is not None:
            self.recording.truth()
        return sim.crash_reason()

    def status(self, severity: int, text: str, *, key: str | None = None) -> None:
        self.statustext.send(severity, text, key=key)
