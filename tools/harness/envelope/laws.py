"""The seam between the laws: envelope cases flown three ways and the verdict per case.

Each case is flown as the envelope flies it with ``controller.supervisor`` appended: ``auto``
(the supervisor picks TFL or the safe law each tick), ``tfl`` (TFL alone) and ``safe`` (the
safe law alone). The verdict is the house rule applied to the supervisor against the better
single law: the supervised flight's max distance to the path over the last 10 s may exceed
the better single-law flight's by at most max(10 %, 0.05 mm)
(:func:`~tfl_mav.tools.harness.envelope.regression.worse_limit_m`); a crash (or a flight that
did not run) is infinitely far, so a supervisor that flies where a single law crashes is
within the rule, and one that crashes is within it only where both single laws crash too.
Beside it: the supervised flight's law switches and the share of its control ticks flown by
the safe law (modes recovery, lost_rotor, spin). A case outside the rule also shows each
flight's peak after the approach and when (:attr:`CaseResult.peak_distance_m`): the last 10 s
of a path open where they open, and two flights that reach the same bend a few tenths of a
second apart can read differently there while their peaks are the same.

Pure: the runs to fly are :func:`law_runs`, the pool is the envelope's
(:func:`~tfl_mav.tools.harness.envelope.run.fly_cases`); everything from the results on is
computed here without I/O. The command is ``tfl-mav envelope --laws``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from tfl_mav.model.modes import Mode
from tfl_mav.tools.harness.envelope.regression import worse_limit_m
from tfl_mav.tools.harness.envelope.report import fmt_distance, fmt_mm
from tfl_mav.tools.harness.envelope.results import CaseResult
from tfl_mav.tools.harness.envelope.spec import Case

__all__ = ["LAWS", "LAWS_BEGIN", "LAWS_END", "SAFE_LAW_MODES", "FamilySummary", "LawsVerdict",
           "distance_m", "judge_laws", "law_run_name", "law_runs", "laws_json",
           "laws_markdown", "safe_law_share", "summarize", "summary_line"]

LAWS = ("auto", "tfl", "safe")          # controller.supervisor: the supervisor, one law alone
SAFE_LAW_MODES = (str(Mode.RECOVERY), str(Mode.LOST_ROTOR), str(Mode.SPIN))
LAWS_BEGIN = "<!-- laws:begin -->"
LAWS_END = "<!-- laws:end -->"
RULE_TEXT = "max(10 %, 0.05 mm)"


def law_run_name(case_name: str, law: str) -> str:
    """The name of one of a case's three runs: ``seam-onoff-r1-3s@tfl``."""
    return f"{case_name}@{law}"


def law_runs(cases: Sequence[Case]) -> list[Case]:
    """Every case three times, the supervisor setting appended (it overrides the case's own,
    if any, as a later ``--set`` does)."""
    return [Case(law_run_name(c.name, law), c.family, c.base,
                 (*c.settings, f"controller.supervisor={law}"), c.note, c.bound_m)
            for c in cases for law in LAWS]


def distance_m(r: CaseResult | None) -> float:
    """The max distance to the path over the last 10 s (m); ``inf`` for a crash, a flight
    that did not run (error, n/a, missing) or a distance that is not finite."""
    if r is None or r.outcome not in ("converged", "off-path"):
        return math.inf
    d = r.max_distance_m
    return float(d) if d is not None and math.isfinite(d) else math.inf


def safe_law_share(r: CaseResult) -> float:
    """The share of control ticks flown by the safe law (recovery + lost_rotor + spin)."""
    return sum(r.mode_fraction.get(m, 0.0) for m in SAFE_LAW_MODES)


