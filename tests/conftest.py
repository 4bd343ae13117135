"""Fixtures shared by the tests: free ports, simulator subprocesses, pilots, output dirs.

Everything here is the real thing (loopback UDP, ``tfl-mav`` subprocesses); the fixtures
only make sure each test gets its own ports and files and that nothing it started
outlives it. The library behind them is :mod:`harness` (also used by bench/).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest

from tfl_mav.link.transport import Address
from tfl_mav.tools.harness.pilot import Pilot
from tfl_mav.tools.harness.ports import free_udp_port
from tfl_mav.tools.harness.processes import Proc, start_sim

# The suite flies the compiled cores, as a user's Linux machine does: each pure step (the
# law's, the safe law's, the detector's, the simulator's) is built once per session and per
# path kind, into the session's own cache, before the flight that needs it. Their Python
# forms are held to them bit for bit by tests/contract (test_native, test_accel, test_step);
# `TFL_MAV_NATIVE=off python -m pytest` flies everything in Python. Set at import, so that
# every `tfl-mav` subprocess inherits it.
os.environ.setdefault("TFL_MAV_NATIVE", "sync")

SimFactory = Callable[..., tuple[Proc, int]]
PilotFactory = Callable[..., Pilot]


@pytest.fixture(scope="session", autouse=True)
def _kernel_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """The compiled cores built by this session go to its own directory (every subprocess
    too), never into the user's cache."""
    if "TFL_MAV_KERNEL_CACHE" not in os.environ:
        os.environ["TFL_MAV_KERNEL_CACHE"] = str(tmp_path_factory.mktemp("kernels"))


@pytest.fixture
def free_port() -> int:
    """A loopback UDP port that was free a moment ago (for a fixed ``--bind``)."""
    return free_udp_port()


@pytest.fixture
def out_dir(tmp_path: Path) -> Path:
    """An empty directory for the test's output files (logs, reports)."""
    out = tmp_path / "out"
    out.mkdir()
    return out


@pytest.fixture
def sim_factory() -> Iterator[SimFactory]:
    """``start(args, scenario="paper") -> (proc, port)``: ``tfl-mav sim`` subprocesses on
    free ports, each stopped (SIGTERM, then SIGKILL) when the test ends."""
    started: list[Proc] = []

    def start(args: Sequence[str] = (), scenario: str = "paper", **kw: Any
              ) -> tuple[Proc, int]:
        proc, port = start_sim(list(args), scenario, **kw)
        started.append(proc)
        return proc, port

    yield start
    for proc in started:
        proc.stop()


@pytest.fixture
def sim(sim_factory: SimFactory) -> int:
    """The port of a lockstep ``tfl-mav sim paper`` without an attack, waiting for its
    controller, that runs until the test ends."""
    _proc, port = sim_factory(["--set", "attack.rotor=0", "--duration", "0"])
    return port


@pytest.fixture
def pilot_factory() -> Iterator[PilotFactory]:
    """``make(address, **kw) -> Pilot`` (HEARTBEAT already sent); closed at the end."""
    made: list[Pilot] = []

    def make(address: Address, **kw: Any) -> Pilot:
        pilot = Pilot(address, **kw)
        made.append(pilot)
        pilot.hello()
        return pilot

    yield make
    for pilot in made:
        pilot.close()


@pytest.fixture
def pilot(sim: int, pilot_factory: PilotFactory) -> Pilot:
    """A pilot connected to the :func:`sim` vehicle (its flight has started)."""
    return pilot_factory(("127.0.0.1", sim))
