"""Read a recorded flight (MCAP) into arrays.

    tfl-mav demo --out flight --duration 5 --no-plots      # records flight/run.mcap, ctl.mcap
    python docs/examples/read_mcap.py flight/run.mcap

The vehicle's log holds the truth; the controller's (ctl.mcap beside it) its mode and
detection. The scenario comes from the log's metadata.
"""

import sys

import numpy as np

from tfl_mav.flightlog.from_mcap import load_flight

log, scenario = load_flight(sys.argv[1] if len(sys.argv) > 1 else "tfl-mav-demo/run.mcap")
t, position, thrust = log["t_s"], log["position_m"], log["thrust_cmd_n"]
print(f"scenario {scenario.name!r}: {len(t)} samples, t = {t[0]:.3f} .. {t[-1]:.3f} s")
print(f"position_m {position.shape}, last {np.round(position[-1], 3).tolist()} (paper frame, z up)")
print(f"thrust_cmd_n {thrust.shape}, range [{thrust.min():.2f}, {thrust.max():.2f}] N")
print(f"path_distance_m: final {log['path_distance_m'][-1]:.4f} m")
if log.detected_rotor is not None and log.detected_rotor.any():
    first = int(np.argmax(log.detected_rotor > 0))
    print(f"detected rotor {log.detected_rotor[first]} at t = {t[first]:.3f} s")
