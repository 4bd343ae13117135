"""The ``tfl-mav`` command: one entry point, one subcommand per job.

Exit codes (all subcommands): 0 success; 1 the flight failed (vehicle crashed, or a check
did not pass); 2 usage or scenario error; 3 link or I/O error (port in use, unwritable file,
a peer process died); 130/143 interrupted (SIGINT/SIGTERM); 141 the reader of the output
went away (``tfl-mav inspect run.mcap | head``: as a process killed by SIGPIPE, silent).
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys

from tfl_mav import __version__

EXIT_BROKEN_PIPE = 128 + signal.SIGPIPE

# Command → the module that adds it. Each module has add_parser(subparsers) and its own run
# function. Only the invoked command's module is imported (each pulls in what its command
# needs: a daemon, pymavlink, MCAP, plotting), so `tfl-mav offline` does not pay for the
# link stack at start-up; --help and an unknown command import them all to list them.
SUBCOMMANDS = {
    "demo": "tfl_mav.tools.cli.demo",
    "sim": "tfl_mav.tools.cli.sim",
    "fly": "tfl_mav.tools.cli.fly",
    "offline": "tfl_mav.tools.cli.offline",
    "inspect": "tfl_mav.tools.cli.inspect_cmd",
    "report": "tfl_mav.tools.cli.report",
    "replay": "tfl_mav.tools.cli.replay",
    "scenarios": "tfl_mav.tools.cli.scenarios_cmd",
    "relay": "tfl_mav.tools.cli.relay",
    "campaign": "tfl_mav.tools.cli.campaign",
    "envelope": "tfl_mav.tools.cli.envelope",
    "compare": "tfl_mav.tools.cli.compare",
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole CLI's parser; with a known ``command``, only that subcommand is added."""
    parser = argparse.ArgumentParser(
        prog="tfl-mav",
        description="Fly a quadrotor along a 3-D path while an attacker controls one rotor: "
                    "a MAVLink SITL vehicle, the TFL offboard controller, and tools around a "
                    "flight. Start with `tfl-mav demo`.",
        epilog="Exit codes: 0 ok, 1 flight failed, 2 usage/scenario error, 3 link/I-O error "
               "(or a peer process died), 130/143 interrupted (SIGINT/SIGTERM), 141 the "
               "output's reader went away (| head).")
    parser.add_argument("--version", action="version", version=f"tfl-mav {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    names = [SUBCOMMANDS[command]] if command in SUBCOMMANDS else SUBCOMMANDS.values()
    for name in names:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue  # subcommand not part of this build
            raise
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    command = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(command)
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("tfl-mav: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader closed the pipe (`| head`): nothing to say, and nothing may be said at
        # exit either (the interpreter's last flush of stdout would fail again), so stdout
        # goes to /dev/null (the Python docs' recipe, "Note on SIGPIPE").
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_BROKEN_PIPE


if __name__ == "__main__":
    sys.exit(main())
