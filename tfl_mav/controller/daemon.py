"""The offboard controller daemon: link → state → attack detector → TFL law → link.

One :class:`Daemon` talks MAVLink 2 over one UDP socket to one vehicle (docs/design.md, "The wire"):

* sends ``HEARTBEAT`` (``MAV_TYPE_ONBOARD_CONTROLLER``) at once and every second (the
  simulator starts its clock on the first one);
* consumes ``ODOMETRY`` (converted NED/FRD → paper frame in :mod:`tfl_mav.model.frames`,
  the one place frames meet), ``ACTUATOR_OUTPUT_STATUS`` (which command the motors held
  over the period that just ended) and ``ESC_TELEMETRY_1_TO_4`` (measured rpm). A state is
  complete when the ESC report that follows its ODOMETRY has arrived;
* gives the detector the command the vehicle *applied*, not the last one sent: its own
  float64 copy of the command with ACTUATOR_OUTPUT_STATUS's ``time_usec`` (a short
  history is kept), else ``actuator[0..3]`` × f_max (a restarted daemon, motors cut). A
  late, lost, duplicated or reordered command is then never an attack; in lockstep the
  applied command is the last one sent, so nothing changes there;
* answers every state with ``HIL_ACTUATOR_CONTROLS`` (:mod:`tfl_mav.controller.daemon_wire`,
  with the telemetry and the recorder's tick record);
* is **not told** about the attack: :class:`~tfl_mav.control.detect.detector.AttackDetector`
  finds it from rpm alone and switches the law (STATUSTEXT on detection);
* publishes its own telemetry at ≤ 50 Hz of sim time (``NAMED_VALUE_FLOAT`` mode, det_rotor,
  atk_est_n, path_m; ``DEBUG_FLOAT_ARRAY`` tfl = ξ1, ξ2, η chains).

**Degrade, don't fall.** Each complete state is classified as it arrives
(:mod:`tfl_mav.controller.daemon_intake`, the message handlers;
:mod:`tfl_mav.controller.arrivals`: fresh,
repeated, old, implausible, or a restart that rebuilds the flight computer, ``rebuilds``);
repeated states get the same command again, old and
implausible ones are counted (``repeated_states``, ``old_states``, ``implausible_states``).
Each loop drains the socket and runs the law once, on the newest fresh state; the other
fresh states of the batch are skipped (``skipped_states``). When states were skipped the law
integrates over the real gap (``gap_ticks``); a STATUSTEXT says when such an episode starts
and one when it is over (a second of sim time without a gap: ``degraded_episodes``), not
every gap, and ``tfl-mav fly``'s summary line gives the totals. After a
restart (a restarted simulator, a vehicle that went on while we were away) the recovery law
takes over when the state is not benign.

**Ready before time starts.** The flight computer is built and warmed (one throw-away
evaluation on a separate instance) in the constructor, before the first HEARTBEAT: the
vehicle starts sim time with the first command, so a slow start would cost the flight.

**Failsafe.** No valid state for ``state_timeout_s`` (wall time) → mode ``failsafe``,
announced by STATUSTEXT; nothing is sent to the motors (a vehicle in lockstep waits, one in
real time cuts its motors after its own command timeout, like a real ESC). When states
return the law resumes from the new state and says so.

**Waiting.** Until the first state arrives, a warning event every 2 s (wall) says what
has been received (and, on a signed link, how many frames were refused by signing), so a
vehicle that is not running, or a key mismatch, is visible instead of a silent wait. A
vehicle refuses an unsigned or wrongly signed controller *silently* (it answers no one it
cannot authenticate), so on a signed link silence is the symptom of a wrong key.

**Signing** (``key``): every frame sent is signed (``link_id`` 0) and only frames that
verify are accepted (:mod:`tfl_mav.link.signing`).

Bad input (garbage, wrong peer or sysid, non-finite or malformed ODOMETRY, unknown
messages) is counted in :class:`DaemonStats` and never stops the loop; nothing non-finite
ever reaches a motor command.
"""

from __future__ import annotations

