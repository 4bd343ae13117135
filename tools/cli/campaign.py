"""``tfl-mav campaign``: many seeded flights over swept scenario keys, as one table.

``tfl-mav campaign SPEC --out DIR`` flies every run of SPEC (a built-in spec name or a TOML
file) that DIR does not have yet, on this machine's cores (``--executor local``) or on Ray
(``--executor ray``, ``--ray-address`` to join a cluster), writing DIR/results.csv,
DIR/summary.json and the report (report.md, map_*.png). ``tfl-mav campaign report DIR``
redraws the report from DIR/results.csv alone.
"""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path
from typing import Any

from tfl_mav.tools.cli.outputs import EXIT_IO, dir_problem

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    from tfl_mav.tools.harness.campaign.spec import builtin_specs

    p = sub.add_parser(
        "campaign", help="fly a campaign of seeded runs over swept keys (or: report DIR)",
        description=__doc__.split("\n\n")[1].replace("\n", " "),
        epilog="Built-in specs: " + "; ".join(f"{k}: {v}" for k, v in builtin_specs().items())
               + ". Exit codes: 0 ok, 2 spec/usage error, 3 I/O or executor error.")
    p.add_argument("spec", metavar="SPEC", help="built-in spec name or .toml path; or "
                                                "`report` to redraw DIR's report")
    p.add_argument("dir", nargs="?", metavar="DIR", help="with `report`: the campaign "
                                                         "directory")
    p.add_argument("--out", metavar="DIR", help="campaign directory (resumed if it exists)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="runs at a time (default: this machine's cores; ray: cluster CPUs)")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="local: forked processes (default); ray: Ray tasks")
    p.add_argument("--ray-address", metavar="ADDR",
                   help="join this Ray cluster (default: start a local Ray instance)")
    p.add_argument("--quiet", action="store_true", help="no progress line, no report table")
    p.set_defaults(func=run)


def _err(message: str) -> None:
    print(f"tfl-mav campaign: {message}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    if args.spec == "report":
        return _report(args)
    from tfl_mav.tools.harness.campaign import (
        CampaignDirError,
        ExecutorError,
        SpecError,
        load_spec,
        run_campaign,
    )

    if args.dir is not None:
        _err(f"unexpected argument {args.dir!r} (the campaign directory is --out DIR)")
        return 2
    if not args.out:
        _err("--out DIR is required")
        return 2
    if args.workers is not None and args.workers < 1:
        _err(f"--workers: must be >= 1, got {args.workers}")
        return 2
    if args.ray_address and args.executor != "ray":
        _err("--ray-address needs --executor ray")
        return 2
    try:
        spec = load_spec(args.spec)
    except SpecError as exc:
        _err(f"spec error: {exc}")
        return 2
    problem = dir_problem(args.out, "--out")
    if problem:
        _err(problem)
        return EXIT_IO
    signals: list[int] = []

    def on_term(signum: int, _frame: Any) -> None:
        # SIGTERM stops as Ctrl-C does, asked for between waits (within 0.25 s) rather than
        # raised from here: an exception raised in a signal handler that lands in a fork's
        # at-fork callback is printed and dropped, and the campaign flew on to its end.
        signals.append(signum)

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        summary = run_campaign(spec, Path(args.out), executor=args.executor,
                               workers=args.workers, ray_address=args.ray_address,
                               progress=not args.quiet, stop=lambda: bool(signals))
    except (CampaignDirError, SpecError) as exc:
        _err(str(exc))
        return 2
    except (ExecutorError, OSError) as exc:
        _err(f"{exc.strerror or exc}: {exc.filename}" if isinstance(exc, OSError)
             and exc.filename else str(exc))
        return 3
    finally:
        signal.signal(signal.SIGTERM, previous)
    out = str(args.out).rstrip("/") or "/"
    if not args.quiet:
        print((Path(out) / "report.md").read_text(encoding="utf-8"))
    how = (f"INTERRUPTED after {summary['flown_now']} runs this session "
           f"({summary['not_flown']} not flown; the same command resumes)"
           if summary["interrupted"] else f"flew {summary['flown_now']} now")
    print(f"{summary['name']}: {summary['runs']} runs, {summary['succeeded']} succeeded, "
          f"{summary['failed']} failed; {how} in {summary['wall_time_s']:.1f} s "
          f"({summary['executor']}); files in {out}/")
    if summary["interrupted"]:
        return 128 + (signals[0] if signals else signal.SIGINT)
    return 0


def _report(args: argparse.Namespace) -> int:
    from tfl_mav.tools.harness.campaign.report import write_report

    if not args.dir:
        _err("usage: tfl-mav campaign report DIR")
        return 2
    out = Path(args.dir)
    if not (out / "results.csv").is_file():
        _err(f"{out}/results.csv: no such file")
        return 3
    try:
        files = write_report(out)
    except OSError as exc:
        _err(str(exc))
        return 3
    print((out / "report.md").read_text(encoding="utf-8"))
    for f in files:
        print(f"wrote {f}")
    return 0
