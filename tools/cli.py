"""The ``tfl-mav`` command: one entry point, one subcommand per job.

Exit codes (all subcommands): 0 success; 1 the flight failed (vehicle crashed, or a check
did not pass); 2 usage or scenario error; 3 link or I/O error (port in use, unwritable file).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from tfl_mav import __version__

# subcommand → module. Each module has add_parser(subparsers) and its own run function.
SUBCOMMANDS = {
    "demo": "tools.demo",
    "sim": "tools.sim",
    "fly": "tools.fly",
    "offline": "tools.offline",
    "inspect": "tools.inspect_cmd",
    "report": "tools.report",
    "replay": "tools.replay",
    "scenarios": "tools.scenarios_cmd",
    "relay": "tools.relay",
    "campaign": "tools.campaign",
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser; ``only``: register just that subcommand (see :func:`main`)."""
    parser = argparse.ArgumentParser(
        prog="tfl-mav",
        description="Fly a quadrotor along a 3-D path while an attacker controls one rotor: "
                    "a MAVLink SITL vehicle, the TFL offboard controller, and tools around a "
                    "flight. Start with `tfl-mav demo`.",
        epilog="Exit codes: 0 ok, 1 flight failed, 2 usage/scenario error, 3 link/I-O error.")
    parser.add_argument("--version", action="version", version=f"tfl-mav {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command, name in SUBCOMMANDS.items():
        if only is not None and command != only:
            continue
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue  # subcommand not part of this build
            raise
        module.add_parser(sub)
    return parser


def _subcommand(argv: list[str]) -> str | None:
    """The subcommand named on the command line, if it is the first argument. Only its
    module is imported then: each pulls in its own stack (the demo imports the simulator,
    the offline harness and matplotlib), and a restarted `fly` must reach its first command
    fast (#12: 0.25 s before a real-time vehicle cuts its motors)."""
    return argv[0] if argv and argv[0] in SUBCOMMANDS else None


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(_subcommand(argv))
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
