"""mavsdk (the native MAVSDK binding, its C++ core inside the wheel) as the ground station.

What a mavsdk user sees on the GCS port of ``tfl-mav sim``: the mode as OFFBOARD, the armed
state, a global position and home at the origin, the scenario's parameters, an empty
mission, a disarm in the air denied as PX4 does, kill (the forced disarm) and arm
honoured. Real time, so the disarmed vehicle falls at 1 g of wall
time (from 200 m it has ~6 s) while mavsdk, whose timeouts are in wall time, looks on.
"""

from __future__ import annotations

import subprocess
import threading
import time

import pytest

from tfl_mav.scenario import load_scenario
from tfl_mav.sitl.gcs import Origin
from tfl_mav.tools.harness.pilot import NoStateError, Pilot, hover_fraction
from tfl_mav.tools.harness.ports import free_udp_port
from tfl_mav.tools.harness.processes import CLI, LISTEN_RE

mavsdk = pytest.importorskip("mavsdk")
from mavsdk.plugins.action import Action, ActionError  # noqa: E402
from mavsdk.plugins.mission_raw import MissionRaw  # noqa: E402
from mavsdk.plugins.param import Param  # noqa: E402
from mavsdk.plugins.telemetry import FlightMode, Telemetry  # noqa: E402

ALTITUDE_M = 200.0


@pytest.mark.slow
def test_mavsdk_sees_an_offboard_vehicle_it_can_disarm():
    gport = free_udp_port()
    sim = subprocess.Popen(
        [*CLI, "sim", "paper", "--set", "attack.rotor=0", "--set",
         f"initial.position_m=[0,0,{ALTITUDE_M}]", "--listen", "127.0.0.1:0",
         "--legacy-ports", "--gcs", f"127.0.0.1:{gport}", "--duration", "0", "--realtime",
         "--command-timeout", "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stop = threading.Event()
    try:
        m = LISTEN_RE.search(sim.stdout.readline())
        assert m, "sim did not start"
        u = hover_fraction(load_scenario("paper"))

        def hover() -> None:
            with Pilot((m.group(1), int(m.group(2)))) as pilot:
                pilot.hello()
                while not stop.is_set():
                    try:
                        odom, _esc = pilot.state(0.5)
                    except NoStateError:
                        continue
                    pilot.reply(odom, [u] * 4)

        threading.Thread(target=hover, daemon=True).start()
        sdk = mavsdk.Mavsdk(mavsdk.Configuration.create_with_component_type(
            mavsdk.ComponentType.GROUND_STATION))
        sdk.add_any_connection(f"udpin://127.0.0.1:{gport}")
        system = sdk.first_autopilot(10.0)
        assert system is not None
        tel, action = Telemetry(system), Action(system)
        time.sleep(1.5)   # first telemetry, home
        assert tel.flight_mode() == FlightMode.OFFBOARD
        assert tel.armed()
        origin = Origin()
        pos, home = tel.position(), tel.home()
        assert pos.latitude_deg == pytest.approx(origin.lat_deg, abs=1e-6)
        assert pos.relative_altitude_m == pytest.approx(ALTITUDE_M, abs=1.0)
        assert (home.latitude_deg, home.absolute_altitude_m) == pytest.approx(
            (origin.lat_deg, origin.alt_m), abs=1e-3)
        assert Param(system).get_param_float("V_MASS_KG") == pytest.approx(1.1, rel=1e-6)
        assert len(MissionRaw(system).download_mission()) == 0
        with pytest.raises(ActionError) as denied:   # in the air: PX4 denies a disarm
            action.disarm()
        assert "COMMAND_DENIED" in str(denied.value)
        assert tel.armed()
        action.kill()          # MAVSDK's kill: ARM_DISARM 0 with the force code 21196
        time.sleep(1.2)
        assert not tel.armed()
        action.arm()
        time.sleep(1.2)
        assert tel.armed()
    finally:
        stop.set()
        sim.terminate()
        sim.communicate(timeout=10)
