"""The vehicle's recorder hooks in lockstep: queued off the critical path (tfl_mav.sitl.recording),
yet seen in the order things happened, with the simulator as it was, and all of them by the
time the run returns. Real UDP on loopback, the Pilot as controller, a GCS socket."""

from __future__ import annotations

import math
import socket
import threading

from tfl_mav.scenario import load_scenario
from tfl_mav.sitl.vehicle import ExitStatus, Vehicle
from tfl_mav.tools.harness.pilot import Pilot, hover_controls
from tfl_mav.tools.harness.ports import LOOPBACK

TICKS = 300


def test_hooks_see_every_tick_in_wire_order_with_the_state_of_their_tick():
    sc = load_scenario("paper").replace(**{"attack.rotor": 0,
                                           "initial.position_m": [0.0, 0.0, 5.0]})
    calls: list[tuple] = []

    def on_frame(direction, raw, msg, time_s):
        kind = msg.get_type() if msg is not None else None
        usec = msg.time_usec if kind in ("ODOMETRY", "HIL_ACTUATOR_CONTROLS") else None
        calls.append((direction, kind, usec))

    def on_truth(sim):
        # what a recorder reads at the call: must be the tick's state, not a later one
        calls.append(("truth", sim.time_usec, tuple(sim.state_vector)))

    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(LOOPBACK)
    vehicle = Vehicle(sc, listen=LOOPBACK, gcs=gcs.getsockname(), on_frame=on_frame,
                      on_truth=on_truth, resend_interval_s=1.0, lockstep_timeout_s=10.0)
    result = {}
    thread = threading.Thread(target=lambda: result.setdefault("r", vehicle.run(TICKS / 1000)))
    thread.start()
    with Pilot(vehicle.listen_address) as pilot:
        pilot.hello()
        pilot.fly(None, hover_controls(sc), timeout_s=10.0, keep=False)
    thread.join(10.0)
    gcs.close()
    vehicle.close()
    assert result["r"].status is ExitStatus.COMPLETED
    assert vehicle.stats.lockstep_resends == 0      # so the sequence below is exact

    truths = [c for c in calls if c[0] == "truth"]
    assert [t[1] for t in truths] == [1000 * k for k in range(TICKS + 1)]   # none lost
    assert all(math.isfinite(x) for t in truths for x in t[2])
    # the state vectors differ tick to tick (a late call would repeat the newest)
    assert len({t[2] for t in truths}) == len(truths)
    # control port order around each truth: reply k-1 in, truth k, state k out
    sent = [c[2] for c in calls if c[:2] == ("tx", "ODOMETRY")]
    assert sent == [1000 * k for k in range(TICKS)]
    for i, c in enumerate(calls):
        if c[0] == "truth" and c[1] > 0:
            before = [b for b in calls[:i] if b[1] in ("HIL_ACTUATOR_CONTROLS", "ODOMETRY")
                      or b[0] == "truth"]
            assert before[-1] == ("rx", "HIL_ACTUATOR_CONTROLS", c[1] - 1000)
            after = [a for a in calls[i + 1:] if a[1] in ("HIL_ACTUATOR_CONTROLS", "ODOMETRY")
                     or a[0] == "truth"]
            if c[1] < 1000 * TICKS:
                assert after[0] == ("tx", "ODOMETRY", c[1])
    assert any(c[1] == "ATTITUDE" for c in calls)   # the GCS port's frames too
