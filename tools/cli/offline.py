"""``tfl-mav offline``: fly a scenario in-process (sitl physics, no network).

The controller runs at ``control_hz`` with a zero-order hold on the sitl physics, seeing the
measured state (with the scenario's sensor noise). How it learns about the attack is chosen
by ``attack_info``:

* ``"oracle"`` — the paper's assumption: once the attack starts the controller is told
  which rotor and that rotor's thrust as measured from its rpm (``f = k_f ω²``);
* ``"detector"`` — it must find the attack itself from ESC rpm
  (:mod:`tfl_mav.control.detect.detector`), as the daemon does.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from tfl_mav.controller.feasibility import check_scenario
from tfl_mav.flightlog.flight import summarize
from tfl_mav.from_scenario import scenario_path
from tfl_mav.offline import fly_offline
from tfl_mav.scenario import Scenario, ScenarioError, apply_overrides, load_scenario
from tfl_mav.tools.cli.args import duration_s
from tfl_mav.tools.cli.outputs import EXIT_IO, dir_problem

__all__ = ["add_parser", "run"]

def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "offline", help="fly a scenario in-process (no network) and print metrics",
        description="Fly SCENARIO with the TFL controller on the sitl physics in one process "
                    "(no network): fast, deterministic, for studying the control law.")
    p.add_argument("scenario", nargs="?", default="paper",
                   help="built-in scenario name or path to a .toml file (default: paper)")
    p.add_argument("--json", action="store_true", help="print one JSON object of metrics")
    p.add_argument("--plot", metavar="DIR", help="write the report PNGs into DIR")
    p.add_argument("--duration", type=duration_s, metavar="S", help="override run.duration_s")
    p.add_argument("--attack-info", choices=("oracle", "detector"), default="oracle",
                   help="how the controller learns of the attack: told (paper's assumption, "
                        "default) or detected from ESC rpm")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario key, e.g. --set controller.law=paper "
                        "(TOML value syntax; repeatable)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        sc = apply_overrides(load_scenario(args.scenario), args.set)
        scenario_path(sc)            # a bad path is a scenario error, found before flying
    except (ScenarioError, TypeError) as exc:
        print(f"tfl-mav offline: scenario error: {exc}", file=sys.stderr)
        return 2
    if args.plot and (problem := dir_problem(args.plot, "--plot")):
        print(f"tfl-mav offline: {problem}", file=sys.stderr)
        return EXIT_IO
    for warning in check_scenario(sc):
        print(f"tfl-mav offline: warning: {warning}", file=sys.stderr)

    def progress(t: float, total: float) -> None:
        if not args.json and sys.stderr.isatty():
            print(f"\r  t = {t:5.1f} / {total:.1f} s", end="", file=sys.stderr, flush=True)

    log = fly_offline(sc, attack_info=args.attack_info, progress=progress,
                      duration_s=args.duration)
    if not args.json and sys.stderr.isatty():
        print(file=sys.stderr)
    metrics = summarize(log)
    if args.plot:
        from tfl_mav.flightlog.plots import write_report

        files = write_report(log, Path(args.plot), title=sc.name)
        metrics["plots"] = [str(f) for f in files]
    if args.json:
        for _t, text in log.events:   # said on stderr too: --json prints no events
            if text.startswith("attack.signal"):
                print(f"tfl-mav offline: warning: {text}", file=sys.stderr)
        print(json.dumps(metrics, indent=2))
    else:
        # What the flight computer said during the flight (law switches, detections), in
        # sim-time order: the daemon sends the same words as STATUSTEXT.
        for t_s, text in sorted(e for e in log.events if not e[1].startswith("fallbacks:")):
            print(f"  t = {t_s:6.2f} s  {text}")
        _print_summary(sc, metrics)
    return 1 if log.crashed else 0


def _print_summary(sc: Scenario, m: dict) -> None:
    status = f"CRASHED: {m['crash_reason']}" if m["crashed"] else "flew the whole run"
    print(f"{sc.name}: {status} ({m['sim_time_s']:.1f} s sim in {m['wall_time_s']:.1f} s wall)")
    if m.get("final_path_distance_m") is not None:
        def e(x: float | None) -> str:   # None: not finite somewhere in the window
            return f"{x:.2e} m" if x is not None else "- (not finite in the window)"
        span = "the whole flight" if m["sim_time_s"] <= 10.0 else "the last 10 s"
        print(f"  path distance: final {e(m['final_path_distance_m'])}; over {span} max "
              f"{e(m['max_path_distance_last_10s_m'])}, "
              f"rms {e(m['rms_path_distance_last_10s_m'])}")
    print(f"  rotor thrust: [{m['thrust_min_n']:.2f}, {m['thrust_max_n']:.2f}] N, saturated "
          f"{100 * m['saturated_fraction']:.1f} % of ticks; max |yaw rate| "
          f"{m['max_yaw_rate_radps']:.1f} rad/s")
    if m.get("attack_min_n") is not None:
        print(f"  attack on rotor {m['attack_rotor']}: [{m['attack_min_n']:.2f}, "
              f"{m['attack_max_n']:.2f}] N")
    for f in m.get("plots", []):
        print(f"  wrote {f}")
