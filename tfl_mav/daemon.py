"""The offboard controller daemon: link → state → attack detector → TFL law → link.

One :class:`Daemon` talks MAVLink 2 over one UDP socket to one vehicle (docs/design.md, "The wire"):

* sends ``HEARTBEAT`` (``MAV_TYPE_ONBOARD_CONTROLLER``) at once and every second (the
  simulator starts its clock on the first one);
* consumes ``ODOMETRY`` (converted NED/FRD → paper frame in :mod:`tfl_mav.frames`,
  the one place frames meet) and ``ESC_TELEMETRY_1_TO_4`` (measured rpm). A control tick
  runs when a state and the ESC report that follows it have both arrived;
* answers every state with ``HIL_ACTUATOR_CONTROLS`` (``controls[0..3]`` = rotor thrust /
  f_max, ``time_usec`` echoing the state's, ``mode`` armed, ``flags`` bit 0 = lockstep);
* is **not told** about the attack: :class:`~tfl_mav.control.detector.AttackDetector`
  finds it from rpm alone and switches the law (STATUSTEXT on detection);
* publishes its own telemetry at ≤ 50 Hz of sim time: ``NAMED_VALUE_FLOAT`` ``mode``
  (0 nominal, 1 attacked, 2 fallback, 3 failsafe), ``det_rotor``, ``atk_est_n``,
  ``path_m``, and ``DEBUG_FLOAT_ARRAY`` ``tfl`` = (ξ1 chain, ξ2 chain, η chain).

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

import math
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

from tfl_mav.flight_computer import FlightComputer, TickResult
from tfl_mav.frames import paper_from_odometry
from tfl_mav.link.dialect import mav
from tfl_mav.link.signing import Signing
from tfl_mav.link.transport import Address, FrameHook, Link
from tfl_mav.modes import Mode
from tfl_mav.scenario import Scenario
from tfl_mav.state import State

__all__ = ["Daemon", "DaemonResult", "DaemonStats", "tick_state"]

_TELEMETRY_PERIOD_S = 0.02        # ≤ 50 Hz of sim time
_ARMED = mav.MAV_MODE_FLAG_SAFETY_ARMED
_LOCKSTEP_FLAG = 1
_WAITING_REPORT_PERIOD_S = 2.0


@dataclass
class DaemonStats:
    """Counters of one run (link counters are in ``link``)."""

    ticks: int = 0
    states: int = 0
    bad_states: int = 0
    esc_reports: int = 0
    bad_esc: int = 0
    ignored_messages: int = 0
    commands_sent: int = 0
    states_resent: int = 0      # lockstep: a state we had answered came again (reply lost)
    failsafes: int = 0
    recoveries: int = 0
    fallback_ticks: int = 0
    saturated_ticks: int = 0
    link: dict[str, int] = field(default_factory=dict)


@dataclass
class DaemonResult:
    """What a run did, for the CLI summary and the demo."""

    reason: str
    sim_time_s: float
    wall_time_s: float
    detected_rotor: int
    detection_time_s: float
    attack_estimate_samples: int
    final_path_distance_m: float
    mode: str
    stats: DaemonStats

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


class Daemon:
    """The offboard controller for one vehicle. See the module docstring."""

    def __init__(self, scenario: Scenario, *, vehicle: Address, bind: Address | None = None,
                 realtime: bool = False, state_timeout_s: float = 0.5, sysid: int = 1,
                 compid: int = mav.MAV_COMP_ID_ONBOARD_COMPUTER,
                 vehicle_sysid: int | None = None, key: bytes | None = None,
                 on_frame: FrameHook | None = None,
                 on_tick: Callable[[float, dict[str, Any]], None] | None = None,
                 on_event: Callable[[str, str, float], None] | None = None) -> None:
        """Open the socket towards ``vehicle`` (raises LinkError).

        ``key``: 32-byte MAVLink 2 signing secret (the vehicle's), or None (unsigned).
        ``on_tick(sim_time_s, state)`` sees the controller's internals every tick (the
        recorder's ``/controller/state``); ``on_event(level, text, sim_time_s)`` every
        event also sent as STATUSTEXT.
        """
        if not (math.isfinite(state_timeout_s) and state_timeout_s > 0):
            raise ValueError(f"state_timeout_s: must be > 0 s, got {state_timeout_s}")
        self.scenario = scenario
        self.realtime = realtime
        self.state_timeout_s = state_timeout_s
        self.computer = FlightComputer(scenario)
        self.signing = Signing(key) if key is not None else None
        self.link = Link.connect(vehicle, src_system=sysid, src_component=compid, bind=bind,
                                 peer_sysid=vehicle_sysid, on_frame=on_frame,
                                 signing=self.signing)
        self.on_tick = on_tick
        self.on_event = on_event
        self.stats = DaemonStats()
        self.thrust_max_n = scenario.vehicle.thrust_max_n
        self.k_f = scenario.vehicle.k_f
        self._stop = threading.Event()
        self._pending_state: Any = None
        self._last_cmd = [scenario.vehicle.mass_kg * scenario.vehicle.gravity_mps2 / 4.0] * 4
        self._mode = Mode.NOMINAL
        self._failsafe = False
        self._next_telemetry_s = 0.0
        self._sim_time_s = 0.0
        self._est_n = 0
        self._distance = math.nan
        self._vehicle_done = ""
        self._statustext_id = 0
        self._answered_usec = -1       # time_usec of the last state answered
        self._last_reply: Any = None   # its HIL_ACTUATOR_CONTROLS (resent for a resent state)

    def stop(self) -> None:
        """End :meth:`run` soon. Safe from a signal handler or another thread."""
        self._stop.set()

    def close(self) -> None:
        self.link.close()

    # ------------------------------------------------------------------ main loop
    def run(self, duration_s: float | None = None) -> DaemonResult:
        """Fly until ``duration_s`` of sim time (None: the scenario's), the vehicle says it is
        done (HEARTBEAT POWEROFF/EMERGENCY) or :meth:`stop`."""
        duration = self.scenario.run.duration_s if duration_s is None else duration_s
        wall0 = time.monotonic()
        next_heartbeat = 0.0
        last_state_wall = time.monotonic()
        reason = "stopped"
        next_waiting_report = wall0 + _WAITING_REPORT_PERIOD_S
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_heartbeat:
                self.link.send(mav.MAVLink_heartbeat_message(
                    mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID,
                    _ARMED, 0, mav.MAV_STATE_ACTIVE, 3))
                next_heartbeat = now + 1.0
            ticked = False
            for msg in self.link.recv(timeout_s=0.05):
                if self._handle(msg):
                    ticked = True
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
            if self._vehicle_done:
                reason = self._vehicle_done
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
        st = self.link.stats
        host, port = self.link.peer or ("?", 0)
        text = (f"no vehicle state after {waited_s:.0f} s: {st.rx_frames} frames accepted, "
                f"{st.rejected} rejected from {host}:{port}")
        if self.signing is not None:
            text += (f" (signing: bad_signature {st.bad_signature}, unsigned {st.unsigned}, "
                     f"replayed {st.replayed}, bad_timestamp {st.bad_timestamp}); is the "
                     "vehicle running, with the same --key-file?")
        else:
            text += "; is the vehicle running there (tfl-mav sim)?"
        self._event("warning", text, send=False)

    # ------------------------------------------------------------------ messages
    def _handle(self, msg: Any) -> bool:
        """Dispatch one accepted message; True if it completed a control tick."""
        mid = msg.get_msgId()
        if mid == mav.MAVLINK_MSG_ID_ODOMETRY:
            try:
                self._pending_state = paper_from_odometry(msg)
            except ValueError as exc:
                self.stats.bad_states += 1
                self._event("warning", f"ODOMETRY rejected: {exc}", quiet=True)
                self._pending_state = None
                return False
            self.stats.states += 1
            return False
        if mid == mav.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4:
            state = self._pending_state
            rpm = [float(r) for r in msg.rpm]
            self.stats.esc_reports += 1
            if state is None:
                return False
            self._pending_state = None
            if not self.realtime and state.time_usec == self._answered_usec:
                # Lockstep resend (our reply was lost): the same answer again, never a second
                # controller step for one tick (the flight must not depend on packet loss).
                self.stats.states_resent += 1
                self.link.send(self._last_reply)
                return False
            self._tick(state, rpm)
            return True
        if mid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            if msg.system_status in (mav.MAV_STATE_POWEROFF, mav.MAV_STATE_EMERGENCY) \
                    and self.stats.ticks > 0:
                self._vehicle_done = ("vehicle reported EMERGENCY (crashed)"
                                      if msg.system_status == mav.MAV_STATE_EMERGENCY
                                      else "vehicle powered off (run over)")
            return False
        if mid == mav.MAVLINK_MSG_ID_STATUSTEXT:
            self._event("info", f"vehicle: {msg.text}", send=False)
            return False
        self.stats.ignored_messages += 1
        return False

    def _tick(self, state: State, rpm: list[float]) -> None:
        t = state.time_usec * 1e-6
        self._sim_time_s = t
        self.stats.ticks += 1
        res = self.computer.step(t, state, rpm, self._last_cmd)
        out = res.law
        if res.new_detection:
            self._event("warning", f"ATTACK on rotor {res.attack_rotor} detected at "
                                   f"t={t:.3f} s; attacked law engaged")
        thrust = res.thrust_n
        self._last_cmd = thrust
        fmax = self.thrust_max_n
        controls = [f / fmax for f in thrust] + [0.0] * 12
        self._last_reply = mav.MAVLink_hil_actuator_controls_message(
            state.time_usec, controls, _ARMED, 0 if self.realtime else _LOCKSTEP_FLAG)
        self._answered_usec = state.time_usec
        self.link.send(self._last_reply)
        self.stats.commands_sent += 1
        self._mode = out.mode
        self._distance = out.path_distance_m
        if out.mode is Mode.FALLBACK:
            self.stats.fallback_ticks += 1
        if any(out.saturated):
            self.stats.saturated_ticks += 1
        if res.attack_rotor and math.isfinite(res.attack_estimate_n):
            self._est_n += 1
        if self.on_tick is not None:
            self.on_tick(t, tick_state(res))
        if t >= self._next_telemetry_s:
            self._next_telemetry_s = t + _TELEMETRY_PERIOD_S
            self._telemetry(state.time_usec, res)

    def _telemetry(self, time_usec: int, res: TickResult) -> None:
        out = res.law
        ms = (time_usec // 1000) & 0xFFFFFFFF
        det = res.detection
        est = det.estimate_n if det is not None else res.attack_estimate_n
        est = est if math.isfinite(est) else 0.0
        dist = out.path_distance_m if math.isfinite(out.path_distance_m) else -1.0
        for name, value in (("mode", float(out.mode)),
                            ("det_rotor", float(res.attack_rotor)),
                            ("atk_est_n", est), ("path_m", dist)):
            self.link.send(mav.MAVLink_named_value_float_message(ms, name.encode(), value))
        arr = [*out.xi[0], *out.xi[1], *out.eta[1:]]
        arr = [v if math.isfinite(v) else 0.0 for v in arr]
        self.link.send(mav.MAVLink_debug_float_array_message(
            time_usec, b"tfl", 1, arr + [0.0] * (58 - len(arr))))

    def _event(self, level: str, text: str, *, send: bool = True, quiet: bool = False) -> None:
        if self.on_event is not None and not quiet:
            self.on_event(level, text, self._sim_time_s)
        if not send:
            return
        severity = {"info": mav.MAV_SEVERITY_INFO, "warning": mav.MAV_SEVERITY_WARNING,
                    "critical": mav.MAV_SEVERITY_CRITICAL}.get(level, mav.MAV_SEVERITY_INFO)
        self._statustext_id = (self._statustext_id % 0xFFFF) + 1
        self.link.send(mav.MAVLink_statustext_message(severity, text[:50].encode(),
                                                      self._statustext_id, 0))


def tick_state(res: TickResult) -> dict[str, Any]:
    """The controller's internals of one tick, as the recorder's ``/controller/state``."""
    out, det = res.law, res.detection
    est = det.estimate_n if det is not None else res.attack_estimate_n
    return {
        "mode": str(out.mode), "detected_rotor": res.attack_rotor,
        "attack_estimate_n": est if math.isfinite(est) else None,
        "path_distance_m": out.path_distance_m, "saturated": any(out.saturated),
        "rotor_thrust_cmd_n": res.thrust_n, "xi": [list(out.xi[0]), list(out.xi[1])],
        "eta": list(out.eta), "mass_estimate_kg": out.mass_estimate_kg,
        "fine_gains": out.fine_gains, "reason": out.reason,
        "cusum": list(det.cusum) if det is not None else [],
    }
