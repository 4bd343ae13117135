"""Scenario files: one TOML file describes one run, shared by the simulator and the controller.

Every key is optional and defaults to the paper's §VI setup (see ``scenarios/paper.toml``
and docs/scenarios.md). Each section maps onto a frozen dataclass below; the field
metadata (unit, bounds, length) is the single source of truth for validation, so an
unknown key, a wrong type or an out-of-range value raises :class:`ScenarioError` naming the
key, e.g. ``vehicle.mass_kg: must be > 0, got -1``.

Frames: vectors in ``[initial]`` are in the paper frame (inertial z **up**, ZYX Euler angles,
body rates (p, q, r) about b1, b2, b3).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from tfl_mav.control.detect.detector import DetectorConfig

__all__ = [
    "SECTIONS",
    "AttackConfig",
    "AttackPhase",
    "ControllerConfig",
    "InitialConfig",
    "PathConfig",
    "RunConfig",
    "Scenario",
    "ScenarioError",
    "SensorConfig",
    "VehicleConfig",
    "WindConfig",
    "apply_overrides",
    "builtin_scenarios",
    "load_scenario",
    "scenario_from_dict",
]


MAX_ESC_RPM = 65535
"""The largest rotor speed ESC_TELEMETRY_1_TO_4 can report (its rpm field is uint16)."""


class ScenarioError(ValueError):
    """A scenario is malformed; ``key`` is the dotted key at fault (``vehicle.mass_kg``)."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}" if key else message)
        self.key = key
        self.message = message


def _f(default: Any, unit: str = "", *, lo: float | None = None, hi: float | None = None,
       lo_open: bool = False, length: int | None = None, doc: str = "") -> Any:
    """A dataclass field carrying the validation rules for one scenario key."""
    meta = {"unit": unit, "lo": lo, "hi": hi, "lo_open": lo_open, "length": length, "doc": doc}
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda: default, metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class VehicleConfig:
    """The true vehicle (the plant). Paper §VI values; d, k_t, k_r are the paper's unstated ones."""

    mass_kg: float = _f(1.1, "kg", lo=0.0, lo_open=True, hi=1000.0)
    inertia_kgm2: tuple[float, float, float] = _f(
        (0.0020066, 0.0020038, 0.0013323), "kg m^2", lo=0.0, lo_open=True, hi=1000.0, length=3,
        doc="diagonal of J in body axes (Ix, Iy, Iz)")
    arm_m: float = _f(0.2656, "m", lo=0.0, lo_open=True, hi=10.0,
                      doc="rotor distance from the CG, l")
    drag_thrust_ratio_m: float = _f(0.016, "m", lo=0.0, lo_open=True, hi=1.0,
                                    doc="d in the mixer")
    k_t: float = _f(0.05, "N s/m", lo=0.0, hi=1000.0, doc="translational drag")
    k_r: float = _f(2.75e-3, "N m s/rad", lo=0.0, hi=100.0, doc="rotational drag")
    thrust_max_n: float = _f(8.0, "N", lo=0.0, lo_open=True, hi=10000.0,
                             doc="per-rotor thrust limit")
    k_f: float = _f(8.0e-6, "N/(rad/s)^2", lo=0.0, lo_open=True, hi=1.0, doc="f = k_f w^2")
    motor_time_constant_s: float = _f(0.0, "s", lo=0.0, hi=1.0, doc="lag on w; 0 = none")
    rpm_noise_std: float = _f(0.0, "rpm", lo=0.0, hi=1000.0, doc="ESC rpm measurement noise")
    gravity_mps2: float = _f(9.81, "m/s^2", lo=0.0, lo_open=True, hi=100.0)
    # Rotor aerodynamics in moving air (tfl_mav.sitl.physics.RotorAeroParams). The defaults
    # are RotorPy's AscTec Hummingbird (rotorpy/vehicles/hummingbird_params.py: k_d 1.19e-4,
    # k_z 2.32e-4, k_h 3.39e-3, c_D 0.5e-2/0.5e-2/1e-2, k_eta 5.57e-6, arm 0.17 m) scaled to
    # this airframe: rotors of the same family with k_f/k_eta = 1.436 have a radius
    # (k_f/k_eta)^1/4 as large, so k_d, k_z (∝ ρ A R) scale by (k_f/k_eta)^3/4 = 1.312 and
    # k_h (∝ ρ A) by (k_f/k_eta)^1/2 = 1.198; the frame's drag by its area, (0.2656/0.17)².
    rotor_aero: bool = _f(False, doc="rotor drag, inflow, lift and frame drag (off: paper)")
    rotor_drag_coeff: float = _f(1.56e-4, "N/((rad/s)(m/s))", lo=0.0,
                                 doc="k_d: H-force per rotor speed and in-plane airspeed")
    rotor_inflow_coeff: float = _f(3.04e-4, "N/((rad/s)(m/s))", lo=0.0,
                                   doc="k_z: induced-inflow drag along the rotor axis")
    translational_lift_coeff: float = _f(4.06e-3, "N/(m/s)^2", lo=0.0,
                                         doc="k_h: thrust gained per in-plane airspeed squared")
    parasitic_drag_coeff: tuple[float, float, float] = _f(
        (1.22e-2, 1.22e-2, 2.44e-2), "N/(m/s)^2", lo=0.0, length=3,
        doc="frame drag c_D along b1, b2, b3")
    rotor_inertia_kgm2: float = _f(0.0, "kg m^2", lo=0.0, hi=0.01,
                                   doc="J_r of each rotor (with rotor_aero: spin-up reaction "
                                       "and gyroscopic torque); 0 = off; OS4's is 6e-5")

    @property
    def omega_max_radps(self) -> float:
        """Rotor speed at which thrust reaches ``thrust_max_n``."""
        return math.sqrt(self.thrust_max_n / self.k_f)


