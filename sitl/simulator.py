"""The simulated vehicle without a network: rigid body + motors/ESCs + attacker + sensors.

One :class:`Simulator` owns sim time. A client sets rotor thrust commands and advances one
control period (a whole number of fixed physics steps); it reads the measured state (with the
scenario's seeded sensor noise) and the ESC rpm, and, for logs, the truth. Both the MAVLink
endpoint (``tfl_mav.sitl.vehicle``) and the in-process runner (``tfl_mav.offline``) drive
this class, so a lockstep flight over UDP and an offline flight integrate exactly the same physics.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from tfl_mav.model.geometry import euler_to_quaternion, quaternion_multiply
from tfl_mav.model.state import State
from tfl_mav.scenario import Scenario
from tfl_mav.sitl.attacker import NO_ATTACK, Attacker, AttackSample, AttackSignal
from tfl_mav.sitl.estimator import EKF_COVARIANCE_HZ, ErrorStateEkf, EstimatorOutput
from tfl_mav.sitl.motors import RADPS_TO_RPM, MotorBank
from tfl_mav.sitl.physics import (
    RigidBodyParams,
    RigidBodyState,
    Rk4Step,
    RotorAeroParams,
    rk4_air_stepper,
    rk4_stepper,
)
from tfl_mav.sitl.sensors import SensorSuite
from tfl_mav.sitl.wind import WindField

__all__ = ["Simulator"]

def _step_numpy_scalars(step: Rk4Step, x: Sequence[float], wrench: Sequence[float],
                        h: float) -> Sequence[float]:
    """The step on numpy scalars, for a diverging state only: where Python floats raise
    (``**`` overflowing, a zero quaternion norm), numpy gives inf/NaN (with a warning), so
    the run ends as :meth:`Simulator.crash_reason` says instead of with an exception."""
    with np.errstate(all="ignore"):
        return step([np.float64(c) for c in x], wrench, h)


_round = float.__round__     # round() without its per-call lookup of __round__

# Beyond these the run is over: the messages say why in words a user can act on.
MAX_BODY_RATE_RADPS = 300.0
MAX_SPEED_MPS = 100.0
_MAX_BODY_RATE2 = MAX_BODY_RATE_RADPS * MAX_BODY_RATE_RADPS   # exact: 90000, 10000
_MAX_SPEED2 = MAX_SPEED_MPS * MAX_SPEED_MPS
assert math.sqrt(_MAX_BODY_RATE2) == MAX_BODY_RATE_RADPS and math.sqrt(_MAX_SPEED2) == MAX_SPEED_MPS



def _attacked_targets(attacker: Attacker, t: float, x: Any, commands: Sequence[float],
                      held: Any, omega_for_thrust: Any) -> tuple[AttackSample, Any]:
    """One physics step's attack sample at time ``t`` s on the true state ``x`` and the
    rotor-speed targets (rad/s) it leaves: the held command's, with the attacked rotor's
    replaced by the speed of the thrust the attacker applies. ``Attacker.sample``'s own
    test (a rotor held, ``t`` past the start) is made here first: most steps need no call.
    One copy for the still-air and the moving-air steps."""
    rotor = attacker.rotor
    if rotor and t >= attacker.start_s:
        att = attacker.sample(t, x, commands[rotor - 1])
        if att.rotor:
            targets = held.copy()
            targets[att.rotor - 1] = omega_for_thrust(att.applied_n)
            return att, targets
        return att, held
    return NO_ATTACK, held

class Simulator:
    """Fixed-step physics at ``run.physics_hz``; the control period is a whole multiple."""

    def __init__(self, scenario: Scenario, *, attack_signal: AttackSignal | None = None
                 ) -> None:
        """``attack_signal(t_s, x)``: drive the scenario's attacked rotor with this function
        instead of its ``attack.signal`` (:meth:`~tfl_mav.sitl.attacker.Attacker.use_signal`)."""
        self.scenario = scenario
        v = scenario.vehicle
        self.params = RigidBodyParams(v.mass_kg, v.inertia_kgm2, v.arm_m,
                                      v.drag_thrust_ratio_m, v.k_t, v.k_r, v.gravity_mps2)
        self.physics_dt_s = scenario.run.physics_dt_s
        self.steps_per_control = scenario.run.steps_per_control
        self.control_dt_s = scenario.run.control_dt_s
        self.thrust_max_n = v.thrust_max_n
        self._rk4 = rk4_stepper(self.params)
        self._arm_m, self._drag_m = v.arm_m, v.drag_thrust_ratio_m
        self._physics_hz = scenario.run.physics_hz
        ini = scenario.initial
        # Python floats throughout: a numpy scalar (euler_to_quaternion's elements) would
        # make every derived state component a numpy scalar, and RK4's ~700 operations on
        # those cost 4-6× as much as on floats (the same IEEE results: tests/golden/test_golden.py).
        q0 = euler_to_quaternion(*ini.euler_rad).tolist()
        self._x = [float(c) for c in (*ini.position_m, *ini.velocity_mps, *q0,
                                      *ini.body_rates_radps)]
        hover_n = v.mass_kg * v.gravity_mps2 / 4.0
        self.motors = MotorBank(v.k_f, v.thrust_max_n, v.motor_time_constant_s, [hover_n] * 4)
        self.attacker = Attacker(scenario.attack, v.thrust_max_n)
        if attack_signal is not None:
            self.attacker.use_signal(attack_signal)
        self.rotor_commands_n = [hover_n] * 4
        self.physics_steps = 0
        # Sim time in µs as sent on the wire (ODOMETRY.time_usec): k·T exactly, set where
        # physics_steps advances. Read it, never write it (a plain attribute: the vehicle's
        # per-tick paths read it without a property's call).
        self.time_usec = 0
        self.tick = 0
        self.rejected_commands = 0
        self.attack = self.attacker.sample(0.0, self._x, hover_n)   # reads its position
        sens = scenario.sensors
        stds = ((v.rpm_noise_std, 4), (sens.position_noise_std_m, 3),
                (sens.velocity_noise_std_mps, 3), (sens.attitude_noise_std_rad, 3),
                (sens.rate_noise_std_radps, 3))
        self._noisy = [std > 0 for std, _ in stds]
        self._noise_scales = [std for std, n in stds if std > 0 for _ in range(n)]
        # Seeded only when a sensor is noisy: a noise-free flight never draws, and skipping
        # numpy.random's import saves ~13 ms of every offline start-up.
        self._rng = np.random.default_rng(scenario.run.seed) if self._noise_scales else None
        self._mean_thrust_n = self.motors.thrust_n
        self._gyro_range_radps = scenario.sensors.gyro_range_radps
        # Moving air or rotor aerodynamics: the air step (physics.rk4_air_step). Still air
        # with the paper's drag keeps the still-air step, untouched.
        self.wind: WindField | None = (WindField(scenario.wind, scenario.run.seed,
                                                 self.physics_dt_s)
                                       if scenario.wind.active else None)
        self.wind_mps: tuple[float, float, float] = (
            self.wind.at(0) if self.wind is not None else (0.0, 0.0, 0.0))
        if self.wind is not None or v.rotor_aero:
            aero = (RotorAeroParams(v.rotor_drag_coeff, v.rotor_inflow_coeff,
                                    v.translational_lift_coeff, v.parasitic_drag_coeff,
                                    1.0 / v.k_f, v.rotor_inertia_kgm2)
                    if v.rotor_aero else RotorAeroParams())
            # the reaction to the rotors' spin-up, J_r ω̇ about b3 (through the wrench)
            self._spin_up_kgm2 = v.rotor_inertia_kgm2 if v.rotor_aero else 0.0
            self._rk4_air = rk4_air_stepper(self.params, aero)
            self.step_control_period = self._step_control_period_air  # type: ignore[method-assign]
        # Realistic sensors: IMU, GPS, baro and mag fused onboard; the controller receives
        # the estimate (the truth never leaves the vehicle).
        self.sensors: SensorSuite | None = None
        self.estimate: EstimatorOutput | None = None
        self.estimator: ErrorStateEkf | None = None
        if sens.model == "realistic":
            self.sensors = SensorSuite(sens, scenario.run.seed, v.gravity_mps2)
            self.estimator = ErrorStateEkf(self._x, v.gravity_mps2, self.sensors.noise,
                                           sens.gps_position_noise_std_m,
                                           sens.gps_velocity_noise_std_mps,
                                           cov_every=max(1, round(scenario.run.control_hz
                                                                  / EKF_COVARIANCE_HZ)))
        # What the controller side would measure this tick, set by measure() every tick (read
        # them, never write them; plain attributes: the per-tick paths read them without a
        # property's call). measured_parts: (position m, velocity m/s, quaternion wxyz, body
        # rates rad/s) in the paper frame, measured_floats' fields without the State;
        # measured_rpm_floats: the four ESC rpm, measured_rpm() as a float tuple.
        self.measured_parts: tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...],
                                   tuple[float, ...]]
        self.measured_rpm_floats: tuple[float, ...]
        # measure(): this tick's measurement, the sensor model alone or fused by the onboard
        # estimator. step_control_period calls it once a tick (so repeated reads agree);
        # calling it again draws new noise (the benches time it alone).
        self.measure = (self._measure_estimated if self.estimator is not None
                        else self._sample_sensors)
        self.measure()

    # ------------------------------------------------------------------ time and commands
    @property
    def time_s(self) -> float:
        return self.physics_steps * self.physics_dt_s

    def set_command(self, thrust_cmd_n: Sequence[float]) -> None:
        """Set the four rotor thrust commands (N), clamped to [0, f_max].

        Raises ValueError (and keeps the previous command) for a wrong length or a value
        that is not finite: a NaN never reaches a motor.
        """
        if len(thrust_cmd_n) != 4:
            self.rejected_commands += 1
            raise ValueError(f"thrust command: expected 4 values, got {len(thrust_cmd_n)}")
        f1, f2, f3, f4 = map(float, thrust_cmd_n)
        fmax = self.thrust_max_n
        # Comparisons are False for NaN: one chained test passes every finite command in
        # range (the norm); anything else is checked, then clamped, one by one.
        if 0.0 <= f1 <= fmax and 0.0 <= f2 <= fmax and 0.0 <= f3 <= fmax and 0.0 <= f4 <= fmax:
            self.rotor_commands_n = [f1, f2, f3, f4]
            return
        values = [f1, f2, f3, f4]
        for i, f in enumerate(values):
            if not math.isfinite(f):
                self.rejected_commands += 1
                raise ValueError(f"thrust command[{i}] (rotor {i + 1}): not finite ({f})")
        self.rotor_commands_n = [min(max(f, 0.0), fmax) for f in values]

    def set_command_floats(self, f1: float, f2: float, f3: float, f4: float) -> None:
        """:meth:`set_command` of four floats (the vehicle's every tick: no list to build
        and convert); the same checks, the same errors."""
        fmax = self.thrust_max_n
        if 0.0 <= f1 <= fmax and 0.0 <= f2 <= fmax and 0.0 <= f3 <= fmax and 0.0 <= f4 <= fmax:
            self.rotor_commands_n = [f1, f2, f3, f4]
            return
        self.set_command([f1, f2, f3, f4])

    def inject_failure(self, rotor: int, failure_type: int) -> None:
        """Start an attack on ``rotor`` now (MAV_CMD_INJECT_FAILURE); ValueError if invalid."""
        self.attacker.inject(rotor, failure_type, self.time_s)

    # ------------------------------------------------------------------ integration
    def step_control_period(self) -> None:
        """Integrate one control period with the current command held (zero-order hold).

        Per physics step: the attack, the motor lag (mean thrust over the step), the mixer
        (eq. (4), written out as :func:`~tfl_mav.model.airframe.mix` computes it) and one RK4 step.
        The rotor-speed targets of the held command are computed once per period; what
        does not change in a step (constants, the last attack sample) is read or stored
        once per period.
        """
        h = self.physics_dt_s
        motors = self.motors
        attacker = self.attacker
        step = self._rk4
        ell, d = self._arm_m, self._drag_m
        commands = self.rotor_commands_n
        omega_for_thrust = motors.omega_for_thrust
        held = motors.omegas_for_thrusts(commands)
        x = self._x
        n = self.physics_steps
        att = NO_ATTACK
        mean = self._mean_thrust_n
        for _ in range(self.steps_per_control):
            att, targets = _attacked_targets(attacker, n * h, x, commands, held,
                                             omega_for_thrust)
            mean = motors.step(targets, h)
            f1, f2, f3, f4 = mean
            wrench = (f1 + f2 + f3 + f4, ell * (f4 - f2), ell * (f3 - f1),
                      d * (f1 - f2 + f3 - f4))
            try:
                x = step(x, wrench, h)
            except (OverflowError, ZeroDivisionError):
                x = _step_numpy_scalars(step, x, wrench, h)
            n += 1
        self.attack = att
        self._mean_thrust_n = mean
        self.physics_steps = n
        self._x = x
        self.time_usec = _round(n * 1_000_000 / self._physics_hz)   # round() on a float
        self.tick += 1
        self.measure()

    def _step_control_period_air(self) -> None:
        """:meth:`step_control_period` in moving air: the same attack, motors and mixer,
        then the air step with the wind at the step's start (:class:`WindField`) and the
        rotors' thrusts."""
        h = self.physics_dt_s
        motors = self.motors
        attacker = self.attacker
        step = self._rk4_air
        wind_at = self.wind.at if self.wind is not None else None
        wind = self.wind_mps
        jr = self._spin_up_kgm2
        ell, d = self._arm_m, self._drag_m
        commands = self.rotor_commands_n
        omega_for_thrust = motors.omega_for_thrust
        held = motors.omegas_for_thrusts(commands)
        x = self._x
        n = self.physics_steps
        att = NO_ATTACK
        mean = self._mean_thrust_n
        for _ in range(self.steps_per_control):
            att, targets = _attacked_targets(attacker, n * h, x, commands, held,
                                             omega_for_thrust)
            w1, w2, w3, w4 = motors.omega_radps
            mean = motors.step(targets, h)
            f1, f2, f3, f4 = mean
            tr = d * (f1 - f2 + f3 - f4)
            if jr:
                n1, n2, n3, n4 = motors.omega_radps
                tr += jr * ((n1 - w1) - (n2 - w2) + (n3 - w3) - (n4 - w4)) / h
            wrench = (f1 + f2 + f3 + f4, ell * (f4 - f2), ell * (f3 - f1), tr)
            if wind_at is not None:
                wind = wind_at(n)
            air = (wind[0], wind[1], wind[2], f1, f2, f3, f4)
            try:
                x = step(x, wrench, air, h)
            except (OverflowError, ZeroDivisionError, ValueError):
                with np.errstate(all="ignore"):
                    x = step([np.float64(c) for c in x], wrench, air, h)
            n += 1
        self.attack = att
        self._mean_thrust_n = mean
        self.physics_steps = n
        self._x = x
        self.wind_mps = wind_at(n) if wind_at is not None else wind
        self.time_usec = _round(n * 1_000_000 / self._physics_hz)
        self.tick += 1
        self.measure()

    def _sample_sensors(self) -> None:
        """Sample the sensors once per control tick (so repeated reads agree).

        One ``standard_normal`` draw for the whole tick, scaled per sensor: numpy's
        ``normal(0, σ, n)`` is ``0 + σ·z`` on the same stream of z, so this draws exactly the
        numbers (and noise) that one ``normal`` call per sensor did, at a fifth of the calls.
        Kept as float tuples (:attr:`measured_floats`); the numpy form :attr:`measured` is
        built only if read. The noisy quaternion's product and norm stay numpy (its norm is
        not a float sum to the bit).
        """
        scales = self._noise_scales
        noisy = self._noisy
        x = self._x
        w_rotor = self.motors.omega_radps
        if scales:
            z = self._rng.standard_normal(len(scales)).tolist()  # type: ignore[union-attr]
            it = iter([0.0 + sc * zi for sc, zi in zip(scales, z, strict=True)])
            rpm = [w * RADPS_TO_RPM for w in w_rotor]
            if noisy[0]:
                # A rotor that does not turn reads 0, as an ESC does (it measures speed from
                # commutation: no turning, nothing to add noise to); its draw is still taken,
                # so the other sensors' noise is the same. Only ω = 0 exactly is stopped (a
                # motor without lag whose command is 0: cut, disarmed): a lagged rotor spinning
                # down keeps reading its speed plus noise.
                rpm = [r + n if r > 0.0 else 0.0
                       for r, n in zip(rpm, [next(it) for _ in range(4)], strict=True)]
            if not (min(rpm) >= 0.0 and max(rpm) <= 65535.0):   # clamp only if needed
                rpm = [min(max(r, 0.0), 65535.0) for r in rpm]
            self.measured_rpm_floats = tuple(rpm)
            pos, vel, w = x[0:3], x[3:6], x[10:13]
            if noisy[1]:
                pos = [c + next(it) for c in pos]
            if noisy[2]:
                vel = [c + next(it) for c in vel]
            if noisy[3]:
                qn = quaternion_multiply(x[6:10], (1.0, 0.5 * next(it), 0.5 * next(it),
                                                   0.5 * next(it)))
                q = tuple((qn / np.linalg.norm(qn)).tolist())
            else:
                q = tuple(x[6:10])
            if noisy[4]:
                w = [c + next(it) for c in w]
        else:   # noise-free (the built-in scenarios): written out on the 17 floats
            w1, w2, w3, w4 = w_rotor
            r1, r2, r3, r4 = (w1 * RADPS_TO_RPM, w2 * RADPS_TO_RPM, w3 * RADPS_TO_RPM,
                              w4 * RADPS_TO_RPM)
            if (0.0 <= r1 <= 65535.0 and 0.0 <= r2 <= 65535.0 and 0.0 <= r3 <= 65535.0
                    and 0.0 <= r4 <= 65535.0):   # in range (so not NaN): the clamp is a no-op
                self.measured_rpm_floats = (r1, r2, r3, r4)
            else:
                self.measured_rpm_floats = tuple([min(max(r, 0.0), 65535.0)
                                                  for r in (r1, r2, r3, r4)])
            px, py, pz, vx, vy, vz, qw, qx, qy, qz, wp, wq, wr = x
            pos, vel, q, w = (px, py, pz), (vx, vy, vz), (qw, qx, qy, qz), (wp, wq, wr)
        g = self._gyro_range_radps
        if g > 0 and not -g <= min(w) <= max(w) <= g:   # a real gyro saturates at its range
            w = [min(max(c, -g), g) for c in w]
        self.measured_parts = (tuple(pos), tuple(vel), tuple(q), tuple(w))
        self._measured_floats: State | None = None    # built from measured_parts on first read
        self._measured: State | None = None

    def _measure_estimated(self) -> None:
        """The realistic sensors sampled now and fused (:mod:`tfl_mav.sitl.estimator`): the
        measured state is the estimate; the ESC rpm are measured as in :meth:`_sample_sensors`."""
        self._sample_sensors()
        suite, ekf = self.sensors, self.estimator
        assert suite is not None and ekf is not None
        imu, fixes, baro, mag = suite.sample(self.time_s, self._x)
        ekf.predict(imu)
        if mag is not None:
            ekf.fuse_mag(mag)
        if baro is not None:
            ekf.fuse_baro(baro)
        for fix in fixes:
            ekf.fuse_gps(fix)
        est = self.estimate = ekf.output()
        self.measured_parts = (est.position_m, est.velocity_mps, est.quaternion_wxyz,
                       est.body_rates_radps)

    # ------------------------------------------------------------------ outputs
    @property
    def state(self) -> RigidBodyState:
        """True rigid-body state (paper frame)."""
        return RigidBodyState.from_list(self._x)

    @property
    def state_vector(self) -> list[float]:
        """True state as 13 floats (position, velocity, quaternion wxyz, body rates), paper
        frame: :attr:`state` without building arrays (a copy; for per-tick logging)."""
        return list(self._x)

    @property
    def measured(self) -> State:
        """State as the vehicle's estimator reports it (truth + sensor noise), numpy arrays
        (built on first read in a tick; :attr:`measured_floats` is the same numbers)."""
        m = self._measured
        if m is None:
            f = self.measured_floats
            m = self._measured = State(np.array(f.position_m), np.array(f.velocity_mps),
                                       np.array(f.quaternion_wxyz),
                                       np.array(f.body_rates_radps), f.time_usec)
        return m

    @property
    def measured_floats(self) -> State:
        """:attr:`measured` with float tuples for fields: what hot loops read (no arrays)."""
        m = self._measured_floats
        if m is None:
            m = self._measured_floats = State(*self.measured_parts, self.time_usec)
        return m

    def measured_rpm(self) -> np.ndarray:
        """ESC-reported rotor speeds (rpm, with the scenario's seeded noise); a new array."""
        return np.array(self.measured_rpm_floats)

    @property
    def rotor_thrusts_n(self) -> list[float]:
        """True instantaneous thrust of each rotor (N)."""
        return self.motors.thrust_n

    @property
    def rotor_rpm_true(self) -> list[float]:
        return [w * RADPS_TO_RPM for w in self.motors.omega_radps]

    @property
    def attack_sample(self) -> AttackSample:
        return self.attack

    def crash_reason(self) -> str | None:
        """None while flyable, else a sentence saying why the run is over."""
        x = self._x
        # A sum of finite floats is finite unless it overflows: one test in the common case.
        if not math.isfinite(sum(x)) and not all(math.isfinite(c) for c in x):
            return "the state became non-finite (NaN/inf): the integration diverged"
        _px, _py, pz, vx, vy, vz, _qw, qx, qy, _qz, wp, wq, wr = x
        if pz < 0.0:
            return f"hit the ground (z = {pz:.2f} m < 0) at t = {self.time_s:.3f} s"
        b3z = 1.0 - 2.0 * (qx * qx + qy * qy)
        if b3z < 0.0:
            return (f"flipped: thrust axis points down (tilt {math.degrees(math.acos(b3z)):.0f}°)"
                    f" at t = {self.time_s:.3f} s")
        # sqrt only past the limit's square: sqrt is monotonic and sqrt(limit²) = limit
        # exactly, so a sum not above the square can never have a root above the limit
        # (products, not ** 2: a finite 1e160 squares to inf here, where ** raises OverflowError)
        rate2 = wp * wp + wq * wq + wr * wr
        if rate2 > _MAX_BODY_RATE2:
            rate = math.sqrt(rate2)
            if rate > MAX_BODY_RATE_RADPS:
                return (f"spinning at {rate:.0f} rad/s (> {MAX_BODY_RATE_RADPS:.0f} rad/s, "
                        f"beyond what a real airframe and its gyros survive) at t = "
                        f"{self.time_s:.3f} s")
        speed2 = vx * vx + vy * vy + vz * vz
        if speed2 > _MAX_SPEED2:
            speed = math.sqrt(speed2)
            if speed > MAX_SPEED_MPS:
                return f"speed {speed:.0f} m/s exceeds {MAX_SPEED_MPS:.0f} m/s: runaway"
        return None

