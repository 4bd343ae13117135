"""Your own attack against the TFL law: rotor 3 cut to 0 N in bursts, never announced.

    python docs/examples/own_attack.py [SECONDS]

An Attack has thrust_n(t_s, state) -> N (the true state, paper frame z up), and optionally
the rotor (1-4) and start_s it seizes; the flight software must find it from ESC rpm.
"""

import math
import sys

from tfl_mav.api import Environment


class Bursts:
    """0 N for 0.5 s of every 2 s, else a thrust that grows with height (z in m)."""

    rotor = 3
    start_s = 1.0

    def thrust_n(self, t_s, state):
        if (t_s - self.start_s) % 2.0 < 0.5:
            return 0.0
        return 2.0 + 0.3 * math.sin(state.position_m[2])


if __name__ == "__main__":
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 20.0
    flight = Environment("paper", attack=Bursts()).fly(seconds)     # the TFL flight computer
    found = flight.detected_rotor[-1]
    print(f"attack on rotor {flight.attack_rotor} from t = {flight.attack_start_s:.1f} s; "
          f"detected: rotor {found} at t = {flight.detection_time_s:.3f} s")
    late = flight.t_s >= flight.t_s[-1] / 2
    print(f"crashed: {flight.crashed}; path distance over the second half: max "
          f"{flight.path_distance_m[late].max():.3f} m, final {flight.path_distance_m[-1]:.3f} m")
