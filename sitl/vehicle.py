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

* :mod:`tfl_mav.sitl.clock` — lockstep (default) and real-time pacing, and the held command;
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
from tfl_mav.sitl.clock import WAIT_SLICE_S, Clock, HeldCommand, LockstepClock, RealtimeClock
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
        self.hand_off = self.recording.flush   # type: ignore[method-assign]  # every tick
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
        self.clock: Clock = (RealtimeClock(self, command_timeout_s, peer_timeout_s) if realtime
                             else LockstepClock(self, lockstep_timeout_s, resend_interval_s,
                                                peer_timeout_s))
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
            status, reason = self.clock.run(n_ticks)
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
            self.wait(min(WAIT_SLICE_S, max(0.0, next_heartbeat - time.monotonic())))
            for msg in ctl.recv(0.0):
                self.dispatch(msg, None)
            self.serve_gcs()
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

    # ------------------------------------------------------------------ what a clock drives
    # (tfl_mav.sitl.clock.Paced)
    def send_heartbeat(self) -> None:
        self.control_link.send(self.flight.heartbeat())

    def publish_state(self) -> None:
        """ODOMETRY, ACTUATOR_OUTPUT_STATUS, ESC_TELEMETRY_1_TO_4 of the current tick to the
        controller (:mod:`tfl_mav.sitl.state_report`)."""
        held = self.held
        latest = self.report.build(held.applied_usec, held.driven)
        if not self._confirmed:      # resend_state's body: one call less every tick
            self._release_silent_candidate()
        self.control_link.send_many(latest)
        self.stats.states_sent += 1

    def resend_state(self) -> None:
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

    def gcs_periodic(self) -> None:
        gcs = self.gcs
        if gcs is not None:
            gcs.periodic()

    def serve_gcs(self) -> None:
        gcs = self.gcs_link
        if gcs is None:
            return
        routes = self.commands.routes
        for msg in gcs.recv(0.0):
            route = routes.get(msg.get_msgId())
            if route is not None:
                route(gcs, msg)

    def wait(self, timeout_s: float) -> None:
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

    def defer_recording(self, defer: bool) -> None:
        self.recording.defer(defer)

    def hand_off(self) -> None:
        self.recording.flush()

    def status(self, severity: int, text: str, *, key: str | None = None) -> None:
        self.statustext.send(severity, text, key=key)

    def cut_motors(self, silent_s: float, timeout_s: float) -> None:
        self.controls.cut_motors(silent_s, timeout_s)
