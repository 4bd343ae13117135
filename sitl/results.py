"""What a :class:`~sitl.vehicle.Vehicle` run ends with and counts along the way.

Kept apart from the endpoint so a caller (``tfl-mav sim``, tests, bench scripts) can read a
run's outcome and counters without the machinery that produced them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

from tfl_mav.link.transport import LinkStats

__all__ = ["ExitStatus", "VehicleResult", "VehicleStats"]


class ExitStatus(Enum):
    """How a run ended; the value is the sentence a user reads."""

    COMPLETED = "ran for the requested duration"
    CRASHED = "the vehicle crashed"
    STOPPED = "stopped on request"


@dataclass(frozen=True)
class VehicleResult:
    """Outcome of :meth:`~sitl.vehicle.Vehicle.run`. ``wall_time_s`` counts from the flight's
    start (the controller's first HEARTBEAT), not the wait before it."""

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

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: v for k, v in self.__dict__.items()
                               if k not in ("control_link", "gcs_link")}
        out["control_link"] = self.control_link.as_dict()
        out["gcs_link"] = self.gcs_link.as_dict() if self.gcs_link is not None else None
        return out

    def summary(self) -> str:
        """Vehicle counters that are not zero, then each link's one-line summary."""
        own = [f"{k} {v}" for k, v in self.__dict__.items()
               if v and k not in ("control_link", "gcs_link")]
        text = "vehicle: " + (", ".join(own) or "nothing counted")
        text += f"; control link: {self.control_link.summary()}"
        if self.gcs_link is not None:
            text += f"; gcs link: {self.gcs_link.summary()}"
        return text
