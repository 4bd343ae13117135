"""The attacker: seizes one rotor from a start time and forces its thrust to A(t, x, y, z).

The paper's false-data-injection model (§III-A, Definition 3): the rotor's thrust is
fully the attacker's. Built-in signals and any safe expression in ``t`` (sim time, s), ``tau``
(time since the attack started, s) and ``x, y, z`` (position, m, paper frame z up) are
supported. The applied value is clamped to [0, f_max]; the raw value and the clamping are
reported so a log shows when the attacker asked for more than the rotor can give.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

from tfl_mav.expr import Expr, compile_expr
from tfl_mav.scenario import AttackConfig, AttackPhase

__all__ = ["FAILURE_TYPES", "NO_ATTACK", "AttackSample", "Attacker"]

# MAV_CMD_INJECT_FAILURE param2 (FAILURE_TYPE) → the signal it starts. 0 (OK) ends the attack.
FAILURE_TYPES: dict[int, str] = {0: "ok", 1: "off", 2: "stuck", 4: "wrong", 8: "drift"}


class AttackSample(NamedTuple):
    """One evaluation of the attack on the seized rotor (a NamedTuple: the simulator makes
    one every physics step while an attack runs, and a frozen dataclass costs 3× as much)."""

    rotor: int          # 1-4; 0 = no attack active
    raw_n: float        # what the signal asked for (N), NaN if it was not finite
    applied_n: float    # clamped to [0, f_max] (N)
    clamped: bool


NO_ATTACK = AttackSample(0, 0.0, 0.0, False)
_new = tuple.__new__

# A signal given as a function (:meth:`Attacker.use_signal`): a name no scenario can hold, so
# every built-in test in ``_raw`` fails and the function is reached last, at no cost to the
# built-in signals.
CUSTOM_SIGNAL = "<function>"
AttackSignal = Callable[[float, Sequence[float]], float]
"""``signal(t_s, x)`` -> thrust (N): ``x`` is the true state, 13 floats in the paper frame
(position m, velocity m/s, quaternion wxyz, body rates rad/s)."""


class Attacker:
    """Evaluates the scenario's attack; :meth:`inject` starts one now (GCS command)."""

    def __init__(self, cfg: AttackConfig, thrust_max_n: float) -> None:
        self.cfg = cfg
        self.thrust_max_n = thrust_max_n
        self.rotor = cfg.rotor
        self.start_s = cfg.start_s
        self.signal = cfg.signal
        self._stuck_n: float | None = None
        self._expr: Expr | None = None
        self._custom: AttackSignal | None = None
        # Sim time (s) the signal first gave no finite value (an expression outside its
        # domain: sqrt(5 - t) after 5 s, log(t - 1) before 1 s), or None; from then on a
        # non-finite value holds the rotor at 0 N (recorded: raw NaN, clamped).
        self.nonfinite_from_s: float | None = None
        self.on_nonfinite: Callable[[float, str], None] | None = None
        self._said = False     # on_nonfinite was called
        """``on_nonfinite(t_s, text)``: called once, at the first non-finite value, with a
        sentence saying what happened and when (the vehicle sends it as STATUSTEXT)."""
        # The schedule ([[attack.phases]]): the phases still to come, and when the next one
        # starts (∞: none, so the running attack's only extra cost is one comparison).
        self._phases = list(cfg.phases)
        self._next_start_s = math.inf
        self.moves: list[tuple[float, int]] = []     # (start s, rotor 0-4) of every phase
        if self._phases:
            self._enter_phase(self._phases.pop(0))
        else:
            self._set_signal(self.signal)

    def _set_signal(self, signal: str) -> None:
        self.signal = signal
        self._expr = None
        if signal not in ("paper", "constant", "step", "ramp", "sine", "stuck", "off"):
            self._expr = compile_expr(signal, ("t", "tau", "x", "y", "z"),
                                      field="attack.signal")

    def _enter_phase(self, phase: AttackPhase) -> None:
        """Make ``phase`` the attack (pending until its start), and the next one due. A
        phase that lets go (rotor 0) makes the following phase pending at once: nothing is
        attacked until it starts."""
        self.moves.append((phase.start_s, phase.rotor))
        self._stuck_n = None
        while phase.rotor == 0 and self._phases:
            phase = self._phases.pop(0)
            self.moves.append((phase.start_s, phase.rotor))
        self.rotor = phase.rotor
        self.start_s = phase.start_s
        if self._custom is None:
            self._set_signal(phase.signal)
        self._next_start_s = self._phases[0].start_s if self._phases else math.inf

    def use_signal(self, signal: AttackSignal | None) -> None:
        """Drive the seized rotor with ``signal(t_s, x)`` instead of the scenario's signal
        (None: back to the scenario's). The rotor and start time stay the scenario's; the
        value is clamped and a non-finite one recorded exactly as for a built-in signal."""
        self._custom = signal
        self.signal = CUSTOM_SIGNAL if signal is not None else self.cfg.signal

    def active(self, t_s: float) -> bool:
        return self.rotor != 0 and t_s >= self.start_s

    def inject(self, rotor: int, failure_type: int, t_s: float) -> None:
        """Start (or, with type 0, stop) an attack on ``rotor`` (1-4) at ``t_s``.

        Types: 1 OFF → thrust 0; 2 STUCK → held at the command at onset; 4 WRONG → the
        scenario's signal (its built-in ``paper`` if the scenario has none); 8 DRIFT → a ramp.
        Raises ValueError naming the parameter for anything else.
        """
        if not 1 <= rotor <= 4:
            raise ValueError(f"param3 (instance): rotor must be 1-4, got {rotor}")
        if failure_type not in FAILURE_TYPES:
            raise ValueError(f"param2 (failure type): {failure_type} is not supported "
                             f"(supported: {sorted(FAILURE_TYPES)})")
        if failure_type == 0:
            if rotor == self.rotor:
                self.rotor = 0
            return
        self.rotor = rotor
        self.start_s = t_s
        self._stuck_n = None
        kind = FAILURE_TYPES[failure_type]
        if kind == "off":
            self.signal = "off"
        elif kind == "stuck":
            self.signal = "stuck"
        elif kind == "drift":
            self.signal = "ramp"
        else:
            self._set_signal(self.cfg.signal if self.cfg.signal != "off" else "paper")

    def sample(self, t_s: float, position_m: Sequence[float],
               last_command_n: float) -> AttackSample:
        """The attacked rotor's thrust at ``t_s``; ``last_command_n`` feeds STUCK.

        ``position_m``: the true position (m, paper frame) in its first three entries; the
        simulator passes its whole true state (13 floats), which a function signal reads."""
        if self.rotor == 0 or t_s < self.start_s:     # not active (inlined: every step)
            return NO_ATTACK
        if t_s >= self._next_start_s:                 # the schedule's next phase is due
            self._enter_phase(self._phases.pop(0))
            if self.rotor == 0 or t_s < self.start_s:
                return NO_ATTACK
        raw = self._raw(t_s, position_m, last_command_n)
        if not math.isfinite(raw):
            if not self._said:
                self._first_nonfinite(t_s, raw)
            return AttackSample(self.rotor, math.nan, 0.0, True)
        fmax = self.thrust_max_n    # min(max(raw, 0), f_max) for a finite raw, without calls
        applied = raw if 0.0 <= raw <= fmax else (0.0 if raw < 0.0 else fmax)
        # tuple.__new__: the NamedTuple's generated __new__ is a Python call (every step)
        return _new(AttackSample, (self.rotor, raw, applied, applied != raw))

    def _first_nonfinite(self, t_s: float, raw: float) -> None:
        if self.nonfinite_from_s is None:
            self.nonfinite_from_s = t_s
        t_s = self.nonfinite_from_s
        if self.on_nonfinite is not None:
            self._said = True
            what = f"{self.signal!r}" if self.signal != CUSTOM_SIGNAL else "the signal function"
            self.on_nonfinite(t_s, f"attack.signal {what} is not finite ({raw}) at t = "
                                   f"{t_s:.3f} s: rotor {self.rotor} gets 0 N while it is "
                                   "(the attacker's value is clamped to [0, f_max])")

    def _raw(self, t: float, pos: Sequence[float], last_command_n: float) -> float:
        c = self.cfg
        tau = t - self.start_s
        s = self.signal
        if s == "paper":
            return 0.1 * t + math.sin(pos[2])
        if s == "constant":
            return c.value_n
        if s == "step":
            return c.value_n if tau >= c.step_after_s else c.initial_n
        if s == "ramp":
            return c.initial_n + c.rate_nps * tau
        if s == "sine":
            return c.offset_n + c.amplitude_n * math.sin(2.0 * math.pi * c.frequency_hz * tau)
        if s == "stuck":
            if self._stuck_n is None:
                self._stuck_n = last_command_n
            return self._stuck_n
        if s == "off":
            return 0.0
        if self._custom is not None:
            return self._custom(t, tuple(pos))    # a copy: the signal cannot change the state
        assert self._expr is not None
        try:
            return float(self._expr({"t": t, "tau": tau, "x": pos[0], "y": pos[1], "z": pos[2]}))
        except (ArithmeticError, ValueError):
            return math.nan