@dataclass(frozen=True)
class InitialConfig:
    """Initial state in the paper frame (z up)."""

    position_m: tuple[float, float, float] = _f((1.5, 0.3, 0.5), "m", length=3)
    velocity_mps: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "m/s", length=3)
    euler_rad: tuple[float, float, float] = _f(
        (0.0, 0.0, 0.0), "rad", length=3, doc="ZYX Euler angles (phi, theta, psi)")
    body_rates_radps: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "rad/s", length=3)


ATTACK_SIGNALS = ("paper", "constant", "step", "ramp", "sine", "stuck", "off")


@dataclass(frozen=True)
class AttackPhase:
    """One phase of an attack schedule (``[[attack.phases]]``): from ``start_s`` the attacker
    holds ``rotor`` (1-4; 0 = lets go) with ``signal`` (as ``attack.signal``; ``tau`` restarts
    at the phase's start). The signals' own keys (``value_n``, ``rate_nps``, …) are the
    section's."""

    rotor: int
    signal: str
    start_s: float


_PHASE_KEYS = ("rotor", "signal", "start_s")


def _phases(value: Any, key: str = "attack.phases") -> tuple[AttackPhase, ...]:
    """``[[attack.phases]]`` checked (each key, start times increasing) into phases."""
    if isinstance(value, tuple) and all(isinstance(p, AttackPhase) for p in value):
        return value
    if not isinstance(value, (list, tuple)):
        raise ScenarioError(key, f"must be a list of tables ([[attack.phases]]), got "
                                 f"{type(value).__name__}")
    out = []
    for i, table in enumerate(value):
        at = f"{key}[{i}]"
        if isinstance(table, AttackPhase):
            table = dataclasses.asdict(table)
        if not isinstance(table, dict):
            raise ScenarioError(at, f"must be a table with {', '.join(_PHASE_KEYS)}, "
                                    f"got {table!r}")
        unknown = sorted(set(table) - set(_PHASE_KEYS))
        if unknown:
            raise ScenarioError(f"{at}.{unknown[0]}", f"unknown key (known keys: "
                                                      f"{', '.join(_PHASE_KEYS)})")
        missing = [k for k in _PHASE_KEYS if k not in table and k != "signal"]
        if missing:
            raise ScenarioError(f"{at}.{missing[0]}", "missing (every phase says which rotor "
                                                      "from when)")
        rotor = _check_number(f"{at}.rotor", table["rotor"],
                              {"lo": 0, "hi": 4, "lo_open": False, "unit": ""}, True)
        start = _check_number(f"{at}.start_s", table["start_s"],
                              {"lo": 0.0, "hi": None, "lo_open": False, "unit": "s"}, False)
        signal = table.get("signal", "paper")
        if not isinstance(signal, str):
            raise ScenarioError(f"{at}.signal", f"must be a string, got {signal!r}")
        _check_signal(f"{at}.signal", signal)
        if out and start <= out[-1].start_s:
            raise ScenarioError(f"{at}.start_s", f"must be after the previous phase's "
                                                 f"({out[-1].start_s:g} s), got {start:g}")
        out.append(AttackPhase(int(rotor), signal, float(start)))
    return tuple(out)


