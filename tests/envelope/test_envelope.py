"""The envelope tier: every case of the spec flown today, judged against its baseline.

One test per case (its id is the case name). A failure names the case, the baseline and
today's flight and why it is worse (the rule: tools/harness/envelope/regression.py). The flights
are the session's (conftest.py), flown with the law's Python core like the rest of the suite
(the compiled core gives the same bits).
"""

from __future__ import annotations

import pytest

from tfl_mav.tools.harness.envelope.regression import Verdict, judge
from tfl_mav.tools.harness.envelope.report import detection_text, result_text
from tfl_mav.tools.harness.envelope.results import (
    CaseResult,
    default_baseline_path,
    read_results_file,
)
from tfl_mav.tools.harness.envelope.spec import load_envelope

pytestmark = [pytest.mark.envelope, pytest.mark.slow]

CASES = [c.name for c in load_envelope().cases]
BASELINE = read_results_file(default_baseline_path())


@pytest.mark.parametrize("case_name", CASES, ids=CASES)
def test_case_is_no_worse_than_its_baseline(
        case_name: str, envelope_results: dict[str, CaseResult],
        envelope_improvements: dict[str, Verdict]) -> None:
    now = envelope_results[case_name]
    base = BASELINE.get(case_name)
    verdict = judge(now, base)
    if verdict.status == "improved":
        envelope_improvements[case_name] = verdict
    assert not verdict.failed, (
        f"{case_name}: {'; '.join(verdict.reasons)} | baseline: {result_text(base)}, "
        f"{detection_text(base)} | now: {result_text(now)}, {detection_text(now)}")
