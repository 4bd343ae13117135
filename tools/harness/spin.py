"""Flights of the spin law in the simulator: the existing flight computer flies until the
take-over, then :func:`~tfl_mav.control.spin.step.spin_step` flies (tests and bench).

No network: the in-process :class:`~tfl_mav.sitl.simulator.Simulator` of the offline runner,
so the physics is exactly that of a lockstep flight. The path reference the law takes is
the closest point of the scenario's path (:class:`~tfl_mav.control.safe.recovery.PathProjector`),
moving along it at the path speed (velocity speed·T, acceleration speed²·κN). The attacked
rotor's thrust is read from its ESC rpm (f = k_f ω²), as the flight computer reads it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from tfl_mav.control.safe.recovery import PathProjector
from tfl_mav.control.spin.law import initial_state
from tfl_mav.control.spin.step import SpinInputs, SpinParams, spin_step
from tfl_mav.controller.flight_computer import FlightComputer
from tfl_mav.from_scenario import scenario_path, spin_params_for
from tfl_mav.scenario import Scenario
from tfl_mav.sitl.motors import RADPS_TO_RPM
from tfl_mav.sitl.simulator import Simulator

__all__ = ["SpinFlight", "fly_spin", "spin_params_for"]


class SpinFlight(NamedTuple):
    """One flight, sampled every control tick (paper frame)."""

    t_s: np.ndarray
    position_m: np.ndarray          # (n, 3)
    rates_radps: np.ndarray         # (n, 3) body
    distance_m: np.ndarray          # to the path (closest point)
    thrusts_n: np.ndarray           # (n, 4) commanded, physical rotors
    rho: np.ndarray                 # spin-up fraction (NaN before the take-over)
    exists: bool | None             # the law's verdict at the last tick (None: it never flew)
    spin_radps: float               # Ω of the equilibrium at the last tick
    cone_rad: float
    drift_m: float
    crashed: bool
    crash_reason: str
    takeover_s: float

    def max_distance_after(self, t0_s: float) -> float:
        """Largest distance (m) to the path from ``t0_s`` on (inf after a crash)."""
        if self.crashed:
            return math.inf
        sel = self.t_s >= t0_s
        return float(self.distance_m[sel].max()) if sel.any() else math.nan


def fly_spin(sc: Scenario, *, takeover_s: float = 5.0, duration_s: float | None = None,
             params: SpinParams | None = None) -> SpinFlight:
    """Fly ``sc`` with the flight computer (told the attacked rotor by an oracle) until
    ``takeover_s``, then with the spin law from whatever state the vehicle is in."""
    params = params or spin_params_for(sc, lag_inverted=False)   # flown without the inverse
    rotor = sc.attack.rotor
    sim = Simulator(sc)
    fc = FlightComputer(sc, attack_info="oracle", design_gains=False)
    path = scenario_path(sc)
    projector = PathProjector(path)
    speed = sc.path.speed_mps
    kf = sc.vehicle.k_f
    duration = sc.run.duration_s if duration_s is None else duration_s
    n = round(duration / sim.control_dt_s)
    ts, pos, rates, dist, thr, rhos = [], [], [], [], [], []
    applied = sim.rotor_commands_n
    state = None
    out = None
    crashed, reason = False, ""
    for _ in range(n):
        t = sim.time_s
        meas = sim.measured_floats
        y = meas.position_m
        proj = projector.project(y)
        if proj is None:
            projector.start(y)
            proj = projector.project(y)
        point, tangent, curvature, d = proj if proj is not None else (y, (0, 0, 0),
                                                                       (0, 0, 0), math.nan)
        if t < takeover_s:
            fc.tell_attack(sim.attack.rotor)
            res = fc.step(t, meas, sim.measured_rpm_floats, applied)
            thrust = list(res[0])
            rho = math.nan
        else:
            if state is None:
                state = initial_state(params, meas.body_rates_radps)
            rpm = sim.measured_rpm_floats[rotor - 1]
            w = rpm / RADPS_TO_RPM
            inputs = SpinInputs(
                tuple(y), tuple(meas.velocity_mps), tuple(meas.quaternion_wxyz),
                tuple(meas.body_rates_radps), kf * w * w, tuple(point),
                tuple(speed * c for c in tangent),
                tuple(speed * speed * c for c in curvature))
            state, out = spin_step(params, state, inputs)
            thrust = list(out.thrusts_n)
            rho = out.rho
        ts.append(t)
        pos.append(tuple(y))
        rates.append(tuple(meas.body_rates_radps))
        dist.append(d)
        thr.append(tuple(thrust))
        rhos.append(rho)
        sim.set_command(thrust)
        applied = sim.rotor_commands_n
        sim.step_control_period()
        why = sim.crash_reason()
        if why:
            crashed, reason = True, why
            break
    return SpinFlight(np.array(ts), np.array(pos), np.array(rates), np.array(dist),
                      np.array(thr), np.array(rhos),
                      out.exists if out else None, out.spin_radps if out else math.nan,
                      out.cone_rad if out else math.nan, out.drift_m if out else math.nan,
                      crashed, reason, takeover_s)
