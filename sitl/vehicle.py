"""The simulated vehicle's MAVLink endpoint and clock (docs/design.md, "The wire" and "Time").

One :class:`Vehicle` owns a :class:`~sitl.simulator.Simulator` and two links:

* the **control port** (``listen``): the offboard controller. The peer is the sender of the
  first valid HEARTBEAT (or ``peer`` if pinned); everything else is counted and dropped by
  :class:`~tfl_mav.link.transport.Link`.
* the optional **GCS port** (``gcs``): a separate socket that sends to a ground station
  (MAVProxy, QGroundControl, mavsdk) and accepts its commands.

**Start.** Until the controller's first HEARTBEAT arrives the vehicle waits: sim time does
not advance, it sends HEARTBEAT at 1 Hz to the GCS (and to a pinned ``peer``), and it
answers commands on either port. The flight starts the moment that HEARTBEAT arrives.

**Lockstep (default).** Tick k: send ``ODOMETRY`` (``time_usec`` = k·T, LOCAL_NED pose,
BODY_FRD twist) and ``ESC_TELEMETRY_1_TO_4`` (true rotor speed as the ESC measures it) in
one datagram, ODOMETRY first (:meth:`~tfl_mav.link.transport.Link.send_many`), wait for
``HIL_ACTUATOR_CONTROLS`` whose ``time_usec`` equals k·T, apply it, integrate to k+1.
Replies for another ``time_usec`` are counted (``stale_controls``) and ignored. No reply
within ``lockstep_timeout_s`` (wall time) is counted (``lockstep_timeouts``), announced by
STATUSTEXT, and the state is sent again; the tick is never skipped, so a lockstep run is
deterministic and runs as fast as both processes allow. The control port's HEARTBEAT is
paced by sim time (every 1 s of it), so the control port's traffic is a pure function of the
scenario and the controller's replies.

**Real time** (``realtime=True``). Physics follows the wall clock; the latest valid command
is held (zero-order hold); replies older than the newest applied one are ``stale``. The run
starts with the rotors at hover thrust (part of the initial state). If no valid command
arrives for ``command_timeout_s`` the vehicle does what a real ESC does when its signal
stops: **the motors are cut to zero thrust** (counted in ``command_timeouts``, STATUSTEXT
EMERGENCY); the next valid command restores them. Falling behind the wall clock by more than
0.1 s re-anchors the clock (counted in ``overruns``) instead of racing to catch up.

**Commands.** ``HIL_ACTUATOR_CONTROLS``: ``controls[0..3]`` = rotor thrust / f_max in
[0, 1] (rotor i+1 on index i; indices 4-15 are ignored); ``mode`` bit 128 (armed) clear
commands zero thrust. A NaN/inf or a value outside [0, 1] by more than
:data:`CONTROL_TOLERANCE` is rejected whole and counted (``rejected_controls``): the motors
keep the previous command, and in lockstep the reply still completes its tick (the vehicle
holds the previous command for that tick, as real hardware would).
``COMMAND_LONG``/``COMMAND_INT`` ``MAV_CMD_INJECT_FAILURE`` (param1 = 101 motor, param2 =
failure type, param3 = rotor 1-4) on either port starts the attack now and is answered
``COMMAND_ACK ACCEPTED``; bad parameters get ``DENIED`` and a STATUSTEXT naming the field;
any other command gets ``UNSUPPORTED``. Commands addressed to another system or component
are not ours and are left unanswered (MAVLink routing).

**GCS telemetry** (paced by wall clock): ``ATTITUDE``, ``LOCAL_POSITION_NED`` (both NED/FRD
from the same measured state as ODOMETRY), ``ACTUATOR_OUTPUT_STATUS`` (``actuator[0..3]`` =
commanded thrust / f_max), ``SYS_STATUS`` (battery from :mod:`sitl.power`;
``errors_count1..4`` = rejected controls, lockstep timeouts, command timeouts, stale
controls) and the latest ``ESC_TELEMETRY_1_TO_4`` (so a GCS sees the attacked rotor's rpm)
at ``gcs_rate_hz`` (≤ 50 Hz, one datagram each time), HEARTBEAT at 1 Hz, and every
STATUSTEXT (ASCII; longer than 50 characters → MAVLink 2 chunks with a shared ``id``).

**End.** The run ends when the duration is reached (:attr:`ExitStatus.COMPLETED`), when the
simulator reports a crash (:attr:`ExitStatus.CRASHED`: STATUSTEXT EMERGENCY with the reason,
HEARTBEAT ``MAV_STATE_EMERGENCY``) or on :meth:`Vehicle.stop` (:attr:`ExitStatus.STOPPED`).
A last HEARTBEAT with ``MAV_STATE_POWEROFF`` (or EMERGENCY after a crash) tells both peers.

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

Single-threaded: :meth:`Vehicle.run` must be called from one thread; :meth:`Vehicle.stop` is
safe from any thread or a signal handler.
"""

