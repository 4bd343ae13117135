"""Fuzzing both UDP endpoints over real loopback sockets.

Shared by ``tests/system/test_fuzz.py`` (a small seeded set) and ``bench/bench_fuzz.py`` (≥ 100 000
inputs per endpoint). Nothing here is mocked: a real :class:`~tfl_mav.sitl.vehicle.Vehicle` or
:class:`~tfl_mav.controller.daemon.Daemon` runs in a thread on a loopback socket, and the fuzzer is
its pinned peer on another socket.

**How a run goes.** The fuzzer sends a valid HEARTBEAT first (so it becomes the peer), then
flies the endpoint in lockstep. Every tick it sends one *batch*: a few hostile datagrams of
one category, then one *completer* (vehicle side: the awaited ``HIL_ACTUATOR_CONTROLS`` at
hover; daemon side: a valid ODOMETRY + ESC_TELEMETRY_1_TO_4 datagram), and waits for the
endpoint's answer to the completer. Datagrams from one socket arrive in order, so when that
answer arrives the endpoint has handled the whole batch and its counters are quiescent:
the counters' change over the batch is exactly what the batch caused.

**Accounting, exactly.** :class:`LinkModel` is a reference model of the framing rules that
``tfl_mav/link/transport.py`` documents (MAVLink 2 only, one datagram at a time, nothing
carried over, reasons ``garbage``/``mavlink1``/``truncated``/``bad_flags``/``bad_crc``/
``malformed``/``unknown_id``/``wrong_sysid``/``reflected``); it checks the CRC itself and
asks pymavlink only to unpack payloads. :class:`VehicleModel` and :class:`DaemonModel` add what each
endpoint does with an accepted message (stale/rejected controls, commands not for us,
denied, unsupported; bad/good states, ESC reports, ticks, ignored messages). Per batch the
predicted counters must equal the endpoint's counters; ``mismatches`` lists every batch
where they do not. A datagram the kernel drops (``rx_datagrams`` short of what was sent) is
reported as ``lost`` and its batch is not compared.

**Invariants.** No exception escapes the endpoint's loop (``crashes``); no non-finite value
reaches physics (state, rotor commands and thrusts are checked at every tick through
``on_truth``) or a motor command (every ``HIL_ACTUATOR_CONTROLS`` the daemon sends is
checked through ``on_frame``: finite, in [0, 1]); and no non-finite float leaves either
endpoint in any frame.

Inputs the protocol defines as *ending* the run (a HEARTBEAT with MAV_STATE_POWEROFF or
EMERGENCY to the daemon, an accepted MAV_CMD_INJECT_FAILURE to the vehicle) are not sent:
they are legitimate commands, not bad input. Nor are states the daemon must take as
genuine: a state whose time is a plausible successor of the newest one (it would be
flown, and answered instead of the completer), or one that confirms a new time line (a
restart, see the daemon's "Restart"). They are counted in ``skipped``. The daemon's
``extreme_state`` batches are a single absurd state at the completer's time, flown by the
law (and answered, even when the law raises).
"""

from tfl_mav.tools.harness.fuzz.generators import DAEMON_CATEGORIES, VEHICLE_CATEGORIES
from tfl_mav.tools.harness.fuzz.models import DaemonModel, LinkModel, VehicleModel
from tfl_mav.tools.harness.fuzz.run import (
    CategoryReport,
    EndpointReport,
    fuzz_daemon,
    fuzz_vehicle,
    reject_reasons,
    rejected_total,
)
from tfl_mav.tools.harness.fuzz.wire import FUZZER_SYSID, LINK_REASONS, nonfinite_floats

__all__ = [
    "DAEMON_CATEGORIES",
    "FUZZER_SYSID",
    "LINK_REASONS",
    "VEHICLE_CATEGORIES",
    "CategoryReport",
    "DaemonModel",
    "EndpointReport",
    "LinkModel",
    "VehicleModel",
    "fuzz_daemon",
    "fuzz_vehicle",
    "nonfinite_floats",
    "reject_reasons",
    "rejected_total",
]