@dataclass(frozen=True)
class LawsVerdict:
    """One case's three flights judged: distances in m (``inf``: crashed or did not run)."""

    case: str
    family: str
    auto_m: float
    tfl_m: float
    safe_m: float
    switches: int | None            # the supervised flight's switches between the laws
    safe_share: float               # the supervised flight's share of ticks in the safe law
    outcomes: tuple[str, str, str]  # auto, tfl, safe
    # each flight's peak after the approach (m) and its time (s), auto, tfl, safe (None:
    # not known: crashed early, or flown by a tree that does not report it)
    peaks: tuple[tuple[float | None, float | None], ...] = ()

    @property
    def best_single_m(self) -> float:
        return min(self.tfl_m, self.safe_m)

    @property
    def best_single_law(self) -> str:
        """``tfl`` or ``safe``: the single law closer over the last 10 s (TFL on a tie)."""
        return "tfl" if self.tfl_m <= self.safe_m else "safe"

    @property
    def within_rule(self) -> bool:
        """The supervisor within max(10 %, 0.05 mm) of the better single law (inf ≤ inf:
        where both single laws crash, nothing is asked of the supervisor)."""
        best = self.best_single_m
        return self.auto_m <= (worse_limit_m(best) if math.isfinite(best) else math.inf)

    @property
    def margin_m(self) -> float:
        """How much further off the supervisor ended than the better single law (m; < 0:
        closer; inf where the supervisor crashed and a single law did not)."""
        if math.isinf(self.auto_m) and math.isinf(self.best_single_m):
            return 0.0
        return self.auto_m - self.best_single_m


def judge_laws(case: Case, flown: Mapping[str, CaseResult]) -> LawsVerdict:
    """The verdict on ``case`` from its three runs in ``flown`` (keyed by
    :func:`law_run_name`; a missing run counts as one that did not fly)."""
    r = {law: flown.get(law_run_name(case.name, law)) for law in LAWS}
    auto = r["auto"]
    return LawsVerdict(
        case=case.name, family=case.family, auto_m=distance_m(auto),
        tfl_m=distance_m(r["tfl"]), safe_m=distance_m(r["safe"]),
        switches=auto.law_switches if auto is not None else None,
        safe_share=safe_law_share(auto) if auto is not None else 0.0,
        outcomes=tuple(x.outcome if x is not None else "missing"   # type: ignore[arg-type]
                       for x in (r["auto"], r["tfl"], r["safe"])),
        peaks=tuple((x.peak_distance_m, x.peak_time_s) if x is not None else (None, None)
                    for x in (r["auto"], r["tfl"], r["safe"])))


@dataclass(frozen=True)
class FamilySummary:
    """A family's cases: how many, how many within the rule, the supervised flights'
    switches in total (those known) and their mean share of ticks in the safe law."""

    family: str
    cases: int
    within_rule: int
    switches: int
    mean_safe_share: float


def summarize(verdicts: Sequence[LawsVerdict]) -> list[FamilySummary]:
    """One summary per family, in the order the families first appear."""
    by_family: dict[str, list[LawsVerdict]] = {}
    for v in verdicts:
        by_family.setdefault(v.family, []).append(v)
    return [FamilySummary(
        family=fam, cases=len(vs), within_rule=sum(v.within_rule for v in vs),
        switches=sum(v.switches for v in vs if v.switches is not None),
        mean_safe_share=sum(v.safe_share for v in vs) / len(vs))
        for fam, vs in by_family.items()]


def _cell(d: float, outcome: str) -> str:
    if math.isfinite(d):
        return fmt_mm(d)
    return {"crashed": "crash", "error": "error", "n/a": "n/a",
            "missing": "—"}.get(outcome, "∞")


def _peak_text(peak: tuple[float | None, float | None]) -> str | None:
    d, t = peak
    if d is None or t is None or not math.isfinite(d):
        return None
    return f"{fmt_mm(d)} mm at {t:.1f} s"


