"""The vehicle's MCAP log: the project recorder fed with the simulator's ground truth.

:class:`SimRecorder` adapts :class:`tfl_mav.mavlink.recorder.Recorder` to the vehicle's
hooks (``on_frame`` for every MAVLink frame, ``on_truth(sim)`` once per control tick) and
adds what only the vehicle knows: the scenario (metadata) and the path drawn in the 3-D
scene. The recorder itself knows nothing of the simulator.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from sitl.simulator import Simulator
from tfl_mav.mavlink.recorder import Recorder, RecorderError
from tfl_mav.scenario import Scenario

__all__ = ["SimRecorder"]


class SimRecorder:
    """``run.mcap`` of a simulated flight. Raises OSError if ``path`` cannot be written."""

    def __init__(self, path: str | Path, *, scenario: Scenario) -> None:
        v = scenario.vehicle
        try:
            self.recorder = Recorder(path, arm_m=v.arm_m, thrust_max_n=v.thrust_max_n)
        except RecorderError as exc:
            raise OSError(str(exc)) from None
        self.recorder.metadata("scenario", {"name": scenario.name, "role": "vehicle",
                                            "scenario_json": json.dumps(scenario.to_dict())})
        try:
            from tfl_mav.controller_factory import scenario_path

            self.recorder.path(scenario_path(scenario).sample(800))
        except Exception as exc:  # a bad path is the controller's error to report
            self.recorder.log("warning", f"path not drawn: {exc}")

    def on_frame(self, direction: str, raw: bytes, msg: Any, time_s: float) -> None:
        self.recorder.on_frame(direction, raw, msg, time_s)

    def on_truth(self, sim: Simulator) -> None:
        st = sim.state
        a = sim.attack
        self.recorder.truth(sim.time_s, st.position_m, st.velocity_mps, st.quaternion_wxyz,
                            st.body_rates_radps, sim.rotor_thrusts_n, a.rotor,
                            a.applied_n if a.rotor else 0.0,
                            a.raw_n if a.rotor else 0.0)

    def log(self, level: Any, text: str, time_s: float | None = None) -> None:
        self.recorder.log(level, text, time_s)

    def close(self) -> None:
        self.recorder.close()
