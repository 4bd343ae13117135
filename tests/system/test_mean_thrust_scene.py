"""The mean thrust axis in the Foxglove scene of a spinning flight, read back from a real
MCAP file with the mcap reader and Foxglove's official protobuf classes.

A rotor pinned at 8 N from t = 0 on the circle: the spin law flies a relaxed hover, the
body turning at ~55 rad/s with its thrust axis on a ~56° cone about the vertical. The
body's own thrust arrow sweeps that cone ten times a second; the scene's ``mean_thrust``
entity is the axis the law steers, which a person can follow.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader

from tfl_mav.flightlog.recorder import MEAN_THRUST_TAU_S, Recorder
from tfl_mav.offline import fly_offline
from tfl_mav.scenario import apply_overrides, load_scenario

pytestmark = pytest.mark.slow


def _quat_to_x(q) -> tuple[float, float, float]:
    """Where the arrow primitive's +x points (world) for its pose's orientation."""
    x, y, z, w = q.x, q.y, q.z, q.w
    return (1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y))


def test_a_spinning_flight_draws_its_mean_thrust_axis(tmp_path):
    sc = apply_overrides(load_scenario("circle"), [
        "attack.signal=constant", "attack.value_n=8.0", "attack.start_s=0",
        "run.duration_s=3.0"])
    path = tmp_path / "spin.mcap"
    v = sc.vehicle
    arm = v.arm_m
    rotors = ((arm, 0.0), (0.0, -arm), (-arm, 0.0), (0.0, arm))
    b3_tilt: list[float] = []
    with Recorder(path, rotor_xy_m=rotors, thrust_max_n=v.thrust_max_n,
                  timeline="sim") as rec:
        def hook(sim) -> None:
            s = sim.state
            _, x, y, _ = s.quaternion_wxyz
            b3_tilt.append(math.degrees(math.acos(max(-1.0, min(1.0, 1 - 2 * (x * x + y * y))))))
            rec.truth(sim.time_s, s.position_m, s.velocity_mps, s.quaternion_wxyz,
                      s.body_rates_radps, sim.rotor_thrusts_n, sim.attack.rotor,
                      sim.attack.applied_n, sim.attack.applied_n)
        log = fly_offline(sc, attack_info="detector", hook=hook)
    assert not log.crashed, log.crash_reason
    mean = []
    with open(path, "rb") as f:
        for _, _ch, m in make_reader(f).iter_messages(topics=["/scene/vehicle"]):
            ents = {e.id: e for e in SceneUpdate.FromString(m.data).entities}
            assert "vehicle" in ents
            if "mean_thrust" in ents:
                e = ents["mean_thrust"]
                assert e.frame_id == "world"
                arrow = e.arrows[0]
                u = _quat_to_x(arrow.pose.orientation)
                length = arrow.shaft_length + arrow.head_length
                mean.append((m.log_time, math.degrees(math.acos(max(-1.0, min(1.0, u[2])))),
                             length, e.texts[0].text))
    assert len(mean) >= 29          # every 5th scene of 50 Hz: 10 Hz over 3 s
    t0 = mean[0][0]
    late = [(tilt, length) for ns, tilt, length, _ in mean if (ns - t0) * 1e-9 >= 2.0]
    spin = np.array(b3_tilt[2000:])
    # the body sweeps its cone: its thrust axis is tilted ~56° from the vertical ...
    assert spin.min() > 40.0
    # ... the mean axis is the vertical, to the filter's residue of the cone's turning part
    # (1/√(1 + (Ω τ)²) of tan 56°: ≤ 5° at Ω ≥ 45 rad/s) plus the outer loop's tilt
    omega = 45.0
    residue = math.degrees(math.atan(math.tan(math.radians(60.0))
                                     / math.sqrt(1 + (omega * MEAN_THRUST_TAU_S) ** 2)))
    assert max(t for t, _ in late) < residue + 3.0
    # its length is the mean thrust: the weight, m g/(2 f_max) m, within the vertical
    # acceleration the outer loop asks (±0.3 g at most, far less once on the path)
    mg = v.mass_kg * v.gravity_mps2
    for _, length in late:
        assert length == pytest.approx(mg / (2 * v.thrust_max_n), rel=0.15)
    assert "deg from vertical" in mean[-1][3]
