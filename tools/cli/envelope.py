"""``tfl-mav envelope``: fly the envelope spec and compare it with the committed baseline.

The guard on the flight envelope: every case of ``tools/harness/envelope/cases.toml`` flown
offline (attack found from rpm), judged against ``tools/harness/envelope/baseline.json`` by
:func:`tfl_mav.tools.harness.envelope.regression.judge`. ``--rewrite-baseline`` is the only way the
baseline changes, and it prints the before/after table that goes with the change.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import subprocess
import sys
from pathlib import Path

from tfl_mav.tools.harness.envelope.laws import (
    LAWS_BEGIN,
    LAWS_END,
    judge_laws,
    law_runs,
    laws_json,
    laws_markdown,
)
from tfl_mav.tools.harness.envelope.regression import judge
from tfl_mav.tools.harness.envelope.report import (
    columns_table,
    diff_table,
    markdown,
    readme_block,
    replace_readme_block,
    run_table,
)
from tfl_mav.tools.harness.envelope.results import (
    ERROR,
    ResultsFile,
    default_baseline_path,
    read_results_file,
    reference_files,
    write_results_file,
)
from tfl_mav.tools.harness.envelope.run import default_jobs, fly_cases, print_progress
from tfl_mav.tools.harness.envelope.spec import EnvelopeSpec, EnvelopeSpecError, load_envelope

__all__ = ["add_parser", "run"]

EXIT_REGRESSION = 1
EXIT_USAGE = 2
REPO = Path(__file__).resolve().parents[2]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "envelope", help="fly the envelope spec and fail on a regression against the baseline",
        description="Fly every case of the envelope spec (tools/harness/envelope/cases.toml) "
                    "offline, the attack found from ESC rpm, and compare each with the "
                    "committed baseline: a case regresses when it crashes and the baseline "
                    "did not, detects another rotor, or ends more than max(10 %, 0.05 mm) "
                    "further from the path over the last 10 s. Progress goes to stderr, the "
                    "table to stdout.",
        epilog="Exit codes: 0 no regression, 1 a regression (or a flight error), 2 usage or "
               "spec error; with --laws 0 whatever the verdicts (a comparison, not the "
               "guard), 1 only when a flight failed to run. Examples: `tfl-mav envelope "
               "--only 'paper-lag*'`; `tfl-mav envelope --rewrite-baseline` (then commit "
               "baseline.json with the printed table); `tfl-mav envelope --markdown "
               "--write-readme`; `tfl-mav envelope --laws --only 'seam-*' --write-readme`.")
    p.add_argument("--only", metavar="GLOB",
                   help="fly only the cases whose name matches the shell glob, e.g. 'dead-*'")
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help=f"flights at a time (default: the CPU count, {default_jobs()} here)")
    p.add_argument("--json", action="store_true",
                   help="print the results and verdicts as one JSON object")
    p.add_argument("--rewrite-baseline", action="store_true",
                   help="fly, then rewrite the baseline with what was flown (with --only: "
                        "those cases only) and print the before/after table")
    p.add_argument("--compare", action="store_true",
                   help="print the committed reference column(s) beside the baseline, case "
                        "by case (no flights)")
    p.add_argument("--laws", action="store_true",
                   help="fly each selected case three ways (controller.supervisor = auto, "
                        "tfl, safe) and print the supervisor against the better single law "
                        "by the same max(10 %%, 0.05 mm) rule, its law switches and time in "
                        "the safe law (no baseline; exit 0 unless a flight fails to run)")
    p.add_argument("--markdown", action="store_true",
                   help="print the README envelope table from the baseline (no flights)")
    p.add_argument("--write-readme", action="store_true",
                   help="with --markdown: write the families between the README's envelope "
                        "markers and every case between docs/envelope.md's; with --laws: "
                        "write the table between docs/envelope.md's laws markers")
    p.add_argument("--fly-reference", metavar="TREE",
                   help="fly the spec with another checkout's own `tfl-mav offline` (its "
                        ".venv) and write reference-LABEL.json next to the baseline")
    p.add_argument("--label", metavar="LABEL",
                   help="with --fly-reference: the tree's name in the table (default: its "
                        "short commit)")
    p.add_argument("--spec", metavar="FILE", help="another spec file (default: the packaged)")
    p.add_argument("--baseline", metavar="FILE",
                   help=f"another baseline file (default: {_rel(default_baseline_path())})")
    p.add_argument("--readme", metavar="FILE", default=str(REPO / "README.md"),
                   help="with --write-readme: the README to update (default: the repo's)")
    p.set_defaults(func=run)


def _rel(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(REPO))
    except ValueError:
        return str(path)


def _tree_name(path: Path) -> str:
    """The short commit of the checkout at ``path``, ``+dirty`` when its code differs from
    it (docs and the envelope's own result files do not count), for the files' ``tree``."""
    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(path), *args], capture_output=True,
                              text=True, check=False).stdout.strip()
    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    dirty = git("status", "--porcelain", "--untracked-files=no", "--", "*.py", "*.toml",
                "*.c", ":(exclude)tools/harness/envelope/*")
    return commit + ("+dirty" if dirty else "")


def _usage_error(args: argparse.Namespace) -> str | None:
    """The one-line complaint about a combination of options, or None."""
    if args.laws:
        clash = [f"--{name.replace('_', '-')}" for name in
                 ("rewrite_baseline", "compare", "markdown", "fly_reference")
                 if getattr(args, name)]
        if clash:
            return f"--laws cannot be combined with {' or '.join(clash)}"
    elif args.write_readme and not args.markdown:
        return "--write-readme needs --markdown or --laws"
    return None


def run(args: argparse.Namespace) -> int:
    problem = _usage_error(args)
    if problem:
        print(f"tfl-mav envelope: {problem}", file=sys.stderr)
        return EXIT_USAGE
    if args.jobs is not None and args.jobs < 1:
        print(f"tfl-mav envelope: --jobs must be >= 1, got {args.jobs}", file=sys.stderr)
        return EXIT_USAGE
    try:
        spec = load_envelope(args.spec)
    except EnvelopeSpecError as exc:
        print(f"tfl-mav envelope: spec error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    baseline_path = Path(args.baseline) if args.baseline else default_baseline_path()
    baseline = read_results_file(baseline_path)
    references = [read_results_file(p) for p in reference_files(baseline_path.parent)]
    if args.markdown:
        return _markdown(args, spec, baseline, references)
    cases = spec.select(args.only)
    if not cases:
        print(f"tfl-mav envelope: no case matches {args.only!r}", file=sys.stderr)
        return EXIT_USAGE
    if args.compare:
        shown = dataclasses.replace(baseline, tree=f"baseline ({baseline.tree or '?'})")
        print(columns_table(cases, [*references, shown]))
        return 0
    if args.fly_reference:
        return _fly_reference(args, spec, cases, baseline_path)
    if args.laws:
        return _laws(args, cases)
    print(f"flying {len(cases)} cases, {args.jobs or default_jobs()} at a time",
          file=sys.stderr)
    now = fly_cases(cases, jobs=args.jobs, on_result=print_progress)
    if args.rewrite_baseline:
        return _rewrite(spec, cases, now, baseline, baseline_path)
    verdicts = {c.name: judge(now[c.name], baseline.get(c.name)) for c in cases}
    failed = [n for n, v in verdicts.items() if v.failed]
    improved = [n for n, v in verdicts.items() if v.status == "improved"]
    if args.json:
        out = {"baseline": _rel(baseline_path), "regressions": failed, "improved": improved,
               "cases": [{"name": c.name, "family": c.family, **now[c.name].to_json(),
                          "wall_time_s": now[c.name].wall_time_s,
                          "verdict": verdicts[c.name].status,
                          "reasons": list(verdicts[c.name].reasons),
                          **{f"reference_{rf.tree}": (rf.get(c.name).to_json()
                                                      if rf.get(c.name) else None)
                             for rf in references}}
                         for c in cases]}
        print(json.dumps(out, indent=2))
    else:
        print(run_table(cases, now, verdicts, references))
        print(f"\n{len(cases)} cases: {len(failed)} regressed, {len(improved)} improved "
              f"(baseline {_rel(baseline_path)}, flown at {baseline.tree or '?'})")
        if failed:
            print("regressed: " + ", ".join(failed))
    return EXIT_REGRESSION if failed else 0


def _rewrite(spec: EnvelopeSpec, cases: list, now: dict, baseline: ResultsFile,
             path: Path) -> int:
    errors = {n: r for n, r in now.items() if r.outcome == ERROR}
    flown = {n: r for n, r in now.items() if n not in errors}
    names = {c.name for c in spec.cases}
    merged = {n: r for n, r in baseline.results.items() if n in names}
    merged.update(flown)
    rf = ResultsFile(tree=_tree_name(REPO), about=(
        "tfl-mav envelope --rewrite-baseline: each case of cases.toml flown offline, the "
        "attack found from ESC rpm (tfl-mav offline BASE --set ... --attack-info detector); "
        "distances in m over the last 10 s"), results=merged)
    write_results_file(path, rf, [c.name for c in spec.cases])
    print(diff_table(cases, baseline, flown, names))
    print(f"\nwrote {_rel(path)} ({len(flown)} cases flown at {rf.tree}; command: tfl-mav "
          f"envelope --rewrite-baseline)")
    for n, r in errors.items():
        print(f"tfl-mav envelope: {n}: the flight failed to run ({r.reason}); its baseline "
              f"entry is left as it was", file=sys.stderr)
    return EXIT_REGRESSION if errors else 0


def _fly_reference(args: argparse.Namespace, spec: EnvelopeSpec, cases: list,
                   baseline_path: Path) -> int:
    from tfl_mav.tools.harness.envelope.reference import fly_reference

    tree = Path(args.fly_reference).resolve()
    label = args.label or _tree_name(tree)
    try:
        results = fly_reference(tree, cases, jobs=args.jobs or default_jobs(),
                                on_result=print_progress)
    except FileNotFoundError as exc:
        print(f"tfl-mav envelope: {exc}", file=sys.stderr)
        return EXIT_USAGE
    path = baseline_path.parent / f"reference-{label}.json"
    old = read_results_file(path)
    merged = {**{n: r for n, r in old.results.items() if any(c.name == n
                                                              for c in spec.cases)},
              **results}
    rf = ResultsFile(tree=label, about=(
        f"the envelope flown by the tree at {label} with its own CLI: `tfl-mav offline BASE "
        "--set ... --attack-info detector --json` per case (n/a: that tree lacks a key, "
        "path or signal; detection unknown where its JSON has none)"), results=merged)
    write_results_file(path, rf, [c.name for c in spec.cases])
    print(f"wrote {_rel(path)} ({len(results)} cases)")
    return 0


def _markdown(args: argparse.Namespace, spec: EnvelopeSpec, baseline: ResultsFile,
              references: list[ResultsFile]) -> int:
    if not baseline.results:
        print("tfl-mav envelope: the baseline is empty: fly --rewrite-baseline first",
              file=sys.stderr)
        return EXIT_USAGE
    if not args.write_readme:
        print(markdown(spec, baseline, references), end="")
        return 0
    readme = Path(args.readme)
    targets = [(readme, markdown(spec, baseline, references, every_case=False)),
               (readme.parent / "docs" / "envelope.md", markdown(spec, baseline, references))]
    for path, block in targets:
        try:
            changed = replace_readme_block(path, block)
        except (OSError, ValueError) as exc:
            print(f"tfl-mav envelope: {path}: {exc}", file=sys.stderr)
            return EXIT_USAGE
        print(f"{'updated' if changed else 'unchanged'}: {path}")
    return 0


def _laws(args: argparse.Namespace, cases: list) -> int:
    doc = Path(args.readme).parent / "docs" / "envelope.md"
    if args.write_readme:   # before the flights, not after them
        try:
            readme_block(doc.read_text(encoding="utf-8"), (LAWS_BEGIN, LAWS_END))
        except (OSError, ValueError) as exc:
            print(f"tfl-mav envelope: {doc}: {exc}", file=sys.stderr)
            return EXIT_USAGE
    runs = law_runs(cases)
    print(f"flying {len(cases)} cases three ways ({len(runs)} flights), "
          f"{args.jobs or default_jobs()} at a time", file=sys.stderr)
    flown = fly_cases(runs, jobs=args.jobs, on_result=print_progress)
    errors = [r for r in flown.values() if r.outcome == ERROR]
    verdicts = [judge_laws(c, flown) for c in cases]
    if args.json:
        print(json.dumps(laws_json(cases, flown), indent=2))
    else:
        print(laws_markdown(verdicts), end="")
    for r in errors:
        print(f"tfl-mav envelope: {r.name}: the flight failed to run ({r.reason})",
              file=sys.stderr)
    if errors:
        if args.write_readme:
            print(f"tfl-mav envelope: {doc} left as it was (a flight failed)",
                  file=sys.stderr)
        return EXIT_REGRESSION
    if args.write_readme:
        only = f" --only {shlex.quote(args.only)}" if args.only else ""
        block = laws_markdown(verdicts, command=f"tfl-mav envelope --laws{only} --write-readme")
        try:
            changed = replace_readme_block(doc, block, (LAWS_BEGIN, LAWS_END))
        except (OSError, ValueError) as exc:
            print(f"tfl-mav envelope: {doc}: {exc}", file=sys.stderr)
            return EXIT_USAGE
        print(f"{'updated' if changed else 'unchanged'}: {doc}", file=sys.stderr)
    return 0