import gc
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from tfl_mav.controller.daemon_intake import Intake
from tfl_mav.controller.daemon_wire import (
    _HIL_TAIL,
    _MODE_NAMES,
    LOCKSTEP_FLAG,
    TICK_FIELDS,
    TICK_SCHEMA,
    DaemonResult,
    DaemonStats,
    _Hil,
    _new,
    applied_thrusts,
    command_message,
    motors_off,
    telemetry_messages,
    tick_state,
    waiting_text,
)
from tfl_mav.controller.flight_computer import FlightComputer, TickResult
from tfl_mav.link.dialect import mav
from tfl_mav.link.signing import Signing
from tfl_mav.link.statustext import split as split_statustext
from tfl_mav.link.transport import Address, FrameHook, Link
from tfl_mav.model.geometry import euler_to_quaternion
from tfl_mav.model.modes import Mode
from tfl_mav.model.state import State
from tfl_mav.scenario import Scenario

__all__ = ["TICK_FIELDS", "TICK_SCHEMA", "Daemon", "DaemonResult", "DaemonStats", "tick_state"]

_TELEMETRY_PERIOD_S = 0.02        # ≤ 50 Hz of sim time
_ARMED = mav.MAV_MODE_FLAG_SAFETY_ARMED
_WAITING_REPORT_PERIOD_S = 2.0
_HISTORY = 512                    # commands remembered by time_usec (0.5 s at 1 kHz)
_GAP_FACTOR = 1.5                 # a gap over 1.5 control periods is integrated as such
_DEGRADE_REPORT_S = 1.0           # sim seconds without a gap that end a degraded episode
_FALLBACK = Mode.FALLBACK
_isfinite = math.isfinite


