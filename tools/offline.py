"""``tfl-mav offline``: fly a scenario in-process (sitl physics, no network).

The controller runs at ``control_hz`` with a zero-order hold on the sitl physics, seeing the
measured state (with the scenario's sensor noise). How it learns about the attack is chosen
by ``attack_info``:

* ``"oracle"`` — the paper's assumption: once the attack starts the controller is told
  which rotor and that rotor's thrust as measured from its rpm (``f = k_f ω²``);
* ``"detector"`` — it must find the attack itself from ESC rpm
  (:mod:`tfl_mav.control.detector`), as the daemon does.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from sitl.physics import mix
from sitl.simulator import Simulator
from tfl_mav.control.law import StateEstimate
from tfl_mav.controller_factory import build_controller
from tfl_mav.scenario import Scenario, ScenarioError, load_scenario
from tools.flightlog import MODES, FlightLog, summarize

__all__ = ["add_parser", "fly_offline", "run"]

TWO_PI_OVER_60 = 2.0 * math.pi / 60.0


def _yaw(q: np.ndarray) -> float:
    w, x, y, z = q
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def fly_offline(sc: Scenario, *, attack_info: str = "oracle",
                progress: Callable[[float, float], None] | None = None,
                duration_s: float | None = None) -> FlightLog:
    """Fly ``sc`` and return its :class:`FlightLog` (finished, arrays)."""
    sim = Simulator(sc)
    ctrl = build_controller(sc)
    detector = None
    if attack_info == "detector":
        from tfl_mav.detector_setup import build_detector

        detector = build_detector(sc)
    elif attack_info != "oracle":
        raise ValueError(f"attack_info must be 'oracle' or 'detector', got {attack_info!r}")
    v = sc.vehicle
    log = FlightLog(thrust_max_n=v.thrust_max_n, attack_rotor=sc.attack.rotor,
                    attack_start_s=sc.attack.start_s if sc.attack.rotor else math.nan)
    log.path_points_m = ctrl.tracker.path.sample(400)
    duration = sc.run.duration_s if duration_s is None else duration_s
    n_ticks = round(duration / sim.control_dt_s)
    yaw_prev = None
    yaw_unwrapped = 0.0
    last_cmd = list(sim.rotor_commands_n)
    t0 = time.perf_counter()
    next_progress = 0.0
    for _ in range(n_ticks):
        meas = sim.measured
        rpm = sim.measured_rpm()
        att = sim.attack
        estimate = math.nan
        if detector is not None:
            det = detector.update(sim.time_s, rpm, last_cmd)
            if det.detected_rotor:
                estimate = det.estimate_n
                ctrl.set_attack(det.detected_rotor, estimate)
        elif att.rotor:
            w = rpm[att.rotor - 1] * TWO_PI_OVER_60
            estimate = v.k_f * w * w
            ctrl.set_attack(att.rotor, estimate)
        out = ctrl.update(StateEstimate(meas.position_m, meas.velocity_mps,
                                        meas.quaternion_wxyz, meas.body_rates_radps,
                                        [r * TWO_PI_OVER_60 for r in rpm]))
        sim.set_command(out.rotor_thrust_n)
        last_cmd = list(sim.rotor_commands_n)
        st = sim.state
        yaw = _yaw(st.quaternion_wxyz)
        if yaw_prev is not None:
            yaw_unwrapped += math.remainder(yaw - yaw_prev, math.tau)
        else:
            yaw_unwrapped = yaw
        yaw_prev = yaw
        true_f = sim.rotor_thrusts_n
        uf, tp, tq, tr = mix(sim.params, true_f)
        log.append(t_s=sim.time_s, position_m=st.position_m, velocity_mps=st.velocity_mps,
                   body_rates_radps=st.body_rates_radps, yaw_rad=yaw_unwrapped,
                   path_distance_m=out.path_distance_m, thrust_cmd_n=out.rotor_thrust_n,
                   thrust_true_n=true_f, attack_true_n=att.applied_n if att.rotor else 0.0,
                   attack_estimate_n=estimate, uf_n=uf, torque_nm=(tp, tq, tr),
                   saturated=any(out.saturated), mode=MODES[out.mode])
        sim.step_control_period()
        reason = sim.crash_reason()
        if reason:
            log.crashed, log.crash_reason = True, reason
            break
        if progress and sim.time_s >= next_progress:
            progress(sim.time_s, duration)
            next_progress += 1.0
    log.wall_time_s = time.perf_counter() - t0
    log.events.append((0.0, f"fallbacks: {ctrl.fallback_count}, "
                            f"saturated ticks: {ctrl.saturation_count}"))
    return log.finish()


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "offline", help="fly a scenario in-process (no network) and print metrics",
        description="Fly SCENARIO with the TFL controller on the sitl physics in one process "
                    "(no network): fast, deterministic, for studying the control law.")
    p.add_argument("scenario", nargs="?", default="paper",
                   help="built-in scenario name or path to a .toml file (default: paper)")
    p.add_argument("--json", action="store_true", help="print one JSON object of metrics")
    p.add_argument("--plot", metavar="DIR", help="write the report PNGs into DIR")
    p.add_argument("--duration", type=float, metavar="S", help="override run.duration_s")
    p.add_argument("--attack-info", choices=("oracle", "detector"), default="oracle",
                   help="how the controller learns of the attack: told (paper's assumption, "
                        "default) or detected from ESC rpm")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario key, e.g. --set controller.law=paper "
                        "(TOML value syntax; repeatable)")
    p.set_defaults(func=run)


def apply_overrides(sc: Scenario, overrides: list[str]) -> Scenario:
    """Apply ``section.key=value`` overrides (values parsed as TOML) to a scenario."""
    import tomllib

    for item in overrides:
        if "=" not in item:
            raise ScenarioError(item, "override must look like section.key=value")
        key, raw = item.split("=", 1)
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw  # a bare string such as controller.law=paper
        if "." not in key:
            raise ScenarioError(key, "override key must be section.key")
        sc = sc.replace(**{key.strip(): value})
    return sc


def run(args: argparse.Namespace) -> int:
    try:
        sc = apply_overrides(load_scenario(args.scenario), args.set)
    except (ScenarioError, TypeError) as exc:
        print(f"tfl-mav offline: scenario error: {exc}", file=sys.stderr)
        return 2

    def progress(t: float, total: float) -> None:
        if not args.json and sys.stderr.isatty():
            print(f"\r  t = {t:5.1f} / {total:.1f} s", end="", file=sys.stderr, flush=True)

    log = fly_offline(sc, attack_info=args.attack_info, progress=progress,
                      duration_s=args.duration)
    if not args.json and sys.stderr.isatty():
        print(file=sys.stderr)
    metrics = summarize(log)
    if args.plot:
        from tools.plots import write_report

        files = write_report(log, Path(args.plot), title=sc.name)
        metrics["plots"] = [str(f) for f in files]
    if args.json:
        print(json.dumps(metrics, indent=2))
    else:
        _print_summary(sc, metrics)
    return 1 if log.crashed else 0


def _print_summary(sc: Scenario, m: dict) -> None:
    status = f"CRASHED: {m['crash_reason']}" if m["crashed"] else "flew the whole run"
    print(f"{sc.name}: {status} ({m['sim_time_s']:.1f} s sim in {m['wall_time_s']:.1f} s wall)")
    if m.get("final_path_distance_m") is not None:
        print(f"  path distance: final {m['final_path_distance_m']:.2e} m, last 10 s max "
              f"{m['max_path_distance_last_10s_m']:.2e} m, "
              f"rms {m['rms_path_distance_last_10s_m']:.2e} m")
    print(f"  rotor thrust: [{m['thrust_min_n']:.2f}, {m['thrust_max_n']:.2f}] N, saturated "
          f"{100 * m['saturated_fraction']:.1f} % of ticks; max |yaw rate| "
          f"{m['max_yaw_rate_radps']:.1f} rad/s")
    if m.get("attack_min_n") is not None:
        print(f"  attack on rotor {m['attack_rotor']}: [{m['attack_min_n']:.2f}, "
              f"{m['attack_max_n']:.2f}] N")
    for f in m.get("plots", []):
        print(f"  wrote {f}")
