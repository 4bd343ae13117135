"""The regression rule (tools/harness/envelope/regression.py), on hand-made results: no
flights."""

from __future__ import annotations

import math

import pytest

from tfl_mav.tools.harness.envelope.regression import judge, worse_limit_m
from tfl_mav.tools.harness.envelope.results import CaseResult, outcome_of


def result(outcome: str = "converged", mm: float | None = 1.0, detected: int | None = 2,
           attacked: int = 2, settings: tuple[str, ...] = ()) -> CaseResult:
    return CaseResult(name="c", outcome=outcome,
                      max_distance_m=None if mm is None else mm / 1000.0,
                      attack_rotor=attacked, detected_rotor=detected, base="paper",
                      settings=settings)


def test_the_same_flight_is_the_same() -> None:
    assert judge(result(), result()).status == "same"


@pytest.mark.parametrize(("base_mm", "limit_mm"), [(1.0, 1.1), (0.1, 0.15), (0.5, 0.55),
                                                   (200.0, 220.0), (0.0, 0.05)])
def test_the_limit_is_ten_percent_or_five_hundredths_of_a_mm(base_mm: float,
                                                             limit_mm: float) -> None:
    assert math.isclose(worse_limit_m(base_mm / 1000), limit_mm / 1000, rel_tol=1e-12)


def test_just_inside_the_limit_passes_and_just_outside_fails() -> None:
    assert judge(result(mm=1.0999), result(mm=1.0)).status == "same"
    v = judge(result(mm=1.1001), result(mm=1.0))
    assert v.failed and "1.100 mm > 1.100 mm" in v.reasons[0]
    assert judge(result(mm=0.1499), result(mm=0.1)).status == "same"
    assert judge(result(mm=0.1501), result(mm=0.1)).failed


def test_a_new_crash_fails_and_a_crash_that_stays_does_not() -> None:
    v = judge(result("crashed", mm=5.0), result(mm=1.0))
    assert v.failed and v.reasons[0].startswith("crashed")
    # both crashed: the distance before the crash is not a tracking figure
    assert judge(result("crashed", mm=900.0), result("crashed", mm=1.0)).status == "same"


def test_a_flight_error_fails() -> None:
    assert judge(result("error", mm=None, detected=None), result()).failed


def test_a_crash_that_no_longer_happens_is_an_improvement() -> None:
    v = judge(result("off-path", mm=75.0), result("crashed", mm=3000.0))
    assert v.status == "improved" and not v.failed
    # however far off it flies: the crashed flight's distance is not a tracking figure
    v = judge(result("off-path", mm=500.0), result("crashed", mm=2.0))
    assert v.status == "improved" and v.reasons == ("no longer crashed: off-path",)


def test_off_path_getting_further_off_fails() -> None:
    assert judge(result("off-path", mm=200.0), result("off-path", mm=75.0)).failed
    assert judge(result("off-path", mm=80.0), result("off-path", mm=75.0)).status == "same"


def test_a_non_finite_distance_where_the_baseline_had_one_fails() -> None:
    assert judge(result("off-path", mm=None), result("off-path", mm=75.0)).failed


def test_better_beyond_the_slack_is_reported_never_failed() -> None:
    v = judge(result(mm=0.1), result(mm=3.0))
    assert v.status == "improved" and not v.failed
    assert judge(result(mm=0.96), result(mm=1.0)).status == "same"


def test_another_rotor_detected_fails() -> None:
    v = judge(result(detected=3), result(detected=2))
    assert v.failed and "detected rotor 3" in v.reasons[0]
    assert judge(result(detected=0), result(detected=2)).failed     # now missed


def test_a_false_alarm_without_attack_fails() -> None:
    assert judge(result(detected=1, attacked=0), result(detected=0, attacked=0)).failed


def test_the_right_rotor_where_the_baseline_was_wrong_is_an_improvement() -> None:
    v = judge(result(detected=2), result(detected=0))
    assert v.status == "improved"


def test_worse_and_better_at_once_is_worse() -> None:
    v = judge(result(mm=5.0, detected=2), result(mm=1.0, detected=0))
    assert v.status == "regressed" and len(v.reasons) == 2


def test_no_baseline_or_an_edited_case_fails_until_the_baseline_is_rewritten() -> None:
    assert judge(result(), None).failed
    v = judge(result(settings=("attack.rotor=3",)), result())
    assert v.failed and "changed" in v.reasons[0]


@pytest.mark.parametrize(("crashed", "mm", "outcome"), [
    (False, 20.0, "converged"), (False, 20.001, "off-path"), (True, 0.1, "crashed"),
    (False, None, "off-path"), (False, math.inf, "off-path")])
def test_outcome(crashed: bool, mm: float | None, outcome: str) -> None:
    assert outcome_of(crashed, None if mm is None else mm / 1000.0) == outcome
