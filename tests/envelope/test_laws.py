"""``tfl-mav envelope --laws``: the supervisor against each law alone.

The verdict, the family summary and the table on hand-built results (pure logic), the
command's usage errors, and one real envelope case flown three ways in a subprocess.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from tfl_mav.tools.cli.main import main
from tfl_mav.tools.harness.envelope.laws import (
    LAWS,
    LAWS_BEGIN,
    LAWS_END,
    distance_m,
    judge_laws,
    law_run_name,
    law_runs,
    laws_json,
    laws_markdown,
    safe_law_share,
    summarize,
)
from tfl_mav.tools.harness.envelope.report import readme_block
from tfl_mav.tools.harness.envelope.results import CaseResult
from tfl_mav.tools.harness.envelope.spec import Case, load_envelope

MM = 1e-3


def _result(name: str, mm: float | None, *, outcome: str | None = None, switches: int = 0,
            modes: dict[str, float] | None = None) -> CaseResult:
    """A flight ending ``mm`` off the path (None: crashed)."""
    if outcome is None:
        outcome = "crashed" if mm is None else ("converged" if mm <= 20 else "off-path")
    return CaseResult(name=name, outcome=outcome,
                      max_distance_m=None if mm is None else mm * MM,
                      mode_fraction=modes or {"attacked": 1.0}, law_switches=switches)


def _flown(case: Case, auto: float | None, tfl: float | None, safe: float | None,
           **auto_kw) -> dict[str, CaseResult]:
    return {law_run_name(case.name, "auto"): _result(f"{case.name}@auto", auto, **auto_kw),
            law_run_name(case.name, "tfl"): _result(f"{case.name}@tfl", tfl),
            law_run_name(case.name, "safe"): _result(f"{case.name}@safe", safe)}


CASE = Case("seam-x", "seam", "paper", ("attack.rotor=3",))


def test_every_case_is_flown_three_ways_with_the_supervisor_setting_last() -> None:
    other = Case("other", "fam", "circle", ())
    runs = law_runs([CASE, other])
    assert [r.name for r in runs] == [f"{c}@{law}" for c in ("seam-x", "other")
                                      for law in LAWS]
    assert runs[1].settings == ("attack.rotor=3", "controller.supervisor=tfl")
    assert runs[5].base == "circle" and runs[5].family == "fam"


def test_a_supervisor_that_flies_where_tfl_crashes_is_judged_against_the_safe_law() -> None:
    v = judge_laws(CASE, _flown(CASE, auto=0.4, tfl=None, safe=0.393))
    assert math.isinf(v.tfl_m) and v.best_single_m == pytest.approx(0.393 * MM)
    assert v.within_rule                    # 0.4 ≤ 0.393 + 0.05 mm


def test_a_tie_within_five_hundredths_of_a_mm_is_within_the_rule() -> None:
    # best 0.1 mm: 10 % is 0.01 mm, so the 0.05 mm floor sets the limit at 0.15 mm
    assert judge_laws(CASE, _flown(CASE, auto=0.149, tfl=0.1, safe=3.0)).within_rule
    assert not judge_laws(CASE, _flown(CASE, auto=0.151, tfl=0.1, safe=3.0)).within_rule


def test_ten_percent_of_the_better_law_is_within_the_rule() -> None:
    # best 2 mm (the safe law): 10 % = 0.2 mm beats the 0.05 mm floor
    assert judge_laws(CASE, _flown(CASE, auto=2.19, tfl=None, safe=2.0)).within_rule
    assert not judge_laws(CASE, _flown(CASE, auto=2.21, tfl=None, safe=2.0)).within_rule


def test_a_worse_supervisor_is_shown_with_its_margin() -> None:
    v = judge_laws(CASE, _flown(CASE, auto=1.107, tfl=0.897, safe=28.574, switches=19))
    assert not v.within_rule and v.margin_m == pytest.approx(0.21 * MM)
    row = laws_markdown([v]).splitlines()[2]
    assert row == "| seam-x | 1.107 | 19 | 0 % | 0.897 | 28.57 | worse by 0.210 mm |"


def test_a_worse_supervisor_shows_its_peak_and_the_better_law_s() -> None:
    # the last 10 s open on the decay of a bend both flights pass: the peaks say so
    flown = _flown(CASE, auto=1.100, tfl=None, safe=0.710)
    for law, (mm, t) in zip(LAWS, ((1.619, 19.49), (None, None), (1.586, 19.26)), strict=True):
        r = flown[law_run_name(CASE.name, law)]
        r.peak_distance_m, r.peak_time_s = (None if mm is None else mm * MM), t
    v = judge_laws(CASE, flown)
    assert v.best_single_law == "safe" and v.peaks[0] == (1.619 * MM, 19.49)
    assert laws_markdown([v]).splitlines()[2].endswith(
        "| worse by 0.390 mm; peaks after the approach 1.619 mm at 19.5 s, "
        "safe 1.586 mm at 19.3 s |")
    # a flight that does not report its peak (another tree's CLI): the margin alone
    flown[law_run_name(CASE.name, "safe")].peak_distance_m = None
    assert laws_markdown([judge_laws(CASE, flown)]).splitlines()[2].endswith(
        "| worse by 0.390 mm |")


def test_a_supervisor_crash_where_a_law_flies_is_worse_and_all_three_crashed_is_not() -> None:
    v = judge_laws(CASE, _flown(CASE, auto=None, tfl=5.0, safe=None))
    assert not v.within_rule and math.isinf(v.margin_m)
    assert laws_markdown([v]).splitlines()[2] == \
        "| seam-x | crash | 0 | 0 % | 5.000 | crash | worse: crash |"
    all_down = judge_laws(CASE, _flown(CASE, auto=None, tfl=None, safe=None))
    assert all_down.within_rule and all_down.margin_m == 0.0


def test_a_flight_that_did_not_run_or_left_no_distance_is_infinitely_far() -> None:
    assert distance_m(None) == math.inf
    assert distance_m(_result("e", None, outcome="error")) == math.inf
    assert distance_m(_result("n", 1.0, outcome="n/a")) == math.inf
    off = CaseResult(name="o", outcome="off-path", max_distance_m=math.nan)
    assert distance_m(off) == math.inf
    assert distance_m(_result("ok", 3.0)) == pytest.approx(3.0 * MM)


def test_the_safe_law_share_is_recovery_lost_rotor_and_spin() -> None:
    r = _result("s", 1.0, modes={"nominal": 0.1, "attacked": 0.2, "fallback": 0.05,
                                 "recovery": 0.15, "lost_rotor": 0.3, "spin": 0.2})
    assert safe_law_share(r) == pytest.approx(0.65)


def test_the_family_summary_counts_rule_switches_and_mean_safe_share() -> None:
    other = Case("other-y", "other", "paper", ())
    flown = {**_flown(CASE, auto=0.12, tfl=0.1, safe=1.0, switches=2,
                      modes={"attacked": 0.6, "lost_rotor": 0.4}),
             **_flown(other, auto=0.5, tfl=0.1, safe=None, switches=7,
                      modes={"attacked": 0.9, "recovery": 0.1})}
    second = Case("seam-z", "seam", "paper", ())
    flown.update(_flown(second, auto=9.0, tfl=None, safe=8.0, switches=1,
                        modes={"lost_rotor": 1.0}))
    verdicts = [judge_laws(c, flown) for c in (CASE, other, second)]
    seam, oth = summarize(verdicts)
    assert (seam.family, seam.cases, seam.within_rule, seam.switches) == ("seam", 2, 1, 3)
    assert seam.mean_safe_share == pytest.approx(0.7)
    assert (oth.cases, oth.within_rule, oth.switches) == (1, 0, 7)
    text = laws_markdown(verdicts, command="tfl-mav envelope --laws --write-readme")
    assert text.startswith("Generated by `tfl-mav envelope --laws --write-readme`")
    assert ("seam: 1 of 2 supervised flights within max(10 %, 0.05 mm) of the better single "
            "law; 3 law switches; safe law 70 % of the ticks on average") in text
    assert "\n\nother: 0 of 1 supervised flights" in text
    header = [c.strip() for c in text.split("\n\n")[1].splitlines()[0].strip("|").split("|")]
    assert header == ["case", "auto (mm)", "switches", "safe law", "TFL alone (mm)",
                      "safe alone (mm)", "rule"]


def test_the_json_holds_every_flight_and_no_infinity() -> None:
    flown = _flown(CASE, auto=0.4, tfl=None, safe=0.393, switches=2)
    out = json.loads(json.dumps(laws_json([CASE], flown), allow_nan=False))
    case = out["cases"][0]
    assert {"auto", "tfl", "safe"} <= set(case) and case["tfl"]["outcome"] == "crashed"
    assert case["verdict"]["tfl_m"] is None and case["verdict"]["within_rule"] is True
    assert case["verdict"]["best_single_m"] == pytest.approx(0.393 * MM)
    assert out["families"] == [{"family": "seam", "cases": 1, "within_rule": 1,
                                "law_switches": 2, "mean_safe_law_share": 0.0}]


@pytest.mark.parametrize("extra", [["--rewrite-baseline"], ["--compare"], ["--markdown"],
                                   ["--fly-reference", "/nonexistent"]])
def test_laws_with_a_mode_of_its_own_is_one_line_and_exit_2(
        extra: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["envelope", "--laws", *extra]) == 2
    err = capsys.readouterr().err
    assert err == f"tfl-mav envelope: --laws cannot be combined with {extra[0]}\n"


def test_write_readme_needs_markdown_or_laws(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["envelope", "--write-readme"]) == 2
    assert capsys.readouterr().err == ("tfl-mav envelope: --write-readme needs --markdown or "
                                       "--laws\n")


def test_laws_write_readme_without_the_markers_fails_before_flying(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "envelope.md").write_text("# no laws block here\n")
    assert main(["envelope", "--laws", "--only", "seam-*", "--write-readme", "--readme",
                 str(tmp_path / "README.md")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "<!-- laws:begin -->" in err and "flying" not in err


def test_the_docs_table_has_every_case_and_the_command_that_made_it() -> None:
    """A case added to or dropped from the spec leaves the table stale until re-flown."""
    doc = (Path(__file__).resolve().parents[2] / "docs" / "envelope.md").read_text("utf-8")
    block = readme_block(doc, (LAWS_BEGIN, LAWS_END))
    assert block.startswith("Generated by `tfl-mav envelope --laws --write-readme`")
    rows = [line.split("|")[1].strip() for line in block.splitlines()
            if line.startswith("| ")][2:]           # after the header and its rule
    assert rows == [c.name for c in load_envelope().select(None)]


# The cheapest case whose three flights differ: TFL alone drifts hundreds of mm off the
# path on the one-sided stretch; the supervisor hands the stretch to the safe law and back.
CHEAP = "seam-handback-r3-16"


@pytest.mark.slow
def test_one_case_flown_three_ways_through_the_cli() -> None:
    assert any(c.name == CHEAP for c in load_envelope().cases)
    proc = subprocess.run([sys.executable, "-m", "tfl_mav.tools.cli", "envelope", "--laws",
                           "--only", CHEAP, "--json", "--jobs", "2"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "[3/3]" in proc.stderr
    out = json.loads(proc.stdout)
    (case,) = out["cases"]
    assert case["name"] == CHEAP
    auto, tfl, safe, v = case["auto"], case["tfl"], case["safe"], case["verdict"]
    assert auto["settings"][-1] == "controller.supervisor=auto"
    # a single law never switches; the safe law alone flies every tick in a safe-law mode
    assert tfl["law_switches"] == 0 and safe["law_switches"] == 0
    assert sum(tfl["mode_fraction"].get(m, 0.0) for m in ("recovery", "lost_rotor", "spin")) \
        == 0.0
    assert safe["mode_fraction"].get("lost_rotor", 0.0) + \
        safe["mode_fraction"].get("recovery", 0.0) == pytest.approx(1.0, abs=1e-5)
    # the supervisor takes over for the stretch where A = 0 and hands back: ≥ 2 switches,
    # some but not all of the flight in the safe law
    assert auto["law_switches"] >= 2 and 0.0 < v["safe_law_share"] < 1.0
    assert v["auto_m"] == auto["max_distance_m"] and v["tfl_m"] == tfl["max_distance_m"]
    assert v["best_single_m"] == min(tfl["max_distance_m"], safe["max_distance_m"])
    # the envelope's claim for this case: the supervisor no worse than either law alone
    assert v["within_rule"] and auto["outcome"] == "converged"