class Daemon:
    """The offboard controller for one vehicle. See the module docstring."""

    def __init__(self, scenario: Scenario, *, vehicle: Address, bind: Address | None = None,
                 realtime: bool = False, state_timeout_s: float = 0.5,
                 silence_end_s: float | None = None, sysid: int = 1,
                 compid: int = mav.MAV_COMP_ID_ONBOARD_COMPUTER,
                 vehicle_sysid: int | None = None, key: bytes | None = None,
                 on_frame: FrameHook | None = None,
                 on_tick: Callable[[float, tuple[Any, ...]], None] | None = None,
                 on_event: Callable[[str, str, float], None] | None = None,
                 hold_start: Callable[[], bool] | None = None,
                 flight_software: Callable[[Scenario], Any] | None = None) -> None:
        """Open the socket towards ``vehicle`` (raises LinkError).

        ``key``: 32-byte MAVLink 2 signing secret (the vehicle's), or None (unsigned).
        ``silence_end_s``: after the flight started, end the run when no state has arrived
        for this many wall seconds (the vehicle is gone even if its goodbye was lost);
        None waits for the vehicle forever (failsafe, then resume when it returns).
        ``on_tick(sim_time_s, record)`` sees the controller's internals every tick as a
        compact tuple (:func:`tick_state`, fields :data:`TICK_FIELDS`; the recorder's
        ``/controller/state``); ``on_event(level, text, sim_time_s)`` every
        event also sent as STATUSTEXT. ``hold_start()``: while it returns True, a vehicle
        waiting at t = 0 (its clock starts with our first command, so waiting is free) gets
        no command yet — e.g. a recorder still starting; a take-over mid-flight never waits.
        ``flight_software(scenario)``: makes the flight software to fly (one per flight,
        :class:`~tfl_mav.api.FlightSoftware`, returning TickResults) instead of the
        :class:`FlightComputer`.
        """
        if not (math.isfinite(state_timeout_s) and state_timeout_s > 0):
            raise ValueError(f"state_timeout_s: must be > 0 s, got {state_timeout_s}")
        self.scenario = scenario
        self.realtime = realtime
        self.state_timeout_s = state_timeout_s
        if silence_end_s is not None and not (math.isfinite(silence_end_s)
                                              and silence_end_s > state_timeout_s):
            raise ValueError(f"silence_end_s: must be > state_timeout_s "
                             f"({state_timeout_s} s), got {silence_end_s}")
        self.silence_end_s = silence_end_s
        self._software_factory = flight_software
        self.computer = self._new_computer()
        self.signing = Signing(key) if key is not None else None
        self.link = Link.connect(vehicle, src_system=sysid, src_component=compid, bind=bind,
                                 peer_sysid=vehicle_sysid, on_frame=on_frame,
                                 signing=self.signing)
        self.on_tick = on_tick
        self.on_event = on_event
        self.hold_start = hold_start
        self.stats = DaemonStats()
        self.thrust_max_n = scenario.vehicle.thrust_max_n
        self.k_f = scenario.vehicle.k_f
        self._stop = threading.Event()
        self._history: dict[int, list[float]] = {}                  # time_usec → thrust_n
        # its keys, oldest first: dropping the oldest by ``next(iter(dict))`` walks past
        # every entry deleted before it (~2 000 instructions a tick at 512 entries)
        self._history_keys: deque[int] = deque()
        self._last_usec = -1          # time_usec of the last state controlled
        self._episode_start_s: float | None = None   # sim time a degraded episode began
        self._episode_base = (0, 0)                   # gap_ticks, skipped_states before it
        self._last_gap_s = 0.0
        self._hover = [scenario.vehicle.mass_kg * scenario.vehicle.gravity_mps2 / 4.0] * 4
        self._last_cmd = list(self._hover)
        self._mode = Mode.NOMINAL
        self._failsafe = False
        self._next_telemetry_s = 0.0
        self._sim_time_s = 0.0
        self._est_n = 0
        self._distance = math.nan
        self._statustext_id = 0
        self._hil_flags = 0 if realtime else LOCKSTEP_FLAG
        self._gap_usec = _GAP_FACTOR * (scenario.run.control_dt_s * 1e6)
        self._motors_off = False      # the vehicle's last word: no command drives the motors
        self._next_motors_report_s = 0.0
        self._motors_said = False     # the current pause was said
        # the vehicle's messages → complete, classified states (daemon_intake.py)
        self.intake = Intake(self.stats, realtime, event=self._event,
                             answer_repeat=self._answer_repeat, new_flight=self._rebuild)

    def _new_computer(self) -> FlightComputer:
        """A flight computer for a new flight, warmed: one throw-away tick on a separate
        instance runs every code path of the first tick (imports, caches) before the
        vehicle starts its clock."""
        sc = self.scenario
        if self._software_factory is not None:
            return self._software_factory(sc)
        # Real time: the spin law's table (1.6 s of computing) is made on a thread, never
        # in a tick; lockstep: in the tick that first needs it (the vehicle waits).
        build = "async" if self.realtime else "sync"
        warm = FlightComputer(sc, spin_build=build)
        ini = sc.initial
        state = State(tuple(ini.position_m), tuple(ini.velocity_mps),
                      tuple(euler_to_quaternion(*ini.euler_rad).tolist()),
                      tuple(ini.body_rates_radps))
        hover = sc.vehicle.mass_kg * sc.vehicle.gravity_mps2 / 4.0
        rpm = math.sqrt(hover / sc.vehicle.k_f) * 60.0 / (2.0 * math.pi)
        warm.step(0.0, state, [rpm] * 4, [hover] * 4)
        fc = FlightComputer(sc, spin_build=build)
        # Everything built so far (modules, path kernels, the safe law's gain schedule) lives
        # for the whole flight: freeze it out of the collector, so a full collection in
        # flight walks only what the flight allocates (they were the only ticks over
        # 1.5 ms in the paper flight, bench_controller.py's flight table).
        gc.collect()
        gc.freeze()
        return fc

    def stop(self) -> None:
        """End :meth:`run` soon. Safe from a signal handler or another thread."""
        self._stop.set()

    def close(self) -> None:
        self.link.close()

    # ------------------------------------------------------------------ main loop
    def run(self, duration_s: float | None = None) -> DaemonResult:
        """Fly until ``duration_s`` of sim time (None: the scenario's), the vehicle says it is
        done (HEARTBEAT POWEROFF/EMERGENCY, or its "crashed"/"simulation ended" STATUSTEXT),
        stays silent for ``silence_end_s`` or :meth:`stop`."""
        duration = self.scenario.run.duration_s if duration_s is None else duration_s
        wall0 = time.monotonic()
        next_heartbeat = 0.0
        last_state_wall = time.monotonic()
        reason = "stopped"
        next_waiting_report = wall0 + _WAITING_REPORT_PERIOD_S
        intake = self.intake
        handlers, handle = intake.handlers, intake.handle
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_heartbeat:
                self.link.send(mav.MAVLink_heartbeat_message(
                    mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID,
                    _ARMED, 0, mav.MAV_STATE_ACTIVE, 3))
                next_heartbeat = now + 1.0
            for msg in self.link.recv(timeout_s=0.05):
                handler = handlers.get(type(msg))    # the per-tick messages, directly
                if handler is None:
                    handle(msg)
                else:
                    handler(msg)
            ticked = self._control_newest()
            now = time.monotonic()
            if ticked:
                last_state_wall = now
                if self._failsafe:
                    self._failsafe = False
                    self.stats.recoveries += 1
                    self._event("info", "state received again: control resumed")
            elif (not self._failsafe and self.stats.ticks > 0
                  and now - last_state_wall > self.state_timeout_s):
                self._failsafe = True
                self._mode = Mode.FAILSAFE
                self.stats.failsafes += 1
                self._event("critical", f"no vehicle state for {self.state_timeout_s:.2f} s: "
                                        "FAILSAFE, no commands sent")
            if self.stats.ticks == 0 and now >= next_waiting_report:
                next_waiting_report = now + _WAITING_REPORT_PERIOD_S
                self._report_waiting(now - wall0)
            if intake.vehicle_done:
                reason = intake.vehicle_done
                break
            if (self.silence_end_s is not None and self.stats.ticks > 0
                    and now - last_state_wall > self.silence_end_s):
                reason = f"vehicle silent for {self.silence_end_s:g} s (gone)"
                break
            if self._sim_time_s >= duration - 1e-9 and self.stats.ticks > 0:
                reason = "duration reached"
                break
        self.stats.link = self.link.stats.as_dict()
        return DaemonResult(
            reason=reason, sim_time_s=self._sim_time_s, wall_time_s=time.monotonic() - wall0,
            detected_rotor=self.computer.detected_rotor,
            detection_time_s=self.computer.detection_time_s,
            attack_estimate_samples=self._est_n,
            final_path_distance_m=self._distance, mode=str(self._mode), stats=self.stats)

    def _report_waiting(self, waited_s: float) -> None:
        """Before the first tick: say (locally) what arrived and what to check."""
        self._event("warning", waiting_text(waited_s, self.link, self.signing is not None),
                    send=False)

    def _control_newest(self) -> bool:
        """Run one control tick on the newest fresh state of this batch (the last one: fresh
        states arrive in increasing time); True if a valid state arrived (for the failsafe's
        clock).

        Runs every tick: the applied command's usual case (our own copy, by the
        state's ``time_usec``), the tick and the command message are written out here, one
        Python call instead of four."""
        batch, arrived = self.intake.take()
        if not batch:
            return arrived
        stats = self.stats
        state, applied_msg, rpm = batch[-1]
        t_usec = state.time_usec
        if stats.ticks == 0 and t_usec == 0 and self.hold_start is not None \
                and self.hold_start():
            self.intake.arrivals.forget_watermark()   # its resend of t = 0: fresh again
            return arrived
        if len(batch) > 1:
            stats.skipped_states += len(batch) - 1
        last_usec = self._last_usec
        dt_s = None
        if last_usec >= 0 and t_usec - last_usec > self._gap_usec:
            dt_s = (t_usec - last_usec) * 1e-6
            stats.gap_ticks += 1
            self._report_degraded(t_usec * 1e-6, len(batch) - 1)
        # the applied command: our own copy of the command it names, else the wire's
        # (applied_thrusts decides every other case)
        history = self._history
        if applied_msg is None:
            stats.applied_unknown += 1
            applied = self._last_cmd
        else:
            applied_usec = applied_msg.time_usec
            applied = history.get(applied_usec) if applied_usec else None
            if applied is None:
                applied = applied_thrusts(applied_msg, history,
                                          self._hover if last_usec < 0 else None,
                                          self.thrust_max_n, stats)
            else:
                stats.applied_from_history += 1
            if motors_off(applied_msg) is not self._motors_off:
                self._motors_switched(not self._motors_off, t_usec)
        if self._motors_off:
            stats.motors_off_ticks += 1
        self._last_usec = t_usec
        # the tick
        t = t_usec * 1e-6
        self._sim_time_s = t
        stats.ticks += 1
        try:
            res = self.computer.step(t, state, rpm, applied, dt_s=dt_s)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
            self._law_failed(t_usec, exc)
            return True
        thrust, out, det, rotor, estimate_n, new, _, events = res
        if new:
            # CRITICAL, as PX4 says a failure it detected (a rotor lost is one)
            self._event("critical", f"ATTACK on rotor {rotor} detected at "
                                   f"t={t:.3f} s; attacked law engaged")
        if events:
            for text in events:              # law switches, in words
                self._event("warning", text)
        self._last_cmd = thrust
        keys = self._history_keys
        if t_usec not in history:
            keys.append(t_usec)
        history[t_usec] = thrust
        if len(keys) > _HISTORY:
            del history[keys.popleft()]        # the oldest
        # command_message's HIL_ACTUATOR_CONTROLS, written out
        f1, f2, f3, f4 = thrust
        fmax = self.thrust_max_n
        self.link.send(_new(_Hil, (t_usec, self._hil_flags, f1 / fmax, f2 / fmax, f3 / fmax,
                                   f4 / fmax, *_HIL_TAIL)))
        stats.commands_sent += 1
        mode = self._mode = out.mode
        self._distance = out.path_distance_m
        if mode is _FALLBACK:
            stats.fallback_ticks += 1
        saturated = True in out.saturated       # any(): the list holds bools
        if saturated:
            stats.saturated_ticks += 1
        if rotor and _isfinite(estimate_n):
            self._est_n += 1
        on_tick = self.on_tick
        if on_tick is not None:     # tick_state(res), written out: the same plain tuple
            if det is None:
                on_tick(t, (_MODE_NAMES[mode], rotor, estimate_n, out.path_distance_m,
                            saturated, thrust, out.xi, out.eta, out.mass_estimate_kg,
                            out.fine_gains, out.reason, ()))
            else:
                on_tick(t, (_MODE_NAMES[mode], rotor, det.estimate_n, out.path_distance_m,
                            saturated, thrust, out.xi, out.eta, out.mass_estimate_kg,
                            out.fine_gains, out.reason, det.cusum))
        if t >= self._next_telemetry_s:
            self._next_telemetry_s = t + _TELEMETRY_PERIOD_S
            self._telemetry(t_usec, res)
            if self._episode_start_s is not None and t - self._last_gap_s >= _DEGRADE_REPORT_S:
                self._degraded_over(t)
        return True

    def _motors_switched(self, off: bool, t_usec: int) -> None:
        """The vehicle's motors stopped being driven (a GCS disarm, a cut) or are driven
        again: the detector is told, so that stopped rotors raise no alarm and the verdict
        it had stands (:meth:`AttackDetector.set_motors_off`)."""
        self._motors_off = off
        det = self.computer.detector
        if det is not None:
            det.set_motors_off(off)
        t = t_usec * 1e-6
        if off:
            self.stats.motors_off_periods += 1
        # A pause is said with its end; at most one pause a second of sim time is said (a
        # vehicle flipping the bit every tick must not flood the link); all are counted.
        if off and t >= self._next_motors_report_s:
            self._motors_said = True
            self._event("warning", f"motors not driven at t={t:.3f} s (vehicle disarmed or "
                                   "cut): attack detection paused, verdict kept")
        elif not off and self._motors_said:
            self._motors_said = False
            self._next_motors_report_s = t + 1.0
            self._event("info", f"motors driven again at t={t:.3f} s: attack detection "
                                f"resumed ({self.stats.motors_off_periods} pauses so far)")

    def _law_failed(self, t_usec: int, exc: BaseException) -> None:
        """A state the laws cannot digest (e.g. a fuzzed one with huge values): the last
        command again (what the vehicle holds anyway; a lockstep vehicle waits for an
        answer to this state), the loop goes on."""
        self.stats.law_errors += 1
        self._event("critical", f"control tick failed at t={t_usec * 1e-6:.3f} s: "
                                f"{type(exc).__name__}: {exc}", quiet=self.stats.law_errors > 1)
        self._send_command(t_usec, self._last_cmd)

    def _answer_repeat(self, t_usec: int) -> None:
        """The state of ``t_usec`` came again: if it is the one last controlled, its command
        again (lost on the way: a lockstep vehicle waits for it)."""
        if self._last_usec == t_usec:
            self._send_command(t_usec, self._last_cmd)

    def _rebuild(self, t_usec: int, from_usec: int) -> None:
        """Vehicle time jumped from ``from_usec`` to ``t_usec`` (a restarted simulator, or a
        vehicle that went on while we were away): a new flight. New law and detector, no
        history (the intake drops its batch and restarts its watermark)."""
        self.stats.rebuilds += 1
        self._event("warning", f"vehicle time jumped to t={t_usec * 1e-6:.3f} s "
                               f"(from {from_usec * 1e-6:.3f} s): new time line, "
                               "controller rebuilt")
        self.computer = self._new_computer()
        if self._motors_off and self.computer.detector is not None:
            self.computer.detector.set_motors_off(True)    # still so, on the new time line
        self._history.clear()
        self._history_keys.clear()
        self._last_usec = -1
        self._last_cmd = list(self._hover)
        self._next_telemetry_s = 0.0
        self._episode_start_s = None      # a new time line: the old episode's clock is gone

    def _report_degraded(self, t: float, skipped_now: int) -> None:
        """A gap was integrated at sim time ``t``. Said when it starts an episode (the first
        gap, or the first after _DEGRADE_REPORT_S of sim time without one), not for every
        gap of a machine that keeps falling behind; :meth:`_degraded_over` says its end."""
        self._last_gap_s = t
        if self._episode_start_s is not None:
            return
        st = self.stats
        self._episode_start_s = t
        self._episode_base = (st.gap_ticks - 1, st.skipped_states - skipped_now)
        st.degraded_episodes += 1
        self._event("warning", f"degraded real time at t={t:.3f} s: the loop fell behind "
                               "(states skipped, the law integrates the gap); said again "
                               "when it recovers")

    def _degraded_over(self, t: float) -> None:
        """No gap for _DEGRADE_REPORT_S of sim time since the last: the episode is over."""
        st = self.stats
        gaps0, skipped0 = self._episode_base
        start = self._episode_start_s
        self._episode_start_s = None
        self._event("info", f"real time recovered at t={t:.3f} s: {st.gap_ticks - gaps0} "
                            f"gaps integrated, {st.skipped_states - skipped0} states skipped "
                            f"over {self._last_gap_s - (start or 0.0):.1f} s")

    def _send_command(self, time_usec: int, thrust: Sequence[float]) -> None:
        """HIL_ACTUATOR_CONTROLS: controls[0..3] = thrust / f_max, 12 zeros, armed."""
        self.link.send(command_message(time_usec, thrust, self.thrust_max_n,
                                       self._hil_flags))
        self.stats.commands_sent += 1

    def _telemetry(self, time_usec: int, res: TickResult) -> None:
        # one datagram (send_many): one sendto here, one recvfrom at the vehicle
        self.link.send_many(telemetry_messages(time_usec, res))

    def _event(self, level: str, text: str, *, send: bool = True, quiet: bool = False) -> None:
        if self.on_event is not None and not quiet:
            self.on_event(level, text, self._sim_time_s)
        if not send:
            return
        severity = {"info": mav.MAV_SEVERITY_INFO, "warning": mav.MAV_SEVERITY_WARNING,
                    "critical": mav.MAV_SEVERITY_CRITICAL}.get(level, mav.MAV_SEVERITY_INFO)
        chunks = split_statustext(text)
        # id 0: a text that fits one STATUSTEXT is whole as it is (MAVLink 2); a chunk id
        # on a full 50-character text would leave a receiver waiting for a next chunk
        text_id = 0
        if len(chunks) > 1:
            text_id = self._statustext_id = (self._statustext_id % 0xFFFF) + 1
        for seq, chunk in enumerate(chunks):   # whole, in MAVLink 2 chunks
            self.link.send(mav.MAVLink_statustext_message(severity, chunk, text_id, seq))