def _rule_cell(v: LawsVerdict) -> str:
    if v.within_rule:
        return "ok"
    if math.isinf(v.margin_m):
        return "worse: crash"
    text = f"worse by {fmt_distance(v.margin_m)}"
    if len(v.peaks) == len(LAWS):
        auto = _peak_text(v.peaks[0])
        best = _peak_text(v.peaks[LAWS.index(v.best_single_law)])
        if auto and best:
            text += f"; peaks after the approach {auto}, {v.best_single_law} {best}"
    return text


def summary_line(s: FamilySummary) -> str:
    """``seam: 23 of 26 supervised flights within max(10 %, 0.05 mm) of the better single
    law; 101 law switches; safe law 39 % of the ticks on average``."""
    return (f"{s.family}: {s.within_rule} of {s.cases} supervised flights within {RULE_TEXT} "
            f"of the better single law; {s.switches} law switches; safe law "
            f"{100 * s.mean_safe_share:.0f} % of the ticks on average")


def laws_markdown(verdicts: Sequence[LawsVerdict], command: str = "") -> str:
    """The table (one row a case) and one summary line per family; ``command``: what made
    it, named in the lead sentence."""
    lines = []
    if command:
        lines += [f"Generated by `{command}`: each case flown offline as the envelope flies "
                  "it (the attack found from ESC rpm) by the supervisor (*auto*), TFL alone "
                  "and the safe law alone (`controller.supervisor`); max distance to the path "
                  "over the last 10 s in mm (*crash*: the vehicle was lost), the supervised "
                  "flight's law switches and share of ticks in the safe law (recovery, "
                  f"lost_rotor, spin); *rule*: the supervisor within {RULE_TEXT} of the "
                  "better single law, and where it is not, each flight's largest distance "
                  "from a third of the flight on (past the approach) and when.", ""]
    lines += ["| case | auto (mm) | switches | safe law | TFL alone (mm) | safe alone (mm) "
              "| rule |",
              "| --- | ---: | ---: | ---: | ---: | ---: | --- |"]
    for v in verdicts:
        switches = "?" if v.switches is None else str(v.switches)
        lines.append(f"| {v.case} | {_cell(v.auto_m, v.outcomes[0])} | {switches} | "
                     f"{100 * v.safe_share:.0f} % | {_cell(v.tfl_m, v.outcomes[1])} | "
                     f"{_cell(v.safe_m, v.outcomes[2])} | {_rule_cell(v)} |")
    for s in summarize(verdicts):     # a paragraph each, so Markdown keeps them apart
        lines += ["", summary_line(s)]
    return "\n".join(lines) + "\n"


def _finite_or_none(d: float) -> float | None:
    return d if math.isfinite(d) else None


def laws_json(cases: Sequence[Case], flown: Mapping[str, CaseResult]) -> dict[str, Any]:
    """Every case's three results and its verdict, and the family summaries (distances in
    m; null where the flight crashed or did not run)."""
    verdicts = [judge_laws(c, flown) for c in cases]
    out_cases = []
    for c, v in zip(cases, verdicts, strict=True):
        runs = {}
        for law in LAWS:
            r = flown.get(law_run_name(c.name, law))
            runs[law] = None if r is None else {**r.to_json(), "wall_time_s": r.wall_time_s}
        out_cases.append({
            "name": c.name, "family": c.family, **runs,
            "verdict": {"auto_m": _finite_or_none(v.auto_m), "tfl_m": _finite_or_none(v.tfl_m),
                        "safe_m": _finite_or_none(v.safe_m),
                        "best_single_m": _finite_or_none(v.best_single_m),
                        "within_rule": v.within_rule, "best_single_law": v.best_single_law,
                        "law_switches": v.switches,
                        "safe_law_share": v.safe_share}})
    return {"rule": f"auto within {RULE_TEXT} of the better of tfl and safe (a crash is "
                    "infinitely far)",
            "cases": out_cases,
            "families": [{"family": s.family, "cases": s.cases, "within_rule": s.within_rule,
                          "law_switches": s.switches, "mean_safe_law_share": s.mean_safe_share}
                         for s in summarize(verdicts)]}