@dataclass(frozen=True)
class AttackConfig:
    """Which rotor the attacker seizes, from when, and the thrust it forces.

    ``signal`` is a built-in name (``paper`` = ``0.1*t + sin(z)``, ``constant``, ``step``,
    ``ramp``, ``sine``, ``stuck``, ``off``) or an expression in ``t`` (sim time, s), ``tau``
    (time since the attack started, s) and ``x, y, z`` (position, m, paper frame). The value
    is clamped to [0, thrust_max_n] and the clamping is recorded.
    """

    rotor: int = _f(2, lo=0, hi=4, doc="1-4; 0 = no attack")
    start_s: float = _f(0.0, "s", lo=0.0)
    signal: str = _f("paper")
    value_n: float = _f(1.0, "N", doc="constant: value; step: level after the step")
    initial_n: float = _f(0.0, "N", doc="step/ramp: level at the attack start")
    step_after_s: float = _f(1.0, "s", lo=0.0, doc="step: delay after start_s")
    rate_nps: float = _f(0.1, "N/s", doc="ramp slope")
    amplitude_n: float = _f(1.0, "N", doc="sine amplitude")
    frequency_hz: float = _f(0.5, "Hz", lo=0.0, doc="sine frequency")
    offset_n: float = _f(2.0, "N", doc="sine offset")
    phases: tuple[AttackPhase, ...] = _f(
        (), doc="[[attack.phases]] (rotor, signal, start_s): an attacker that moves between "
                "rotors; when given, it replaces rotor/start_s/signal")

    def __post_init__(self) -> None:
        object.__setattr__(self, "phases", _phases(self.phases))

    @property
    def first_rotor(self) -> int:
        """The first rotor attacked (the schedule's first phase that holds one)."""
        if self.phases:
            return next((p.rotor for p in self.phases if p.rotor), 0)
        return self.rotor


@dataclass(frozen=True)
class PathConfig:
    """The path: ``kind`` and its own keys (see ``tfl_mav.control.path.paths.PATH_KINDS``)."""

    kind: str = _f("paper")
    speed_mps: float = _f(0.5, "m/s", doc="desired speed along the path (eta reference)")
    params: dict[str, Any] = _f({}, doc="the kind's own keys, validated by the path library")


@dataclass(frozen=True)
class ControllerConfig:
    """The controller's model and gains (model deliberately off by the scales)."""

    model_mass_scale: float = _f(1.02, lo=0.5, hi=2.0, doc="model mass = scale * true mass")
    model_inertia_scale: float = _f(1.1, lo=0.5, hi=2.0, doc="model J = scale * true J")
    law: str = _f("robust", doc="'paper' (plain law) or 'robust' (estimators + gain switch)")
    supervisor: str = _f("auto", doc="which law flies: 'auto' (TFL where it holds the path, "
                                     "the safe law where it cannot), 'tfl' or 'safe' alone")
    xi_pole: float = _f(-2.5, "1/s", hi=0.0, lo_open=False, doc="repeated pole of the xi chain")
    eta_pole: float = _f(-2.0, "1/s", hi=0.0, doc="repeated pole of the eta chain")
    # The transverse error a residual acceleration d leaves is 6d/p² (four poles at −p), and
    # what a hand-back's start costs falls as 1/p² (acceleration) and 1/p³ (jerk): every
    # envelope case was as good or better at −6, −8 and −12 than at −4, and the first to lose
    # was at −20 (a 20 ms lag with 20 rpm noise under an intermittent attack, 5.3 → 6.1 mm).
    # −8 keeps a factor 2.5 from there.
    xi_pole_fine: float = _f(-8.0, "1/s", hi=0.0, doc="robust: xi pole after settling")
    eta_pole_fine: float = _f(-2.5, "1/s", hi=0.0, doc="robust: eta pole after settling")
    yaw_pole: float = _f(-4.0, "1/s", hi=0.0, doc="nominal law: yaw (psi) chain pole")
    mass_estimator: bool = _f(True, doc="robust: online thrust-to-mass estimate")
    disturbance_observer: bool = _f(True, doc="robust: p/q angular acceleration observer")
    gain_switch: bool = _f(True, doc="robust: switch to the fine poles once settled")
    observer_tau_s: float = _f(0.004, "s", lo=0.0, lo_open=True, hi=1.0)
    translational_observer: str = _f("auto", doc="robust: the horizontal unmodelled-"
                                     "acceleration observer (a wind's drag) fed to the xi, eta "
                                     "chains: 'on', 'off', or 'auto' (on outdoors: wind, rotor "
                                     "aerodynamics or realistic sensors)")
    translational_observer_tau_s: float = _f(0.1, "s", lo=0.0, lo_open=True, hi=10.0)
    aware_of_attack: bool = _f(True, doc="False = the baseline that ignores the attack")
    motor_time_constant_scale: float = _f(1.0, lo=0.0, hi=10.0,
                                          doc="controller's tau_m = scale * true "
                                              "motor_time_constant_s; 0 = ignore the lag")


