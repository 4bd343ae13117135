"""What a :class:`~tfl_mav.sitl.vehicle.Vehicle` run ends with and counts along the way.

Kept apart from the endpoint so a caller (``tfl-mav sim``, tests, bench scripts) can read a
run's outcome and counters without the machinery that produced them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

from tfl_mav.link.transport import LinkStats

__all__ = ["AgeHistogram", "ExitStatus", "VehicleResult", "VehicleStats"]


_NESTED = ("control_link", "gcs_link", "command_age", "held_age")


class AgeHistogram:
    """Ages (µs): bin 0 is exactly 0 (on time), then 0.1 ms bins up to 2 s (beyond: the last
    bin), for p50/p99 without keeping every sample: a run of hours costs a fixed 160 kB."""

    BIN_USEC = 100
    N_BINS = 20_001

    def __init__(self) -> None:
        self.counts = [0] * self.N_BINS
        self.n = 0
        self.max_usec = 0

    def add(self, age_usec: int) -> None:
        if age_usec <= 0:           # on time (lockstep: always): bin 0, the maximum holds
            self.counts[0] += 1
            self.n += 1
            return
        age = age_usec
        self.counts[min(-(-age // self.BIN_USEC), self.N_BINS - 1)] += 1
        self.n += 1
        if age > self.max_usec:
            self.max_usec = age

    def percentile_ms(self, q: float) -> float:
        """The ``q``-quantile (0-1) in ms, the upper edge of its bin (NaN when empty)."""
        if self.n == 0:
            return math.nan
        rank = max(1, math.ceil(q * self.n))
        seen = 0
        for i, c in enumerate(self.counts):
            seen += c
            if seen >= rank:
                return min(i * self.BIN_USEC, self.max_usec) / 1000.0
        return self.max_usec / 1000.0

    def as_dict(self) -> dict[str, Any]:
        if self.n == 0:
            return {"n": 0, "p50": None, "p99": None, "max": None}
        return {"n": self.n, "p50": self.percentile_ms(0.5), "p99": self.percentile_ms(0.99),
                "max": self.max_usec / 1000.0}

    def summary(self) -> str:
        return (f"p50 {self.percentile_ms(0.5):.1f} ms, p99 {self.percentile_ms(0.99):.1f} ms, "
                f"max {self.max_usec / 1000.0:.1f} ms")


class ExitStatus(Enum):
    """How a run ended; the value is the sentence a user reads."""

    COMPLETED = "ran for the requested duration"
    CRASHED = "the vehicle crashed"
    STOPPED = "stopped on request"
    PEER_LOST = "the controller went silent"


@dataclass(frozen=True)
class VehicleResult:
    """Outcome of :meth:`~tfl_mav.sitl.vehicle.Vehicle.run`. ``wall_time_s`` counts from the
    flight's start (the controller's first HEARTBEAT), not the wait before it."""

    status: ExitStatus
    reason: str
    ticks: int
    sim_time_s: float
    wall_time_s: float

    @property
    def real_time_factor(self) -> float:
        """Sim seconds per wall second (lockstep: how much faster than real time)."""
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else math.nan


@dataclass
class VehicleStats:
    """Counters of one vehicle; the links' own counters are attached live.

    One flat record on purpose: its field order is the order of ``tfl-mav sim --json`` and
    of the summary line, and every part of the vehicle (clock, commands, GCS) counts here.
    """

    ticks: int = 0                  # control periods integrated
    states_sent: int = 0            # ODOMETRY + ESC_TELEMETRY pairs, resends included
    controls_applied: int = 0
    rejected_controls: int = 0      # NaN/inf or out of [0, 1]: never applied
    stale_controls: int = 0         # not the awaited time_usec (lockstep) / older (real time)
    duplicate_controls: int = 0     # lockstep: a second answer to a tick (its state resent)
    lockstep_resends: int = 0       # no reply within resend_interval_s: state resent
    lockstep_timeouts: int = 0      # no reply within lockstep_timeout_s: reported
    command_timeouts: int = 0       # real time: no valid command for command_timeout_s → cut
    overruns: int = 0               # real time: fell > 0.1 s behind the wall clock
    late_controls: int = 0          # real time: applied after their own tick's step began
    start_wait_states: int = 0      # real time: t=0 states sent while waiting for a command
    commands_accepted: int = 0
    commands_denied: int = 0        # MAV_CMD_INJECT_FAILURE with bad parameters / disabled
    commands_unsupported: int = 0
    commands_not_for_us: int = 0    # addressed to another system/component: not answered
    controllers_refused: int = 0    # HEARTBEATs refused as controller (not an offboard one)
    controllers_released: int = 0   # identified as controller but sent no actuator commands
    failures_injected: int = 0      # accepted INJECT_FAILURE other than type 0 (OK = clear)
    statustexts_sent: int = 0
    statustexts_suppressed: int = 0  # repeats inside the per-reason rate limit
    control_link: LinkStats = field(default_factory=LinkStats)
    gcs_link: LinkStats | None = None
    command_age: AgeHistogram = field(default_factory=lambda: AgeHistogram())
    """Sim time when a command was applied − its ``time_usec`` (0 = on time)."""
    held_age: AgeHistogram = field(default_factory=lambda: AgeHistogram())
    """Age of the held command at each control period integrated (real time)."""

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: v for k, v in self.__dict__.items() if k not in _NESTED}
        out["command_age_ms"] = self.command_age.as_dict()
        out["held_age_ms"] = self.held_age.as_dict()
        out["control_link"] = self.control_link.as_dict()
        out["gcs_link"] = self.gcs_link.as_dict() if self.gcs_link is not None else None
        return out

    def summary(self) -> str:
        """Vehicle counters that are not zero, then each link's one-line summary."""
        own = [f"{k} {v}" for k, v in self.__dict__.items() if v and k not in _NESTED]
        text = "vehicle: " + (", ".join(own) or "nothing counted")
        for name, hist in (("command age", self.command_age), ("held age", self.held_age)):
            if hist.n and hist.max_usec > 0:
                text += f"; {name} {hist.summary()}"
        text += f"; control link: {self.control_link.summary()}"
        if self.gcs_link is not None:
            text += f"; gcs link: {self.gcs_link.summary()}"
        return text