from __future__ import annotations

import math
import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

from sitl.attacker import FAILURE_TYPES
from sitl.power import PowerModel
from sitl.simulator import Simulator
from tfl_mav.frames import (
    MAV_FRAME_BODY_FRD,
    MAV_FRAME_LOCAL_NED,
    enu_to_ned,
    odometry_from_paper,
)
from tfl_mav.geometry import euler_zyx_from_rotation, rotation_from_quaternion
from tfl_mav.link.dialect import mav
from tfl_mav.link.signing import Signing
from tfl_mav.link.transport import Address, FrameHook, Link, LinkStats
from tfl_mav.scenario import Scenario

__all__ = [
    "CONTROL_TOLERANCE",
    "ExitStatus",
    "Vehicle",
    "VehicleResult",
    "VehicleStats",
]

CONTROL_TOLERANCE = 1e-4
"""Normalised controls within this of [0, 1] are clamped; beyond it they are rejected."""

_ID_HEARTBEAT = mav.MAVLINK_MSG_ID_HEARTBEAT
_ID_HIL_ACTUATOR_CONTROLS = mav.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS
_ID_COMMAND_LONG = mav.MAVLINK_MSG_ID_COMMAND_LONG
_ID_COMMAND_INT = mav.MAVLINK_MSG_ID_COMMAND_INT
_ID_COMMANDS = (_ID_COMMAND_LONG, _ID_COMMAND_INT)
_CONTROL_LINK_ID, _GCS_LINK_ID = 0, 1      # MAVLink signing link ids of our two ports
_ARMED = mav.MAV_MODE_FLAG_SAFETY_ARMED
_STATUSTEXT_LEN = 50
_STATUSTEXT_MAX_CHUNKS = 4
_STATUS_MIN_INTERVAL_S = 1.0   # per-reason rate limit of repeated STATUSTEXTs (wall time)
_WAIT_SLICE_S = 0.05           # longest uninterrupted wait: bounds the reaction to stop()
_OVERRUN_S = 0.1               # real time: re-anchor the clock when this far behind
_SENSORS = (mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL
            | mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | mav.MAV_SYS_STATUS_SENSOR_BATTERY)
# ODOMETRY covariance arrays: upper triangle of a 6×6 matrix, row-major; diagonal indices.
_COV_DIAGONAL = (0, 6, 11, 15, 18, 20)

# What _on_controls did with a HIL_ACTUATOR_CONTROLS message.
_APPLIED, _REJECTED, _STALE = 0, 1, 2


class ExitStatus(Enum):
    """How a run ended; the value is the sentence a user reads."""

    COMPLETED = "ran for the requested duration"
    CRASHED = "the vehicle crashed"
    STOPPED = "stopped on request"


@dataclass(frozen=True)
class VehicleResult:
    """Outcome of :meth:`Vehicle.run`. ``wall_time_s`` counts from the flight's start (the
    controller's first HEARTBEAT), not the wait before it."""

    status: ExitStatus
    reason: str
    ticks: int
    sim_time_s: float
    wall_time_s: float

    @property
    def real_time_factor(self) -> float:
        """Sim seconds per wall second (lockstep: how much faster than real time)."""
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else math.nan


@dataclass
class VehicleStats:
    """Counters of one vehicle; the links' own counters are attached live."""

    ticks: int = 0                  # control periods integrated
    states_sent: int = 0            # ODOMETRY + ESC_TELEMETRY pairs, resends included
    controls_applied: int = 0
    rejected_controls: int = 0      # NaN/inf or out of [0, 1]: never applied
    stale_controls: int = 0         # not the awaited time_usec (lockstep) / older (real time)
    lockstep_timeouts: int = 0      # no reply within lockstep_timeout_s: state resent
    command_timeouts: int = 0       # real time: no valid command for command_timeout_s → cut
    overruns: int = 0               # real time: fell > 0.1 s behind the wall clock
    commands_accepted: int = 0
    commands_denied: int = 0        # MAV_CMD_INJECT_FAILURE with bad parameters / disabled
    commands_unsupported: int = 0
    commands_not_for_us: int = 0    # addressed to another system/component: not answered
    failures_injected: int = 0      # accepted INJECT_FAILURE other than type 0 (OK = clear)
    statustexts_sent: int = 0
    statustexts_suppressed: int = 0  # repeats inside the per-reason rate limit
    control_link: LinkStats = field(default_factory=LinkStats)
    gcs_link: LinkStats | None = None

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: v for k, v in self.__dict__.items()
                               if k not in ("control_link", "gcs_link")}
        out["control_link"] = self.control_link.as_dict()
        out["gcs_link"] = self.gcs_link.as_dict() if self.gcs_link is not None else None
        return out

    def summary(self) -> str:
        """Vehicle counters that are not zero, then each link's one-line summary."""
        own = [f"{k} {v}" for k, v in self.__dict__.items()
               if v and k not in ("control_link", "gcs_link")]
        text = "vehicle: " + (", ".join(own) or "nothing counted")
        text += f"; control link: {self.control_link.summary()}"
        if self.gcs_link is not None:
            text += f"; gcs link: {self.gcs_link.summary()}"
        return text


