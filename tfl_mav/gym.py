"""A Gymnasium environment over the lockstep simulator (``pip install 'tfl-mav[gym]'``).

::

    import gymnasium as gym
    import tfl_mav.gym                       # registers "TflMav-v0"

    env = gym.make("TflMav-v0", scenario="paper")            # four rotor commands
    env = gym.make("TflMav-v0", base="tfl")                  # a residual on the TFL law
    obs, info = env.reset(seed=3, options={"attack": {"signal": "off"}})

One step is one control period of the scenario (1 ms in ``paper``): the simulator in this
process, no network, no clock — so ``reset`` is cheap (a new simulator is a few lists; the
path's kernels are built once per scenario) and the same seed flies the same episode.

**Action** (``Box(-1, 1, (4,))``, rotors 1-4): without a base, the rotor thrust commands,
f_i = (a_i + 1)/2 · f_max; with ``base`` (``tfl``, ``se3``, ``cascade`` or ``module:Name``,
flying with the attack found from rpm), a residual on the base's command,
f_i = f_base,i + a_i · ``residual_n``. Either is clipped to [0, f_max]; an action outside
[-1, 1] is clipped, a non-finite one raises ValueError (never a NaN to a motor).

**Observation** (``Box((20,), float32)``): what the flight software sees — the measured
state (position m, velocity m/s, quaternion wxyz body FLU → inertial, body rates rad/s;
paper frame, z up; with the scenario's sensor noise), the ESC speeds (rpm, rotors 1-4) and
the vector from the position to the path's closest point (m, from the measured position).

**Reward** per step: −d, d the *true* distance (m) from the vehicle to the path after the
step; on a crash additionally −``crash_penalty`` (default 100). So an episode's return is
about −∫d dt / dt: staying on the path scores 0, drifting 1 m costs 1 a tick.

**Episode end**: ``terminated`` on a crash (hit the ground, flipped, spinning past
300 rad/s, runaway, a non-finite state); ``truncated`` at the scenario's ``run.duration_s``
(or ``duration_s``). ``info``: ``t_s``, ``path_distance_m``, ``thrust_n`` (what went to the
motors), ``attack_n``, ``detected_rotor`` (the base's detection; 0 without a base),
``crash_reason``.

**reset(seed, options)**: ``seed`` is the scenario's ``run.seed`` (sensor noise) and seeds
``initial_position_noise_m`` (a uniform offset of the start, default 0); ``options``:
``scenario`` (name, path or Scenario), ``attack`` (an :class:`~tfl_mav.api.Attack`, a
dict of ``[attack]`` keys, or ``"none"``), ``base`` — each kept for later resets.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import gymnasium
import numpy as np
from gymnasium import spaces

from tfl_mav.api import AttackSignal, with_attack
from tfl_mav.baselines.reference import PathReference
from tfl_mav.controller.flight_computer import FlightComputer
from tfl_mav.controller.software import (
    GuardedSoftware,
    load_flight_software,
    load_object,
    software_name,
)
from tfl_mav.scenario import Scenario, ScenarioError, apply_overrides, load_scenario
from tfl_mav.sitl.simulator import Simulator

__all__ = ["OBSERVATION_FIELDS", "TflMavEnv"]

# Bounds of each observation: wide enough for anything flown before the simulator calls it
# a crash (|v| ≤ 100 m/s, |ω| ≤ 300 rad/s), the ESC's rpm field, a unit quaternion.
_BOUNDS = {"m": 1e6, "mps": 1e3, "q": 1.0, "radps": 1e4, "rpm": 65535.0}
OBSERVATION_FIELDS = ("x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps", "qw", "qx", "qy", "qz",
                      "p_radps", "q_radps", "r_radps", "rpm1", "rpm2", "rpm3", "rpm4",
                      "path_dx_m", "path_dy_m", "path_dz_m")
_UNITS = ["m"] * 3 + ["mps"] * 3 + ["q"] * 4 + ["radps"] * 3 + ["rpm"] * 4 + ["m"] * 3
_OBS_HIGH = np.array([_BOUNDS[u] for u in _UNITS], dtype=np.float32)
_OBS_LOW = np.where(np.array(_UNITS) == "rpm", 0.0, -_OBS_HIGH).astype(np.float32)


class TflMavEnv(gymnasium.Env):
    """The vehicle of a scenario, flown one control period a step (see the module)."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": []}

    def __init__(self, scenario: Scenario | str = "paper", *, base: str | None = None,
                 settings: Sequence[str] = (), residual_n: float = 1.0,
                 crash_penalty: float = 100.0, duration_s: float | None = None,
                 initial_position_noise_m: float = 0.0) -> None:
        super().__init__()
        self.residual_n = float(residual_n)
        self.crash_penalty = float(crash_penalty)
        self.duration_s = duration_s
        self.initial_position_noise_m = float(initial_position_noise_m)
        self.action_space = spaces.Box(-1.0, 1.0, (4,), np.float32)
        self.observation_space = spaces.Box(_OBS_LOW, _OBS_HIGH, dtype=np.float32)
        self._settings = list(settings)
        self._attack: Any = None
        self._set_scenario(scenario)
        self._set_base(base)
        self.sim: Simulator | None = None

    # ------------------------------------------------------------------ configuration
    def _set_scenario(self, scenario: Scenario | str) -> None:
        sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
        self.scenario = apply_overrides(sc, self._settings)
        self._refresh_paths()

    def _refresh_paths(self) -> None:
        """The path references (their kernels built once per scenario) and the closest
        point of the nominal start, from which every episode's projection starts (the same
        start every reset: the same bits every episode)."""
        sc = self._flown_scenario()
        self._seen = PathReference.for_scenario(sc)       # from the measured state (obs)
        self._true = PathReference(self._seen.path, sc.path.speed_mps)   # reward
        self._true.at(sc.initial.position_m)
        self._lam0 = self._true.lam

    def _set_base(self, base: str | None) -> None:
        self.base = base
        self._base_factory = None
        if base is not None:
            name, factory = load_flight_software(base)
            if load_object(base) is FlightComputer:   # no deadline here: gains when met
                factory = lambda sc: FlightComputer(sc, design_gains=False)  # noqa: E731
            self._base_factory = factory
            self._base_name = name

    def _set_attack(self, attack: Any) -> None:
        if attack is None:
            return
        if attack == "none":
            self.scenario = self.scenario.replace(**{"attack.rotor": 0})
            self._attack = None
        elif isinstance(attack, Mapping):
            self.scenario = apply_overrides(
                self.scenario, [f"attack.{k}={_toml(v)}" for k, v in attack.items()])
            self._attack = None
        else:
            with_attack(self.scenario, attack)          # says now if it cannot be flown
            self._attack = attack
        self._refresh_paths()

    def _flown_scenario(self) -> Scenario:
        return with_attack(self.scenario, self._attack)

    # ------------------------------------------------------------------ gymnasium
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = sorted(set(options) - {"scenario", "attack", "base"})
        if unknown:
            raise ValueError(f"reset options: unknown {unknown[0]!r} (known: scenario, "
                             "attack, base)")
        if "scenario" in options:
            self._set_scenario(options["scenario"])
        if "attack" in options:
            self._set_attack(options["attack"])
        if "base" in options:
            self._set_base(options["base"])
        run_seed = int(seed) if seed is not None else int(self.np_random.integers(2 ** 31))
        sc = self._flown_scenario().replace(**{"run.seed": run_seed})
        if self.initial_position_noise_m > 0.0:
            offset = self.np_random.uniform(-1.0, 1.0, 3) * self.initial_position_noise_m
            sc = sc.replace(**{"initial.position_m": [
                float(c) + float(o) for c, o in zip(sc.initial.position_m, offset, strict=True)]})
        self._signal = (AttackSignal(self._attack, software_name(self._attack))
                        if self._attack is not None else None)
        self.sim = Simulator(sc, attack_signal=self._signal)
        self._seen.start_at(self._lam0)
        self._true.start_at(self._lam0)
        self._base = (GuardedSoftware(self._base_factory(sc), name=self._base_name,
                                      thrust_max_n=sc.vehicle.thrust_max_n)
                      if self._base_factory is not None else None)
        duration = sc.run.duration_s if self.duration_s is None else self.duration_s
        self._ticks_left = round(duration / self.sim.control_dt_s)
        self._fmax = sc.vehicle.thrust_max_n
        self._base_thrust = self._base_command()
        return self._observation(), self._info(self.sim.rotor_commands_n, self._distance())

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        sim = self.sim
        if sim is None:
            raise RuntimeError("step: call reset() first")
        a = np.asarray(action, dtype=float).reshape(-1)
        if a.shape != (4,) or not np.all(np.isfinite(a)):
            raise ValueError(f"action: expected 4 finite values in [-1, 1], got {action!r}")
        a = np.clip(a, -1.0, 1.0).tolist()
        fmax = self._fmax
        if self._base_thrust is None:
            thrust = [(ai + 1.0) * 0.5 * fmax for ai in a]
        else:
            r = self.residual_n
            thrust = [min(max(f + ai * r, 0.0), fmax)
                      for f, ai in zip(self._base_thrust, a, strict=True)]
        sim.set_command(thrust)
        sim.step_control_period()
        self._ticks_left -= 1
        crash = sim.crash_reason()
        failed = self._failure()
        dist = self._distance()
        reward = -dist if math.isfinite(dist) else -self.crash_penalty
        terminated = crash is not None or failed is not None
        if terminated:
            reward -= self.crash_penalty
            self._base_thrust = None
        else:
            self._base_thrust = self._base_command()
        truncated = not terminated and self._ticks_left <= 0
        info = self._info(sim.rotor_commands_n, dist)
        info["crash_reason"] = crash or failed or ""
        return self._observation(), float(reward), terminated, truncated, info

    # ------------------------------------------------------------------ parts
    def _base_command(self) -> list[float] | None:
        """The base flight software's command for the state now (None: no base)."""
        if self._base is None:
            return None
        sim = self.sim
        assert sim is not None
        res = self._base.step(sim.time_s, sim.measured_floats, sim.measured_rpm_floats,
                              sim.rotor_commands_n)
        return list(res.thrust_n)

    def _failure(self) -> str | None:
        if self._signal is not None and self._signal.failure_reason:
            return self._signal.failure_reason
        if self._base is not None and self._base.failure_reason:
            return self._base.failure_reason
        return None

    def _distance(self) -> float:
        assert self.sim is not None
        ref = self._true.at(self.sim.state_vector[:3])
        return ref.distance_m if ref is not None else math.nan

    def _observation(self) -> np.ndarray:
        sim = self.sim
        assert sim is not None
        m = sim.measured_floats
        ref = self._seen.at(m.position_m)
        delta = ((ref.position_m[0] - m.position_m[0], ref.position_m[1] - m.position_m[1],
                  ref.position_m[2] - m.position_m[2]) if ref is not None else (0.0, 0.0, 0.0))
        obs = np.array([*m.position_m, *m.velocity_mps, *m.quaternion_wxyz,
                        *m.body_rates_radps, *sim.measured_rpm_floats, *delta],
                       dtype=np.float32)
        return np.clip(np.nan_to_num(obs, nan=0.0), _OBS_LOW, _OBS_HIGH)

    def _info(self, thrust: Sequence[float], dist: float) -> dict[str, Any]:
        sim = self.sim
        assert sim is not None
        return {"t_s": sim.time_s, "path_distance_m": dist, "thrust_n": list(thrust),
                "attack_n": sim.attack.applied_n if sim.attack.rotor else 0.0,
                "detected_rotor": self._base.detected_rotor if self._base is not None else 0}


def _toml(value: Any) -> str:
    """A Python value as the TOML text ``--set`` parses."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, (int, float)):
        return repr(value)
    raise ScenarioError("attack", f"cannot set {value!r}")


if "TflMav-v0" not in gymnasium.registry:
    gymnasium.register(id="TflMav-v0", entry_point="tfl_mav.gym:TflMavEnv")
