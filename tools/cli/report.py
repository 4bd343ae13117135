"""``tfl-mav report RUN.mcap --out DIR``: the report PNGs of a flight, from its log alone.

The scenario comes from the log's ``scenario`` metadata (written by ``tfl-mav sim --mcap``)
unless ``--scenario`` overrides it; ``ctl.mcap`` next to the log (or ``--ctl``) adds the
controller's commands, mode and attack estimate. DIR gets the six PNGs and
``summary.json`` (the flight summary ``--json`` prints).

Exit codes: 0 the report was written (whatever the flight did: ``inspect`` and the
summary say how it went); 2 the input is not a vehicle log (a controller log, no scenario);
3 the log cannot be read or DIR cannot be written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from tfl_mav.flightlog.flight import summarize
from tfl_mav.flightlog.from_mcap import load_flight, scenario_from_log
from tfl_mav.scenario import ScenarioError, load_scenario
from tfl_mav.tools.cli.outputs import EXIT_IO, dir_problem

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="write the report PNGs of a recorded flight",
                       description=__doc__.split("\n\n")[0].split(": ", 1)[1],
                       epilog=__doc__.split("\n\n")[2].replace("\n", " "))
    p.add_argument("log", metavar="RUN.mcap", help="the vehicle's log (tfl-mav sim --mcap)")
    p.add_argument("--out", required=True, metavar="DIR", help="where to write the PNGs")
    p.add_argument("--ctl", metavar="CTL.mcap",
                   help="the controller's log (default: ctl.mcap next to RUN.mcap, if any)")
    p.add_argument("--scenario", help="scenario name or file (default: from the log)")
    p.add_argument("--json", action="store_true", help="print the flight summary as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    log_path = Path(args.log)
    if not log_path.exists():
        print(f"tfl-mav report: {log_path}: no such file", file=sys.stderr)
        return 3
    problem = dir_problem(args.out, "--out")
    if problem:
        print(f"tfl-mav report: {problem}", file=sys.stderr)
        return EXIT_IO
    try:
        sc = load_scenario(args.scenario) if args.scenario else scenario_from_log(log_path)
    except (ScenarioError, OSError, ValueError) as exc:
        print(f"tfl-mav report: {exc}", file=sys.stderr)
        return 2
    from tfl_mav.flightlog.plots import write_report  # matplotlib: ~1 s, only here

    try:
        log, sc = load_flight(log_path, sc, args.ctl)
    except OSError as exc:
        print(f"tfl-mav report: {exc}", file=sys.stderr)
        return EXIT_IO
    if len(log["t_s"]) == 0:
        print(f"tfl-mav report: {log_path} has no vehicle truth (/sim/truth/*) to plot: "
              "report needs the vehicle's log (tfl-mav sim --mcap, run.mcap); "
              f"`tfl-mav inspect {log_path}` summarises a controller log", file=sys.stderr)
        return 2
    out = Path(args.out)
    files = write_report(log, out, title=sc.name)
    m = {**summarize(log), "plots": [str(f) for f in files]}
    summary = out / "summary.json"
    summary.write_text(json.dumps(m, indent=2) + "\n", encoding="utf-8")
    if args.json:
        print(json.dumps(m, indent=2))
    else:
        print(f"tfl-mav report: {len(files)} figures and {summary.name} in {out}/ "
              f"({m['sim_time_s']:.1f} s of flight; {m['convergence']})")
    return 0
