"""The flight modes of the controller: one vocabulary for the law, daemon, logs and wire.

The integer value is what goes on the wire (``NAMED_VALUE_FLOAT`` ``mode``) and into logs;
the lower-case name is what people read (``str(Mode.ATTACKED) == "attacked"``).
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["Mode"]


class Mode(IntEnum):
    NOMINAL = 0     # four healthy rotors: the nominal TFL law, yaw held
    ATTACKED = 1    # one rotor seized: the attacked TFL law on three rotors, yaw internal
    FALLBACK = 2    # the law has no valid answer this tick (left the tube, D(x) singular)
    FAILSAFE = 3    # the daemon has no vehicle state: nothing is sent to the motors
    RECOVERY = 4    # the reduced-attitude safe law on four rotors: a take-over from an
                    # unknown state, or the TFL law lost the path (level, hold altitude)
    LOST_ROTOR = 5  # the reduced-attitude law on three rotors (relaxed hover, spinning):
                    # the attack is where the TFL attacked law has no authority (A ≈ 0)
    SPIN = 6        # the spin law: relaxed hover about a tilted axis with the attacked
                    # rotor pinned above m g/2 (no attitude hold exists there)

    def __str__(self) -> str:
        return self.name.lower()

    @classmethod
    def parse(cls, value: object) -> Mode:
        """A mode from its name (any case) or its integer; ValueError naming the value."""
        if isinstance(value, str):
            try:
                return cls[value.upper()]
            except KeyError:
                raise ValueError(f"mode: unknown name {value!r} (known: "
                                 f"{', '.join(str(m) for m in cls)})") from None
        return cls(int(value))  # type: ignore[call-overload]