class Vehicle:
    """A simulated quadrotor on UDP. See the module docstring for the protocol."""

    def __init__(self, scenario: Scenario, *, listen: Address,
                 gcs: Address | None = None, peer: Address | None = None,
                 realtime: bool = False, lockstep_timeout_s: float = 2.0,
                 command_timeout_s: float = 0.25, gcs_rate_hz: float = 50.0,
                 allow_failure_injection: bool = True, sysid: int = 1, compid: int = 1,
                 key: bytes | None = None, on_frame: FrameHook | None = None,
                 on_truth: Callable[[Simulator], None] | None = None,
                 on_status: Callable[[int, str], None] | None = None) -> None:
        """Bind the sockets (raises :class:`~tfl_mav.link.transport.LinkError`) and build the sim.

        ``listen``: control port to bind (port 0 = ephemeral, see :attr:`listen_address`).
        ``gcs``: where a ground station listens, or None. ``peer``: pin the controller's
        address instead of learning it. ``lockstep_timeout_s``/``command_timeout_s``: wall
        seconds (see the module docstring). ``gcs_rate_hz``: GCS telemetry rate, at most
        50 Hz. ``key``: 32-byte MAVLink 2 signing secret for both ports, or None (unsigned).
        ``on_status(severity, text)`` sees every STATUSTEXT the vehicle sends.
        """
        for name, value in (("lockstep_timeout_s", lockstep_timeout_s),
                            ("command_timeout_s", command_timeout_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: must be a positive number of seconds, got {value}")
        if not (math.isfinite(gcs_rate_hz) and 0 < gcs_rate_hz <= 50):
            raise ValueError(f"gcs_rate_hz: must be in (0, 50] Hz, got {gcs_rate_hz}")
        self.scenario = scenario
        self.sim = Simulator(scenario)
        self.realtime = realtime
        self.lockstep_timeout_s = lockstep_timeout_s
        self.command_timeout_s = command_timeout_s
        self.gcs_period_s = 1.0 / gcs_rate_hz
        self.allow_failure_injection = allow_failure_injection
        self.sysid = sysid
        self.compid = compid
        self.on_truth = on_truth
        self.on_status = on_status
        self.signing = Signing(key) if key is not None else None
        self.control_link = Link.listen(listen, src_system=sysid, src_component=compid,
                                        peer=peer, on_frame=on_frame, signing=self.signing,
                                        link_id=_CONTROL_LINK_ID)
        self.gcs_link: Link | None = None
        if gcs is not None:
            try:
                self.gcs_link = Link.connect(gcs, src_system=sysid, src_component=compid,
                                             on_frame=on_frame, signing=self.signing,
                                             link_id=_GCS_LINK_ID)
            except Exception:
                self.control_link.close()
                raise
        self.stats = VehicleStats(control_link=self.control_link.stats,
                                  gcs_link=self.gcs_link.stats if self.gcs_link else None)
        v = scenario.vehicle
        self.power = PowerModel(drag_thrust_ratio_m=v.drag_thrust_ratio_m, k_f=v.k_f)
        self.power.step(self.sim.motors.omega_radps, 0.0)
        sens = scenario.sensors
        self._pose_cov = _covariance((sens.position_noise_std_m,) * 3
                                     + (sens.attitude_noise_std_rad,) * 3)
        self._vel_cov = _covariance((sens.velocity_noise_std_mps,) * 3
                                    + (sens.rate_noise_std_radps,) * 3)
        self._fds = [self.control_link.fileno()]
        if self.gcs_link is not None:
            self._fds.append(self.gcs_link.fileno())
        self._stop = threading.Event()
        self._external_stop: threading.Event | None = None
        self._armed = False
        self._flying = False
        self._motors_cut = False
        self._system_status = mav.MAV_STATE_STANDBY
        self._controller_seen = False
        self._refused_reported = 0
        self._last_controls_usec = -1
        self._esc_count = 0
        self._state_msgs: tuple[Any, Any] | None = None
        self._status_last: dict[str, float] = {}
        self._status_suppressed: dict[str, int] = {}
        self._statustext_id = 0
        self._last_inject: tuple[Any, ...] | None = None
        self._next_gcs_s = 0.0
        self._next_gcs_heartbeat_s = 0.0
        self._ran = False

    # ------------------------------------------------------------------ lifecycle
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
        self._system_status = mav.MAV_STATE_ACTIVE
        wall0 = time.monotonic()
        if self.on_truth is not None:
            self.on_truth(self.sim)
        loop = self._run_realtime if self.realtime else self._run_lockstep
        status, reason = loop(n_ticks)
        return self._finish(status, reason, time.monotonic() - wall0)

    def _stopped(self) -> bool:
        ext = self._external_stop
        return self._stop.is_set() or (ext is not None and ext.is_set())

    # ------------------------------------------------------------------ phases
    def _await_controller(self) -> bool:
        """Before the flight: HEARTBEAT at 1 Hz to the GCS (and a pinned peer), answer
        commands, until the controller's first HEARTBEAT. False if stopped first."""
        next_heartbeat = 0.0
        ctl = self.control_link
        while not self._controller_seen:
            if self._stopped():
                return False
            now = time.monotonic()
            if now >= next_heartbeat:
                hb = self._heartbeat()
                if ctl.peer is not None:
                    ctl.send(hb)
                if self.gcs_link is not None:
                    self.gcs_link.send(hb)
                next_heartbeat = now + 1.0
            self._wait(min(_WAIT_SLICE_S, max(0.0, next_heartbeat - time.monotonic())))
            self._drain(None)
            if self.signing is not None:
                self._report_refused_signatures()
        host, port = ctl.peer or ("?", 0)
        self._status(mav.MAV_SEVERITY_INFO, f"controller {host}:{port} (sysid "
                                            f"{ctl.peer_sysid}) connected: flight starts")
        return True

    def _report_refused_signatures(self) -> None:
        """Before the flight: say so when would-be controllers' frames fail signing."""
        st = self.control_link.stats
        refused = st.unsigned + st.bad_signature + st.replayed + st.bad_timestamp
        if refused > self._refused_reported:
            self._refused_reported = refused
            self._status(mav.MAV_SEVERITY_WARNING,
                         f"control port: {refused} frames refused by signing (bad_signature "
                         f"{st.bad_signature}, unsigned {st.unsigned}, replayed {st.replayed}, "
                         f"bad_timestamp {st.bad_timestamp}); same --key-file on both sides?",
                         key="signing")

    def _run_lockstep(self, n_ticks: float) -> tuple[ExitStatus, str]:
        sim = self.sim
        stats = self.stats
        ticks_per_heartbeat = max(1, round(1.0 / sim.control_dt_s))
        ctl = self.control_link
        gcs = self.gcs_link
        while stats.ticks < n_ticks:
            if stats.ticks % ticks_per_heartbeat == 0:
                ctl.send(self._heartbeat())
            self._publish_state()
            if gcs is not None:
                self._gcs_periodic()
            if not self._await_reply(sim.time_usec):
                return ExitStatus.STOPPED, "stopped on request"
            crash = self._step()
            if crash is not None:
                return ExitStatus.CRASHED, crash
        return ExitStatus.COMPLETED, f"ran {sim.time_s:.3f} s of sim time"

    def _await_reply(self, time_usec: int) -> bool:
        """Lockstep: block until the reply for ``time_usec`` is consumed; False if stopped."""
        ctl = self.control_link
        deadline = time.monotonic() + self.lockstep_timeout_s
        while True:
            # Wait first: the reply is at least one round trip away, and select() returns
            # at once if it is already queued.
            self._wait(min(_WAIT_SLICE_S, deadline - time.monotonic()))
            awaited = time_usec
            for msg in ctl.recv(0.0):
                # Handle the whole batch (a command may follow the reply); once the reply
                # is consumed, a duplicate for the same tick is stale (-1 matches nothing).
                if self._dispatch(ctl, msg, awaited) is not None:
                    awaited = -1
            if self.gcs_link is not None:
                self._drain_gcs()
            if awaited == -1:
                return True
            if self._stopped():
                return False
            now = time.monotonic()
            if now >= deadline:
                self.stats.lockstep_timeouts += 1
                self._status(mav.MAV_SEVERITY_WARNING,
                             f"lockstep: no HIL_ACTUATOR_CONTROLS for time_usec {time_usec} "
                             f"within {self.lockstep_timeout_s:g} s; state resent",
                             key="lockstep_timeout")
                ctl.send(self._heartbeat())
                self._resend_state()
                deadline = now + self.lockstep_timeout_s
                if self.gcs_link is not None:
                    self._gcs_periodic()

    def _run_realtime(self, n_ticks: float) -> tuple[ExitStatus, str]:
        sim = self.sim
        stats = self.stats
        dt = sim.control_dt_s
        ticks_per_heartbeat = max(1, round(1.0 / dt))
        ctl = self.control_link
        gcs = self.gcs_link
        t0 = time.monotonic()
        last_command_s = t0
        k0 = 0   # tick at which the clock was last anchored at t0
        while stats.ticks < n_ticks:
            if stats.ticks % ticks_per_heartbeat == 0:
                ctl.send(self._heartbeat())
            self._publish_state()
            target = t0 + (stats.ticks + 1 - k0) * dt
            while True:
                for msg in ctl.recv(0.0):
                    if self._dispatch(ctl, msg, None) == _APPLIED:
                        last_command_s = time.monotonic()
                if gcs is not None:
                    self._gcs_periodic()
                    self._drain_gcs()
                if self._stopped():
                    return ExitStatus.STOPPED, "stopped on request"
                now = time.monotonic()
                if now >= target:
                    break
                self._wait(min(_WAIT_SLICE_S, target - now))
            if not self._motors_cut and now - last_command_s > self.command_timeout_s:
                self._cut_motors(now - last_command_s)
            crash = self._step()
            if crash is not None:
                return ExitStatus.CRASHED, crash
            if now - target > _OVERRUN_S:
                stats.overruns += 1
                t0, k0 = now, stats.ticks
                self._status(mav.MAV_SEVERITY_WARNING,
                             f"real time: physics fell {now - target:.3f} s behind the wall "
                             "clock; clock re-anchored", key="overrun")
        return ExitStatus.COMPLETED, f"ran {sim.time_s:.3f} s of sim time"

    def _step(self) -> str | None:
        """Integrate one control period; return the crash reason, if any."""
        sim = self.sim
        sim.step_control_period()
        self.stats.ticks += 1
        self.power.step(sim.motors.omega_radps, sim.control_dt_s)
        if self.on_truth is not None:
            self.on_truth(sim)
        return sim.crash_reason()

    def _finish(self, status: ExitStatus, reason: str, wall_s: float) -> VehicleResult:
        if status is ExitStatus.CRASHED:
            self._system_status = mav.MAV_STATE_EMERGENCY
            self._status(mav.MAV_SEVERITY_EMERGENCY, f"crashed: {reason}")
        else:
            self._system_status = mav.MAV_STATE_POWEROFF
            self._status(mav.MAV_SEVERITY_INFO,
                         f"simulation ended at t = {self.sim.time_s:.3f} s: {status.value}")
        hb = self._heartbeat()
        for link in (self.control_link, self.gcs_link):
            if link is not None and link.peer is not None:
                link.send(hb)
        return VehicleResult(status, reason, self.stats.ticks, self.sim.time_s, wall_s)

    # ------------------------------------------------------------------ receiving
    def _wait(self, timeout_s: float) -> None:
        """Sleep until a datagram arrives on either socket or ``timeout_s`` passes."""
        if timeout_s > 0.0:
            select.select(self._fds, [], [], timeout_s)

    def _drain(self, awaited_usec: int | None) -> None:
        ctl = self.control_link
        for msg in ctl.recv(0.0):
            self._dispatch(ctl, msg, awaited_usec)
        if self.gcs_link is not None:
            self._drain_gcs()

    def _drain_gcs(self) -> None:
        gcs = self.gcs_link
        assert gcs is not None
        for msg in gcs.recv(0.0):
            mid = msg.get_msgId()
            if mid in _ID_COMMANDS:
                self._on_command(gcs, msg)

    def _dispatch(self, link: Link, msg: Any, awaited_usec: int | None) -> int | None:
        """Handle one message from the control port; the HIL_ACTUATOR_CONTROLS outcome
        (``_APPLIED``/``_REJECTED``) if it completes the awaited tick, else None."""
        mid = msg.get_msgId()
        if mid == _ID_HIL_ACTUATOR_CONTROLS:
            if not self._flying:
                self.stats.stale_controls += 1
                return None
            outcome = self._on_controls(msg, awaited_usec)
            return None if outcome == _STALE else outcome
        if mid == _ID_HEARTBEAT:
            self._controller_seen = True
        elif mid in _ID_COMMANDS:
            self._on_command(link, msg)
        return None

    def _on_controls(self, msg: Any, awaited_usec: int | None) -> int:
        """Validate and apply one HIL_ACTUATOR_CONTROLS. Lockstep (``awaited_usec`` given):
        only the awaited time_usec counts. Real time: newest wins, never the future."""
        stats = self.stats
        t = msg.time_usec
        if awaited_usec is not None:
            if t != awaited_usec:
                stats.stale_controls += 1
                self._status(mav.MAV_SEVERITY_WARNING,
                             f"HIL_ACTUATOR_CONTROLS.time_usec: {t} is not the awaited "
                             f"{awaited_usec}; ignored", key="stale")
                return _STALE
        elif t < self._last_controls_usec or t > self.sim.time_usec:
            stats.stale_controls += 1
            return _STALE
        controls = msg.controls
        problem = _check_controls(controls)
        if problem is not None:
            stats.rejected_controls += 1
            self._status(mav.MAV_SEVERITY_ERROR,
                         f"HIL_ACTUATOR_CONTROLS.{problem}; rejected, previous command held",
                         key="rejected_controls")
            return _REJECTED
        self._last_controls_usec = t
        armed = bool(msg.mode & _ARMED)
        if armed != self._armed:
            self._armed = armed
            self._status(mav.MAV_SEVERITY_NOTICE,
                         "armed by the controller" if armed
                         else "disarmed by the controller (mode bit 128 clear): motors stopped")
        fmax = self.sim.thrust_max_n
        if armed:
            self.sim.set_command([controls[0] * fmax, controls[1] * fmax,
                                  controls[2] * fmax, controls[3] * fmax])
        else:
            self.sim.set_command([0.0, 0.0, 0.0, 0.0])
        stats.controls_applied += 1
        if self._motors_cut:
            self._motors_cut = False
            self._system_status = mav.MAV_STATE_ACTIVE
            self._status(mav.MAV_SEVERITY_NOTICE, "commands resumed: motors restored")
        return _APPLIED

    def _cut_motors(self, silent_s: float) -> None:
        """Real time link loss: zero thrust, like an ESC whose signal stopped."""
        self.stats.command_timeouts += 1
        self._motors_cut = True
        self._system_status = mav.MAV_STATE_EMERGENCY
        self.sim.set_command([0.0, 0.0, 0.0, 0.0])
        self._status(mav.MAV_SEVERITY_EMERGENCY,
                     f"link loss: no valid HIL_ACTUATOR_CONTROLS for {silent_s:.3f} s "
                     f"(> {self.command_timeout_s:g} s): motors cut")

    # ------------------------------------------------------------------ commands
    def _on_command(self, link: Link, msg: Any) -> None:
        """COMMAND_LONG / COMMAND_INT: answer INJECT_FAILURE, refuse the rest explicitly."""
        stats = self.stats
        if msg.target_system not in (0, self.sysid) or msg.target_component not in (
                0, self.compid):
            stats.commands_not_for_us += 1
            return
        command = msg.command
        if command != mav.MAV_CMD_INJECT_FAILURE:
            stats.commands_unsupported += 1
            self._ack(link, msg, mav.MAV_RESULT_UNSUPPORTED)
            return
        params = (msg.param1, msg.param2, msg.param3)
        key = (msg.get_srcSystem(), msg.get_srcComponent(), *params)
        if getattr(msg, "confirmation", 0) > 0 and key == self._last_inject:
            self._ack(link, msg, mav.MAV_RESULT_ACCEPTED)   # retransmission: already applied
            return
        try:
            rotor, failure_type = self._inject(*params)
        except ValueError as exc:
            stats.commands_denied += 1
            self._status(mav.MAV_SEVERITY_ERROR, f"MAV_CMD_INJECT_FAILURE denied: {exc}")
            self._ack(link, msg, mav.MAV_RESULT_DENIED)
            return
        self._last_inject = key
        stats.commands_accepted += 1
        self._ack(link, msg, mav.MAV_RESULT_ACCEPTED)
        if failure_type == 0:
            self._status(mav.MAV_SEVERITY_NOTICE,
                         f"failure cleared: rotor {rotor} at t = {self.sim.time_s:.3f} s")
            return
        stats.failures_injected += 1
        self._status(mav.MAV_SEVERITY_WARNING,
                     f"failure injected: rotor {rotor} {FAILURE_TYPES[failure_type].upper()} "
                     f"at t = {self.sim.time_s:.3f} s")

    def _inject(self, param1: float, param2: float, param3: float) -> tuple[int, int]:
        """Validate MAV_CMD_INJECT_FAILURE's parameters and start the attack; ValueError
        naming the parameter otherwise."""
        if not self.allow_failure_injection:
            raise ValueError("failure injection is disabled on this vehicle")
        unit = _whole(param1, "param1 (failure unit)")
        if unit != mav.FAILURE_UNIT_SYSTEM_MOTOR:
            raise ValueError(f"param1 (failure unit): only {mav.FAILURE_UNIT_SYSTEM_MOTOR} "
                             f"(FAILURE_UNIT_SYSTEM_MOTOR) is supported, got {unit}")
        failure_type = _whole(param2, "param2 (failure type)")
        rotor = _whole(param3, "param3 (instance)")
        self.sim.inject_failure(rotor, failure_type)
        return rotor, failure_type

    def _ack(self, link: Link, msg: Any, result: int) -> None:
        link.send(mav.MAVLink_command_ack_message(msg.command, result, 0, 0,
                                                  msg.get_srcSystem(), msg.get_srcComponent()))

    # ------------------------------------------------------------------ sending
    def _heartbeat(self) -> Any:
        base_mode = mav.MAV_MODE_FLAG_HIL_ENABLED | (_ARMED if self._armed else 0)
        return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_GENERIC,
                                             base_mode, 0, self._system_status, 3)

    def _publish_state(self) -> None:
        """ODOMETRY + ESC_TELEMETRY_1_TO_4 of the current tick to the controller."""
        sim = self.sim
        m = sim.measured
        f = odometry_from_paper(m.position_m.tolist(), m.velocity_mps.tolist(),
                                m.quaternion_wxyz.tolist(), m.body_rates_radps.tolist())
        odometry = mav.MAVLink_odometry_message(
            sim.time_usec, MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_FRD, f.x, f.y, f.z, f.q,
            f.vx, f.vy, f.vz, f.rollspeed, f.pitchspeed, f.yawspeed, self._pose_cov,
            self._vel_cov, 0, mav.MAV_ESTIMATOR_TYPE_MOCAP, 100)
        p = self.power.sample
        self._esc_count = (self._esc_count + 1) & 0xFFFF
        count = self._esc_count
        cv = min(65535, round(p.voltage_v * 100.0))
        esc = mav.MAVLink_esc_telemetry_1_to_4_message(
            [min(255, max(0, round(t))) for t in p.temperatures_c],
            [cv, cv, cv, cv],
            [min(65535, round(i * 100.0)) for i in p.currents_a],
            [min(65535, round(c)) for c in p.consumed_mah],
            [min(65535, round(r)) for r in sim.measured_rpm().tolist()],
            [count, count, count, count])
        self._state_msgs = (odometry, esc)
        self._resend_state()

    def _resend_state(self) -> None:
        """ODOMETRY then ESC_TELEMETRY_1_TO_4, in that order, in one datagram."""
        assert self._state_msgs is not None
        self.control_link.send_many(self._state_msgs)
        self.stats.states_sent += 1

    def _gcs_periodic(self) -> None:
        """GCS telemetry at ``gcs_rate_hz`` and HEARTBEAT at 1 Hz, both on the wall clock."""
        now = time.monotonic()
        if now < self._next_gcs_s:
            return
        gcs = self.gcs_link
        assert gcs is not None
        self._next_gcs_s = max(self._next_gcs_s + self.gcs_period_s, now)
        if now >= self._next_gcs_heartbeat_s:
            gcs.send(self._heartbeat())
            self._next_gcs_heartbeat_s = max(self._next_gcs_heartbeat_s + 1.0, now)
        gcs.send_many(self._gcs_messages())

    def _gcs_messages(self) -> list[Any]:
        sim = self.sim
        m = sim.measured
        t_ms = int(sim.time_s * 1000.0) & 0xFFFFFFFF
        f = odometry_from_paper(m.position_m.tolist(), m.velocity_mps.tolist(),
                                m.quaternion_wxyz.tolist(), m.body_rates_radps.tolist())
        roll, pitch, yaw = euler_zyx_from_rotation(rotation_from_quaternion(f.q))
        v_ned = enu_to_ned(m.velocity_mps)
        fmax = sim.thrust_max_n
        actuators = [c / fmax for c in sim.rotor_commands_n] + [0.0] * 28
        p = self.power.sample
        st = self.stats
        links = [s for s in (st.control_link, st.gcs_link) if s is not None]
        rx = sum(s.rx_datagrams for s in links)
        rejected = sum(s.rejected for s in links)
        sensors_health = _SENSORS & ~(mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
                                      if self._motors_cut else 0)
        msgs = [
            mav.MAVLink_attitude_message(t_ms, roll, pitch, yaw, f.rollspeed, f.pitchspeed,
                                         f.yawspeed),
            mav.MAVLink_local_position_ned_message(t_ms, f.x, f.y, f.z, float(v_ned[0]),
                                                   float(v_ned[1]), float(v_ned[2])),
            mav.MAVLink_actuator_output_status_message(sim.time_usec, 4, actuators),
            mav.MAVLink_sys_status_message(
                _SENSORS, _SENSORS, sensors_health, 0,
                min(65535, round(p.voltage_v * 1000.0)),
                min(32767, round(p.total_current_a * 100.0)),
                max(0, min(100, round(p.remaining_pct))),
                min(10000, round(10000.0 * rejected / rx)) if rx else 0,
                min(65535, rejected),
                min(65535, st.rejected_controls), min(65535, st.lockstep_timeouts),
                min(65535, st.command_timeouts), min(65535, st.stale_controls)),
        ]
        if self._state_msgs is not None:
            msgs.append(self._state_msgs[1])   # this tick's ESC_TELEMETRY_1_TO_4: rpm
        return msgs

    def _status(self, severity: int, text: str, *, key: str | None = None) -> None:
        """STATUSTEXT to the controller and the GCS (chunked past 50 characters).

        With ``key``, repeats of the same reason within 1 s (wall) are suppressed and
        counted; the next one that goes out says how many were suppressed.
        """
        if key is not None:
            now = time.monotonic()
            last = self._status_last.get(key)
            if last is not None and now - last < _STATUS_MIN_INTERVAL_S:
                self.stats.statustexts_suppressed += 1
                self._status_suppressed[key] = self._status_suppressed.get(key, 0) + 1
                return
            self._status_last[key] = now
            skipped = self._status_suppressed.pop(key, 0)
            if skipped:
                text += f" (+{skipped} suppressed)"
        self.stats.statustexts_sent += 1
        if self.on_status is not None:
            self.on_status(severity, text)
        msgs = self._statustext_messages(severity, text)
        for link in (self.control_link, self.gcs_link):
            if link is not None and link.peer is not None:
                for msg in msgs:
                    link.send(msg)

    def _statustext_messages(self, severity: int, text: str) -> list[Any]:
        data = text.replace("°", " deg").encode("ascii", errors="replace")
        n = _STATUSTEXT_LEN
        if len(data) <= n:
            return [mav.MAVLink_statustext_message(severity, data, 0, 0)]
        data = data[:n * _STATUSTEXT_MAX_CHUNKS]
        self._statustext_id = self._statustext_id % 0xFFFF + 1
        chunks = [data[i:i + n] for i in range(0, len(data), n)]
        if len(chunks[-1]) == n and len(chunks) < _STATUSTEXT_MAX_CHUNKS:
            chunks.append(b"")   # a full last chunk needs an empty terminator (MAVLink spec)
        return [mav.MAVLink_statustext_message(severity, c, self._statustext_id, i)
                for i, c in enumerate(chunks)]


# ---------------------------------------------------------------------------- helpers
def _check_controls(controls: Any) -> str | None:
    """The first problem with controls[0..3] ("controls[2]: not finite (nan)"), or None."""
    lo, hi = -CONTROL_TOLERANCE, 1.0 + CONTROL_TOLERANCE
    for i in range(4):
        c = controls[i]
        if not math.isfinite(c):
            return f"controls[{i}]: not finite ({c})"
        if c < lo or c > hi:
            return f"controls[{i}]: {c:.6g} outside [0, 1]"
    return None


def _whole(value: float, name: str) -> int:
    """A COMMAND_LONG float parameter that must hold a whole number."""
    if not math.isfinite(value) or value != math.floor(value):
        raise ValueError(f"{name}: must be a whole number, got {value}")
    return int(value)


def _covariance(stds: tuple[float, ...]) -> list[float]:
    """ODOMETRY covariance array (21 floats, 6×6 upper triangle) with σ² on the diagonal."""
    cov = [0.0] * 21
    for index, std in zip(_COV_DIAGONAL, stds, strict=True):
        cov[index] = std * std
    return cov
