"""The ``tfl-mav`` command: one entry point, one subcommand per job.

Exit codes (all subcommands): 0 success; 1 the flight failed (vehicle crashed, or a check
did not pass); 2 usage or scenario error; 3 link or I/O error (port in use, unwritable file).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from tfl_mav import __version__

# (module, what it adds). Each module has add_parser(subparsers) and its own run function.
SUBCOMMANDS = (
    "tools.demo",
    "tools.sim",
    "tools.fly",
    "tools.offline",
    "tools.inspect_cmd",
    "tools.report",
    "tools.replay",
    "tools.scenarios_cmd",
    "tools.relay",
    "tools.campaign",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tfl-mav",
        description="Fly a quadrotor along a 3-D path while an attacker controls one rotor: "
                    "a MAVLink SITL vehicle, the TFL offboard controller, and tools around a "
                    "flight. Start with `tfl-mav demo`.",
        epilog="Exit codes: 0 ok, 1 flight failed, 2 usage/scenario error, 3 link/I-O error.")
    parser.add_argument("--version", action="version", version=f"tfl-mav {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue  # subcommand not part of this build
            raise
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("tfl-mav: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
