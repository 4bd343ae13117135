"""The envelope tier's flights: flown once per session, in a pool, for the selected cases.

Only the cases whose tests were collected and selected (``-k``, a node id) are flown, so
``python -m pytest tests/envelope -k dead`` costs the dead-rotor flights only. Improvements
on the baseline are listed at the end of the run: they never fail, but the baseline should
be rewritten to keep them (``tfl-mav envelope --rewrite-baseline``).
"""

from __future__ import annotations

import pytest

from tfl_mav.tools.harness.envelope.regression import Verdict
from tfl_mav.tools.harness.envelope.results import CaseResult
from tfl_mav.tools.harness.envelope.run import default_jobs, fly_cases
from tfl_mav.tools.harness.envelope.spec import load_envelope

_IMPROVED = pytest.StashKey[dict[str, Verdict]]()


@pytest.fixture(scope="session")
def envelope_results(request: pytest.FixtureRequest) -> dict[str, CaseResult]:
    """Every selected case's flight today, keyed by case name."""
    selected = {item.callspec.params["case_name"] for item in request.session.items
                if item.get_closest_marker("envelope") is not None
                and "case_name" in getattr(getattr(item, "callspec", None), "params", {})}
    cases = [c for c in load_envelope().cases if c.name in selected]
    return fly_cases(cases, jobs=default_jobs())


@pytest.fixture(scope="session")
def envelope_improvements(request: pytest.FixtureRequest) -> dict[str, Verdict]:
    """Where the tests put the cases that did better than their baseline (for the summary)."""
    return request.config.stash.setdefault(_IMPROVED, {})


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    improved = terminalreporter.config.stash.get(_IMPROVED, {})
    if not improved:
        return
    terminalreporter.section("envelope: better than the baseline")
    for name, verdict in sorted(improved.items()):
        terminalreporter.write_line(f"{name}: {'; '.join(verdict.reasons)}")
    terminalreporter.write_line("keep them: tfl-mav envelope --rewrite-baseline (and commit "
                                "baseline.json with its table)")