@dataclass(frozen=True)
class SensorConfig:
    """Noise on the state the controller sees (Gaussian, seeded), paper frame."""

    position_noise_std_m: float = _f(0.0, "m", lo=0.0)
    velocity_noise_std_mps: float = _f(0.0, "m/s", lo=0.0)
    attitude_noise_std_rad: float = _f(0.0, "rad", lo=0.0)
    rate_noise_std_radps: float = _f(0.0, "rad/s", lo=0.0)
    gyro_range_radps: float = _f(0.0, "rad/s", lo=0.0, hi=1000.0,
                                 doc="measured rates clip at ± this (34.9 = 2000 deg/s); 0 = off")
    model: str = _f("ideal", doc="'ideal' (the state + the noise above) or 'realistic' (IMU, "
                                 "GPS, baro, mag fused onboard by an error-state EKF)")
    gps_hz: float = _f(10.0, "Hz", lo=1.0, hi=50.0, doc="realistic: GPS fix rate")
    gps_latency_s: float = _f(0.1, "s", lo=0.0, hi=1.0, doc="realistic: fix delivered this late")
    gps_position_noise_std_m: float = _f(0.02, "m", lo=0.0, lo_open=True, hi=10.0,
                                         doc="realistic: horizontal (vertical 1.5x); "
                                             "0.02 = RTK")
    gps_velocity_noise_std_mps: float = _f(0.05, "m/s", lo=0.0, lo_open=True, hi=5.0,
                                           doc="realistic: GPS velocity noise")


TURBULENCE_LEVELS = ("none", "light", "moderate", "severe")
OBSERVER_MODES = ("auto", "on", "off")
SENSOR_MODELS = ("ideal", "realistic")


@dataclass(frozen=True)
class WindConfig:
    """The air the vehicle flies in, paper frame (z up), m/s: a mean wind, Dryden turbulence
    (MIL-F-8785C / MIL-HDBK-1797 low-altitude scales and intensities, seeded by ``run.seed``)
    and one discrete 1 − cos gust (``tfl_mav.sitl.wind``). Every aerodynamic force acts on the
    velocity relative to this air."""

    mean_mps: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "m/s", length=3, lo=-50.0,
                                              hi=50.0, doc="mean wind, paper frame")
    turbulence: str = _f("none", doc="none | light | moderate | severe (Dryden)")
    gust_mps: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "m/s", length=3, lo=-50.0,
                                              hi=50.0, doc="1 - cos gust: peak air velocity")
    gust_start_s: float = _f(0.0, "s", lo=0.0)
    gust_duration_s: float = _f(0.0, "s", lo=0.0, hi=3600.0, doc="0 = no gust")

    @property
    def active(self) -> bool:
        """Whether the air moves at all (still air keeps the still-air physics step)."""
        return (any(c != 0.0 for c in self.mean_mps) or self.turbulence != "none"
                or (self.gust_duration_s > 0.0 and any(c != 0.0 for c in self.gust_mps)))


