"""The envelope spec and its committed files: fast checks, no flights."""

from __future__ import annotations

from pathlib import Path

import pytest

from tfl_mav.scenario import apply_overrides, load_scenario
from tfl_mav.tools.harness.envelope.report import markdown, readme_block
from tfl_mav.tools.harness.envelope.results import (
    OUTCOMES,
    default_baseline_path,
    read_results_file,
    reference_files,
)
from tfl_mav.tools.harness.envelope.spec import (
    EnvelopeSpecError,
    case_scenario,
    load_envelope,
    spec_from_dict,
)

REPO = Path(__file__).resolve().parents[2]
SPEC = load_envelope()

# The families the envelope must cover (what the law has lost before, and the rest of the
# attack class): a family dropped from the spec fails here, not silently.
FAMILIES = ("paper", "exact", "model2", "model5", "signal", "high", "dead", "circle", "path",
            "initial", "spin", "lag", "noise", "rate", "infeasible", "long", "sentinel")


def test_at_least_120_cases_with_unique_names() -> None:
    names = [c.name for c in SPEC.cases]
    assert len(names) >= 120
    assert len(set(names)) == len(names)


def test_every_family_is_present_and_not_empty() -> None:
    present = {c.family for c in SPEC.cases}
    assert set(FAMILIES) <= present, set(FAMILIES) - present


def test_every_override_is_a_valid_scenario_key() -> None:
    for case in SPEC.cases:
        apply_overrides(load_scenario(case.base), list(case.settings))


def test_the_spec_covers_the_attack_class() -> None:
    scs = [case_scenario(c) for c in SPEC.cases]
    signals = {sc.attack.signal for sc in scs if sc.attack.rotor}
    assert {"paper", "constant", "step", "ramp", "sine", "stuck", "off"} <= signals
    assert any(s not in ("paper", "constant", "step", "ramp", "sine", "stuck", "off")
               for s in signals), "an expression signal"
    assert {1, 2, 3, 4, 0} <= {sc.attack.rotor for sc in scs}
    assert {"paper", "line", "circle", "helix", "lemniscate", "expr"} <= {
        sc.path.kind for sc in scs}
    assert {0.5, 1.0, 2.0, 3.0} <= {sc.path.params.get("radius_m", 2.0) for sc in scs
                                   if sc.path.kind == "circle"}
    assert {250.0, 500.0, 1000.0} <= {sc.run.control_hz for sc in scs}
    assert {2.0, 6.0, 8.0, 10.0} <= {sc.initial.body_rates_radps[2] for sc in scs}
    corners = {(sc.controller.model_mass_scale, sc.controller.model_inertia_scale)
               for sc in scs}
    for dm, dj in ((0.02, 0.1), (0.05, 0.2)):
        assert {(1 + sm * dm, 1 + sj * dj) for sm in (1, -1) for sj in (1, -1)} <= {
            (round(m, 6), round(j, 6)) for m, j in corners}
    lag = {(sc.vehicle.motor_time_constant_s, sc.controller.model_mass_scale,
            sc.controller.model_inertia_scale) for sc in scs if sc.attack.signal == "paper"}
    for tau in (0.02, 0.05):
        assert {(tau, m, j) for m in (0.98, 1.02) for j in (0.9, 1.1)} <= lag
    assert {0.0, 3.0, 5.0} <= {sc.attack.start_s for sc in scs if sc.attack.signal == "off"}
    assert max(sc.run.duration_s for sc in scs) == 120.0


def _spec(*cases: dict, **family: object) -> dict:
    return {"family": [{"name": "f", "title": "t", "base": "paper", **family,
                        "case": list(cases)}]}


@pytest.mark.parametrize(("data", "message"), [
    (_spec({"name": "a"}, {"name": "a"}), "case 'a': case name used twice"),
    (_spec({"name": "a", "set": ["attack.nope=1"]}), "case 'a': attack.nope: unknown key"),
    (_spec({"name": "a", "set": ["path.kind=spiral"]}), "case 'a': path.kind: unknown kind"),
    (_spec({"name": "a", "set": "attack.rotor=1"}), "case 'a': set must be a list"),
    (_spec({"name": "a", "base": "nowhere"}), "case 'a': base 'nowhere' is not a built-in"),
    (_spec({"name": "a", "colour": 1}), "case 'a': unknown key 'colour'"),
    (_spec({"name": "a"}, duration_s=-1), "family 'f': duration_s must be a number > 0"),
    ({"family": []}, "expected [[family]] tables"),
])
def test_a_bad_spec_fails_with_one_line_naming_the_case(data: dict, message: str) -> None:
    with pytest.raises(EnvelopeSpecError) as err:
        spec_from_dict(data, "x.toml")
    text = str(err.value)
    assert "\n" not in text and text.startswith("x.toml: ") and message in text, text


def test_the_baseline_holds_every_case_as_the_spec_has_it() -> None:
    baseline = read_results_file(default_baseline_path())
    for case in SPEC.cases:
        b = baseline.get(case.name)
        assert b is not None, f"{case.name}: not in the baseline (tfl-mav envelope " \
                              f"--rewrite-baseline --only {case.name})"
        assert (b.base, b.settings) == (case.base, case.settings), \
            f"{case.name}: edited since its baseline was flown"
        assert b.outcome in OUTCOMES
    assert set(baseline.results) == {c.name for c in SPEC.cases}


def test_readme_envelope_block_is_generated_from_the_committed_baseline() -> None:
    """A stale figure fails here: fix with `tfl-mav envelope --markdown --write-readme`."""
    baseline = read_results_file(default_baseline_path())
    refs = [read_results_file(p) for p in reference_files()]
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    assert readme_block(readme) == markdown(SPEC, baseline, refs, every_case=False), \
        "README envelope table is stale: tfl-mav envelope --markdown --write-readme"
    doc = (REPO / "docs" / "envelope.md").read_text(encoding="utf-8")
    assert readme_block(doc) == markdown(SPEC, baseline, refs), \
        "docs/envelope.md is stale: tfl-mav envelope --markdown --write-readme"
