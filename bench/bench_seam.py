"""The seam between the laws: every case of an envelope family flown three ways — the
supervisor (``auto``), TFL alone and the safe law alone — side by side.

    python bench/bench_seam.py [--family seam] [--only GLOB] [--jobs N] [--json FILE]

Each case is the envelope's (``tools/harness/envelope/cases.toml``: ``tfl-mav offline BASE
--set ... --attack-info detector``) with ``controller.supervisor`` set to each mode. The
table shows the max distance to the path over the last 10 s (``crash`` where the vehicle was
lost), the switches between the laws and the share of the flight the safe law flew, and
whether the supervised flight is within the house rule (max(10 %, 0.05 mm)) of the better
single-law flight: ``ok``, or ``worse`` with the margin.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from tfl_mav.tools.harness.envelope.run import fly_cases
from tfl_mav.tools.harness.envelope.spec import Case, load_envelope

MODES = ("auto", "tfl", "safe")


def _distance(r) -> float:
    """The max distance over the last 10 s (m); inf for a crash or no number."""
    if r.outcome in ("crashed", "error", "n/a") or r.max_distance_m is None:
        return float("inf")
    return float(r.max_distance_m)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--family", default="seam", help="the envelope family (default: seam)")
    ap.add_argument("--only", help="only the cases whose name matches this shell glob")
    ap.add_argument("--jobs", type=int, default=None, help="flights at a time (default: cores)")
    ap.add_argument("--json", type=Path, help="write every result to this file")
    args = ap.parse_args()
    spec = load_envelope()
    cases = [c for c in spec.select(args.only) if c.family == args.family]
    if not cases:
        print(f"bench_seam: no case of family {args.family!r} matches", file=sys.stderr)
        return 2
    runs = [Case(f"{c.name}@{mode}", c.family, c.base,
                 (*c.settings, f"controller.supervisor={mode}")) for c in cases for mode in MODES]

    def progress(i: int, n: int, r) -> None:
        print(f"\r  {i}/{n} flights", end="", file=sys.stderr, flush=True)

    results = fly_cases(runs, jobs=args.jobs, on_result=progress)
    print(file=sys.stderr)
    print("| case | auto (mm) | switches | safe law | TFL alone (mm) | safe alone (mm) | rule |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | --- |")
    rows = []
    bad = 0
    for c in cases:
        r = {m: results[f"{c.name}@{m}"] for m in MODES}
        d = {m: _distance(r[m]) for m in MODES}
        best = min(d["tfl"], d["safe"])
        limit = best + max(0.1 * best, 5e-5)
        ok = d["auto"] <= limit
        bad += not ok
        frac = r["auto"].mode_fraction
        safe = frac.get("lost_rotor", 0.0) + frac.get("recovery", 0.0)

        def mm(x: float) -> str:
            return "crash" if x == float("inf") else f"{x * 1e3:.3f}"
        switches = r["auto"].law_switches
        rule = "ok" if ok else f"worse by {mm(d['auto'] - best)} mm"
        print(f"| {c.name} | {mm(d['auto'])} | {switches} | {100 * safe:.0f} % | "
              f"{mm(d['tfl'])} | {mm(d['safe'])} | {rule} |")
        rows.append({"case": c.name, **{f"{m}_m": (None if d[m] == float("inf") else d[m])
                                        for m in MODES},
                     "safe_fraction": safe, "within_rule": ok})
    print(f"\n{len(cases) - bad} of {len(cases)} supervised flights within max(10 %, 0.05 mm) "
          "of the better single law")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