@dataclass(frozen=True)
class RunConfig:
    """Run length, rates and seed."""

    duration_s: float = _f(30.0, "s", lo=0.0, lo_open=True, hi=86400.0)
    physics_hz: float = _f(1000.0, "Hz", lo=1000.0, hi=100000.0)
    control_hz: float = _f(1000.0, "Hz", lo=1.0, hi=100000.0)
    seed: int = _f(0, lo=0)

    @property
    def physics_dt_s(self) -> float:
        return 1.0 / self.physics_hz

    @property
    def steps_per_control(self) -> int:
        return round(self.physics_hz / self.control_hz)

    @property
    def control_dt_s(self) -> float:
        return self.steps_per_control / self.physics_hz


@dataclass(frozen=True)
class Scenario:
    """One run. ``source`` says where it came from (built-in name or file path)."""

    name: str = "paper"
    description: str = ""
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    initial: InitialConfig = field(default_factory=InitialConfig)
    attack: AttackConfig = field(default_factory=AttackConfig)
    path: PathConfig = field(default_factory=PathConfig)
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    sensors: SensorConfig = field(default_factory=SensorConfig)
    run: RunConfig = field(default_factory=RunConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    wind: WindConfig = field(default_factory=WindConfig)
    source: str = "<defaults>"

    def replace(self, **sections: Any) -> Scenario:
        """A copy with whole sections or dotted keys replaced: ``replace(**{"run.seed": 3})``."""
        out = self
        for key, value in sections.items():
            if "." in key:
                sec, name = key.split(".", 1)
                section = getattr(out, sec)
                if isinstance(section, PathConfig):
                    # kind, speed_mps and the path library's own keys share one table
                    table = {"kind": section.kind, "speed_mps": section.speed_mps,
                             **section.params, name: value}
                    out = dataclasses.replace(out, path=_path_section(table, PathConfig()))
                    continue
                if isinstance(section, dict):
                    out = dataclasses.replace(out, **{sec: {**section, name: value}})
                    continue
                checked = _section(type(section), {name: value}, sec, base=section)
                out = dataclasses.replace(out, **{sec: checked})
            else:
                out = dataclasses.replace(out, **{key: value})
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (TOML-shaped) for logging into run metadata."""
        d = dataclasses.asdict(self)
        path = d["path"]
        d["path"] = {"kind": path["kind"], "speed_mps": path["speed_mps"], **path["params"]}
        return d


#: The scenario's sections (a TOML table each) and the config type each is read into.
SECTIONS: dict[str, type] = {
    "vehicle": VehicleConfig,
    "initial": InitialConfig,
    "attack": AttackConfig,
    "controller": ControllerConfig,
    "sensors": SensorConfig,
    "run": RunConfig,
    "detector": DetectorConfig,
    "wind": WindConfig,
}


def _check_number(key: str, value: Any, meta: dict[str, Any], integer: bool) -> float | int:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        kind = "an integer" if integer else "a number"
        raise ScenarioError(key, f"must be {kind}, got {type(value).__name__} {value!r}")
    if integer and not isinstance(value, int):
        raise ScenarioError(key, f"must be an integer, got {value!r}")
    if not math.isfinite(value):
        raise ScenarioError(key, f"must be finite, got {value!r}")
    lo, hi, unit = meta["lo"], meta["hi"], meta["unit"]
    u = f" {unit}" if unit else ""
    too_low = lo is not None and (value <= lo if meta["lo_open"] else value < lo)
    if too_low or (hi is not None and value > hi):
        if lo is not None and hi is not None:   # say the whole accepted range
            raise ScenarioError(key, f"must be in {'(' if meta['lo_open'] else '['}{lo:g}, "
                                     f"{hi:g}]{u}, got {value!r}")
        if too_low:
            rel = ">" if meta["lo_open"] else ">="
            raise ScenarioError(key, f"must be {rel} {lo}{u}, got {value!r}")
        raise ScenarioError(key, f"must be <= {hi}{u}, got {value!r}")
    return int(value) if integer else float(value)


def _section(cls: type, table: Any, name: str, base: Any = None) -> Any:
    """Validate one TOML table against dataclass ``cls`` (starting from ``base`` values)."""
    if not isinstance(table, dict):
        raise ScenarioError(name, f"must be a table, got {type(table).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    values: dict[str, Any] = {}
    for key, value in table.items():
        dotted = f"{name}.{key}"
        f = fields.get(key)
        if f is None:
            known = ", ".join(sorted(fields))
            raise ScenarioError(dotted, f"unknown key (known keys: {known})")
        meta = dict(f.metadata)
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        if meta.get("length"):
            if not isinstance(value, (list, tuple)) or len(value) != meta["length"]:
                raise ScenarioError(dotted, f"must be a list of {meta['length']} numbers, "
                                            f"got {value!r}")
            values[key] = tuple(_check_number(f"{dotted}[{i}]", v, meta, False)
                                for i, v in enumerate(value))
        elif isinstance(default, bool):
            if not isinstance(value, bool):
                raise ScenarioError(dotted, f"must be true or false, got {value!r}")
            values[key] = value
        elif isinstance(default, int):
            values[key] = _check_number(dotted, value, meta, True)
        elif isinstance(default, float):
            values[key] = _check_number(dotted, value, meta, False)
        elif isinstance(default, str):
            if not isinstance(value, str):
                raise ScenarioError(dotted, f"must be a string, got {value!r}")
            values[key] = value
        else:
            values[key] = value
    out = dataclasses.replace(base, **values) if base is not None else cls(**values)
    _cross_check(name, out)
    return out


def _cross_check(name: str, sec: Any) -> None:
    """Rules that involve more than one key of a section."""
    if isinstance(sec, RunConfig):
        ratio = sec.physics_hz / sec.control_hz
        if ratio < 1 or abs(ratio - round(ratio)) > 1e-9:
            raise ScenarioError(f"{name}.control_hz", "physics_hz must be a whole multiple of "
                                f"control_hz, got {sec.physics_hz:g}/{sec.control_hz:g}")
    if isinstance(sec, ControllerConfig) and sec.law not in ("paper", "robust"):
        raise ScenarioError(f"{name}.law", f"must be 'paper' or 'robust', got {sec.law!r}")
    if isinstance(sec, ControllerConfig) and sec.supervisor not in ("auto", "tfl", "safe"):
        raise ScenarioError(f"{name}.supervisor",
                            f"must be 'auto', 'tfl' or 'safe', got {sec.supervisor!r}")
    if isinstance(sec, ControllerConfig) and sec.translational_observer not in OBSERVER_MODES:
        raise ScenarioError(f"{name}.translational_observer",
                            f"must be 'auto', 'on' or 'off', got {sec.translational_observer!r}")
    if isinstance(sec, AttackConfig):
        _check_signal(f"{name}.signal", sec.signal)
    if isinstance(sec, VehicleConfig):
        # Full thrust must be a rotor speed ESC_TELEMETRY_1_TO_4 can carry (rpm is uint16):
        # beyond it the controller reads a clamped rpm, i.e. a wrong thrust, on every rotor
        # near full throttle (the detector then flags the wrong rotor).
        rpm_max = sec.omega_max_radps * 60.0 / (2.0 * math.pi)
        if rpm_max > MAX_ESC_RPM:
            f_ok = sec.k_f * (MAX_ESC_RPM * 2.0 * math.pi / 60.0) ** 2
            raise ScenarioError(f"{name}.thrust_max_n",
                                f"{sec.thrust_max_n:g} N needs {rpm_max:.0f} rpm with k_f = "
                                f"{sec.k_f:g}, beyond the {MAX_ESC_RPM} rpm ESC telemetry "
                                f"carries: must be in (0, {f_ok:.4g}] N for this k_f "
                                f"(or raise {name}.k_f)")
    if isinstance(sec, SensorConfig) and sec.model not in SENSOR_MODELS:
        raise ScenarioError(f"{name}.model", f"must be one of {', '.join(SENSOR_MODELS)}, "
                                             f"got {sec.model!r}")
    if isinstance(sec, WindConfig) and sec.turbulence not in TURBULENCE_LEVELS:
        raise ScenarioError(f"{name}.turbulence", f"must be one of "
                            f"{', '.join(TURBULENCE_LEVELS)}, got {sec.turbulence!r}")


def _check_signal(key: str, signal: str) -> None:
    if signal in ATTACK_SIGNALS:
        return
    from tfl_mav.expr import ExprError, compile_expr

    try:
        compile_expr(signal, ("t", "tau", "x", "y", "z"), field=key)
    except ExprError as exc:
        hint = f" (or one of {', '.join(ATTACK_SIGNALS)})"
        raise ScenarioError(key, exc.message + hint) from None


def scenario_from_dict(data: dict[str, Any], *, source: str = "<dict>",
                       base: Scenario | None = None) -> Scenario:
    """Build a validated scenario from a TOML-shaped dict, on top of ``base`` (defaults)."""
    sc = base or Scenario()
    kwargs: dict[str, Any] = {"source": source}
    for key, value in data.items():
        if key in ("name", "description"):
            if not isinstance(value, str):
                raise ScenarioError(key, f"must be a string, got {value!r}")
            kwargs[key] = value
        elif key in SECTIONS:
            kwargs[key] = _section(SECTIONS[key], value, key, base=getattr(sc, key))
        elif key == "path":
            kwargs[key] = _path_section(value, sc.path)
        else:
            known = ", ".join(["name", "description", "path", *SECTIONS])
            raise ScenarioError(key, f"unknown section (known: {known})")
    return dataclasses.replace(sc, **kwargs)


def _path_section(table: Any, base: PathConfig) -> PathConfig:
    if not isinstance(table, dict):
        raise ScenarioError("path", "must be a table")
    table = dict(table)
    kind = table.pop("kind", base.kind)
    if not isinstance(kind, str):
        raise ScenarioError("path.kind", f"must be a string, got {kind!r}")
    speed = table.pop("speed_mps", base.speed_mps)
    meta = {"lo": None, "hi": 20.0, "lo_open": False, "unit": "m/s"}
    speed = _check_number("path.speed_mps", speed, meta, False)
    params = table if kind != base.kind or not base.params else {**base.params, **table}
    return PathConfig(kind=kind, speed_mps=speed, params=params)


def builtin_scenarios() -> dict[str, str]:
    """Built-in scenario names mapped to their one-line descriptions."""
    out = {}
    for entry in sorted(resources.files("tfl_mav.scenarios").iterdir(), key=lambda p: p.name):
        if entry.name.endswith(".toml"):
            data = tomllib.loads(entry.read_text(encoding="utf-8"))
            out[entry.name[:-5]] = str(data.get("description", ""))
    return out


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load a built-in scenario by name (``paper``) or a TOML file by path.

    Raises :class:`ScenarioError` for a missing file, bad TOML, or any bad key.
    """
    text: str
    source = str(name_or_path)
    candidate = Path(name_or_path)
    if candidate.suffix == ".toml" or candidate.exists():
        try:
            text = candidate.read_text(encoding="utf-8")
        except OSError as exc:
            raise ScenarioError("", f"cannot read scenario file {source!r}: {exc.strerror}") \
                from None
    else:
        res = resources.files("tfl_mav.scenarios").joinpath(f"{name_or_path}.toml")
        if not res.is_file():
            names = ", ".join(builtin_scenarios())
            raise ScenarioError("", f"no built-in scenario {source!r} and no such file "
                                    f"(built-ins: {names})")
        text = res.read_text(encoding="utf-8")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError("", f"{source}: not valid TOML: {exc}") from None
    data.setdefault("name", candidate.stem if candidate.suffix else str(name_or_path))
    return scenario_from_dict(data, source=source)


def apply_overrides(scenario: Scenario, overrides: list[str]) -> Scenario:
    """Apply ``--set SECTION.KEY=VALUE`` overrides (VALUE in TOML syntax; a bare word is a
    string, so ``controller.law=paper`` works). The one parser of ``--set`` for every command;
    raises :class:`ScenarioError` naming the key."""
    sections = [f.name for f in dataclasses.fields(Scenario)
                if f.name not in ("name", "description", "source")]
    for item in overrides:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or "." not in key:
            raise ScenarioError("--set", f"expected SECTION.KEY=VALUE, got {item!r}")
        try:
            value: Any = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text.strip()
        section = key.split(".", 1)[0]
        if section not in sections:
            raise ScenarioError(key, f"unknown section {section!r} (known: "
                                     f"{', '.join(sections)})")
        try:
            scenario = scenario.replace(**{key: value})
        except TypeError as exc:
            raise ScenarioError(key, str(exc)) from None
    return scenario
