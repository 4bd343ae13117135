"""``tfl-mav compare``: controllers side by side on one scenario (:mod:`tfl_mav.comparison`).

Exit codes: 0 the comparison was made (whatever flew or crashed), 2 usage or scenario error
(an unknown controller among them), 3 the output directory is unusable.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from tfl_mav.scenario import ScenarioError, apply_overrides, load_scenario
from tfl_mav.tools.cli.args import duration_s
from tfl_mav.tools.cli.outputs import EXIT_IO, dir_problem

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compare", help="fly TFL and baseline controllers on the same scenario and seeds",
        description="Fly SCENARIO with each controller (offline, lockstep physics), the "
                    "attack found from ESC rpm by all; print one table, write a plot of "
                    "path distance vs time and a CSV.")
    p.add_argument("scenario", nargs="?", default="paper",
                   help="built-in scenario name or .toml path (default: paper)")
    p.add_argument("--controllers", default="tfl,se3,cascade", metavar="A,B,...",
                   help="comma-separated: tfl, se3, cascade, MODULE:NAME or FILE.py:NAME "
                        "(default: tfl,se3,cascade)")
    p.add_argument("--seeds", type=int, default=1, metavar="N",
                   help="fly seeds run.seed, run.seed+1, ... (N of them; default 1)")
    p.add_argument("--duration", type=duration_s, metavar="S", help="override run.duration_s")
    p.add_argument("--on-path", type=float, default=0.05, metavar="M",
                   help="'on the path' means within M metres (default 0.05)")
    p.add_argument("--out", default="tfl-mav-compare", metavar="DIR",
                   help="write compare.csv and compare.png here (default ./tfl-mav-compare)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario key (TOML value), repeatable")
    p.add_argument("--family", metavar="NAME",
                   help="fly every case of this envelope family instead of SCENARIO (one "
                        "table a case), e.g. pinned-high: a rotor pinned above m g/2, where "
                        "no attitude hold exists (TFL's spin law against SE(3) and the "
                        "cascade: crash, max distance after 5 s, escape = the distance at "
                        "the end)")
    p.set_defaults(func=run)


def _family_cases(name: str) -> list[tuple[str, object]]:
    """(case name, scenario) of the envelope family ``name``; ValueError if unknown."""
    from tfl_mav.tools.harness.envelope.spec import case_scenario, load_envelope

    spec = load_envelope()
    cases = [c for c in spec.cases if c.family == name]
    if not cases:
        raise ValueError(f"--family: no envelope family {name!r} (one of "
                         f"{', '.join(f.name for f in spec.families)})")
    return [(c.name, case_scenario(c)) for c in cases]


def run(args: argparse.Namespace) -> int:
    prog = "tfl-mav compare"
    from tfl_mav.comparison import check_controllers
    from tfl_mav.controller.software import FlightSoftwareError

    names = [n.strip() for n in args.controllers.split(",") if n.strip()]
    try:
        if args.family:
            flights = [(n, apply_overrides(c, args.set))   # type: ignore[arg-type]
                       for n, c in _family_cases(args.family)]
        else:
            flights = [("", apply_overrides(load_scenario(args.scenario), args.set))]
        if not names:
            raise ValueError("--controllers: give at least one")
        if args.seeds < 1:
            raise ValueError(f"--seeds: must be >= 1, got {args.seeds}")
        if args.duration is not None and not args.duration > 0:
            raise ValueError(f"--duration: must be > 0 s, got {args.duration}")
        check_controllers(names)
    except (ScenarioError, FlightSoftwareError, ValueError) as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    if problem := dir_problem(args.out, "--out"):
        print(f"{prog}: {problem}", file=sys.stderr)
        return EXIT_IO
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for case, sc in flights:
        _compare_one(args, names, case, sc, out / case if case else out)
    return 0


def _compare_one(args: argparse.Namespace, names: list[str], case: str, sc: Any,
                 out: Path) -> None:
    """Fly one scenario with every controller; print its table, write its CSV and plot."""
    from tfl_mav.comparison import Result, fly_all, plot, table, write_csv

    seeds = [sc.run.seed + i for i in range(args.seeds)]

    def progress(r: Result) -> None:
        if sys.stderr.isatty():
            print(f"\r  flown: {r.controller} seed {r.seed}   ", end="", file=sys.stderr,
                  flush=True)

    results, first = fly_all(sc, names, seeds, duration_s=args.duration,
                             on_path_m=args.on_path, progress=progress)
    if sys.stderr.isatty():
        print(file=sys.stderr)
    out.mkdir(parents=True, exist_ok=True)
    duration = args.duration if args.duration is not None else sc.run.duration_s
    attack = (f"rotor {sc.attack.rotor} {sc.attack.signal!r} from {sc.attack.start_s:g} s"
              if sc.attack.rotor else "no attack")
    title = f"{case} ({sc.name})" if case else sc.name
    print(f"{title}: {duration:g} s, {attack}, seeds {seeds[0]}..{seeds[-1]}; "
          f"the attack found from rpm by every controller; on path = within {args.on_path:g} m")
    print(table(results))
    write_csv(results, out / "compare.csv")
    plot(first, out / "compare.png", title=sc.name)
    print(f"wrote {out / 'compare.csv'}, {out / 'compare.png'}")
