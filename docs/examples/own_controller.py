"""Your own controller, flown offline: a small-angle PD that follows the path.

    python docs/examples/own_controller.py [SECONDS]

A Controller has reset(scenario) and update(t_s, state, rpm) -> four thrusts (N); the
Environment runs the attack detector, guards the result and returns the flight as arrays.
"""

import math
import sys

from tfl_mav.api import Environment
from tfl_mav.baselines.reference import PathReference, controller_model
from tfl_mav.control.allocation import allocate_nominal
from tfl_mav.model.geometry import rotation_rows


class PathPD:
    def reset(self, scenario):
        self.model = controller_model(scenario)          # mass off by 2 %, inertia by 10 %
        self.ref = PathReference.for_scenario(scenario)  # closest point, tangent x speed

    def update(self, t_s, state, rpm):
        m, (p, v, w) = self.model, (state.position_m, state.velocity_mps, state.body_rates_radps)
        r, g = self.ref.at(p), m.gravity_mps2
        a = [min(max(4.0 * (r.position_m[i] - p[i]) + 4.0 * (r.velocity_mps[i] - v[i])
                     + r.acceleration_mps2[i], -3.0), 3.0) for i in range(3)]
        R = rotation_rows(state.quaternion_wxyz)          # body FLU -> inertial, z up
        roll, pitch, yaw = math.atan2(R[2][1], R[2][2]), -math.asin(R[2][0]), \
            math.atan2(R[1][0], R[0][0])
        roll_d, pitch_d = -a[1] / g, a[0] / g              # small angles, yaw held at 0
        J = m.inertia_kgm2
        tau = (J[0] * (225.0 * (roll_d - roll) - 30.0 * w[0]),
               J[1] * (225.0 * (pitch_d - pitch) - 30.0 * w[1]),
               J[2] * (16.0 * (0.0 - yaw) - 8.0 * w[2]))
        uf = m.mass_kg * (g + a[2]) / (math.cos(roll) * math.cos(pitch))
        return allocate_nominal(uf, *tau, m.arm_m, m.drag_thrust_ratio_m, m.thrust_max_n)


if __name__ == "__main__":
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 20.0
    flight = Environment("paper", PathPD(), settings=["attack.rotor=0"]).fly(seconds)
    print(f"crashed: {flight.crashed}, failed: {flight.failure_reason}")
    print(f"path distance: start {flight.path_distance_m[0]:.2f} m, "
          f"end {flight.path_distance_m[-1]:.3f} m after {flight.t_s[-1]:.1f} s")
