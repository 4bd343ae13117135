"""Lockstep through the fault relay: the wall time of N ticks at a given datagram loss.

Shared by ``bench/bench_lockstep_loss.py`` (the table) and ``tests/system/test_lockstep_loss.py``
(the bound): a ``tfl-mav sim`` subprocess (hover, no attack) flown by the test pilot
through :class:`tfl_mav.tools.harness.relay.Relay` dropping ``drop`` of the datagrams in each
direction.
"""

from __future__ import annotations

import time
from typing import Any

from tfl_mav.scenario import load_scenario
from tfl_mav.tools.harness.pilot import Pilot, hover_controls
from tfl_mav.tools.harness.processes import start_sim
from tfl_mav.tools.harness.relay import Faults, Relay

__all__ = ["fly_through_relay"]


def fly_through_relay(ticks: int, drop: float, resend_s: float = 0.005, seed: int = 1
                      ) -> dict[str, Any]:
    """Wall time of ``ticks`` lockstep ticks through a relay dropping ``drop`` each way."""
    sc = load_scenario("paper").replace(**{"attack.rotor": 0})
    sim, port = start_sim(["--set", "attack.rotor=0", "--duration", "0", "--gcs", "none",
                           "--resend-interval", str(resend_s)])
    faults = Faults(drop=drop)
    try:
        with Relay(("127.0.0.1", port), to_vehicle=faults, to_daemon=faults,
                   seed=seed) as relay, Pilot(relay.listen_address) as pilot:
            pilot.hello()
            command = hover_controls(sc)
            pilot.fly(10, command, keep=False)          # connected, warm
            t0 = time.perf_counter()
            pilot.fly(ticks, command, keep=False, timeout_s=10.0)
            wall = time.perf_counter() - t0
            stats = relay.stats
            lost = stats.to_vehicle.dropped + stats.to_daemon.dropped
    finally:
        sim.stop()
    return {"drop": drop, "ticks": ticks, "wall_s": wall, "lost_datagrams": lost,
            "ms_per_loss": None}
