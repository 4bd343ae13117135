"""``tfl-mav scenarios``: list the built-in scenarios, or check a scenario file."""

from __future__ import annotations

import argparse
import json
import sys

from tfl_mav.scenario import ScenarioError, builtin_scenarios, load_scenario

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "scenarios", help="list built-in scenarios, or validate and show one",
        description="Without arguments, list the built-in scenarios. With SCENARIO (a name or a "
                    ".toml path), validate it and print the fully resolved scenario as JSON.")
    p.add_argument("scenario", nargs="?", help="built-in name or path to a .toml file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not args.scenario:
        for name, desc in builtin_scenarios().items():
            print(f"{name:16s} {desc}")
        return 0
    try:
        sc = load_scenario(args.scenario)
        from tfl_mav.from_scenario import scenario_path

        scenario_path(sc)  # validates the path keys too
    except ScenarioError as exc:
        print(f"tfl-mav scenarios: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(sc.to_dict(), indent=2))
    return 0
