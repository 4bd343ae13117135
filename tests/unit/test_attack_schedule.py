"""An attacker that moves between rotors ([[attack.phases]]): which rotor, from when, with
which signal; letting go; and the scenario's checks."""

from __future__ import annotations

import pytest

from tfl_mav.scenario import AttackConfig, AttackPhase, ScenarioError, scenario_from_dict
from tfl_mav.sitl.attacker import NO_ATTACK, Attacker

X = (0.0, 0.0, 2.0)


def _attacker(phases, **kw) -> Attacker:
    return Attacker(AttackConfig(phases=phases, **kw), 8.0)


def _walk(att: Attacker, times):
    out = []
    for t in times:
        # the simulator's own test (inlined there) before it samples
        s = att.sample(t, X, 2.5) if att.rotor and t >= att.start_s else NO_ATTACK
        out.append((s.rotor, s.applied_n))
    return out


def test_phases_move_the_attack_and_let_go():
    att = _attacker([{"rotor": 2, "start_s": 1.0, "signal": "constant"},
                     {"rotor": 0, "start_s": 2.0},
                     {"rotor": 4, "start_s": 3.0, "signal": "1 + tau"},
                     {"rotor": 1, "start_s": 4.0, "signal": "off"}], value_n=1.5)
    got = _walk(att, [0.0, 0.999, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 9.0])
    assert got == [(0, 0.0), (0, 0.0), (2, 1.5), (2, 1.5), (0, 0.0), (0, 0.0),
                   (4, 1.0), (4, 1.5), (1, 0.0), (1, 0.0)]
    assert att.moves == [(1.0, 2), (2.0, 0), (3.0, 4), (4.0, 1)]


def test_a_schedule_skipped_over_in_one_step_lands_on_the_phase_in_force():
    att = _attacker([{"rotor": 2, "start_s": 0.0, "signal": "constant"},
                     {"rotor": 3, "start_s": 1.0, "signal": "constant"},
                     {"rotor": 1, "start_s": 1.01, "signal": "off"}], value_n=2.0)
    assert _walk(att, [0.5]) == [(2, 2.0)]
    # one sample per phase boundary crossed: the next sample is the next phase's
    assert _walk(att, [1.02, 1.03]) == [(3, 2.0), (1, 0.0)]


def test_without_phases_the_attack_is_the_sections_own():
    att = Attacker(AttackConfig(rotor=3, start_s=0.5, signal="constant", value_n=2.0), 8.0)
    assert _walk(att, [0.0, 0.5, 30.0]) == [(0, 0.0), (3, 2.0), (3, 2.0)]
    assert att.moves == []


def test_phases_from_toml_shaped_data_and_back():
    sc = scenario_from_dict({"attack": {"phases": [
        {"rotor": 2, "start_s": 0.0}, {"rotor": 3, "start_s": 5.0, "signal": "stuck"}]}})
    assert sc.attack.phases == (AttackPhase(2, "paper", 0.0), AttackPhase(3, "stuck", 5.0))
    assert sc.attack.first_rotor == 2
    data = sc.to_dict()
    data.pop("source")
    assert scenario_from_dict(data).attack == sc.attack
    assert scenario_from_dict({"attack": {"phases": [{"rotor": 0, "start_s": 1.0},
                                                     {"rotor": 4, "start_s": 2.0}]}}
                              ).attack.first_rotor == 4


@pytest.mark.parametrize(("phases", "key", "words"), [
    ([{"rotor": 2, "start_s": 3.0}, {"rotor": 1, "start_s": 1.0}], "attack.phases[1].start_s",
     "after the previous phase"),
    ([{"rotor": 7, "start_s": 0.0}], "attack.phases[0].rotor", "[0, 4]"),
    ([{"rotor": 1}], "attack.phases[0].start_s", "missing"),
    ([{"rotor": 1, "start_s": 0.0, "signal": "t +"}], "attack.phases[0].signal", ""),
    ([{"rotor": 1, "start_s": 0.0, "when": 1}], "attack.phases[0].when", "unknown key"),
])
def test_bad_phases_name_the_key(phases, key, words):
    with pytest.raises(ScenarioError) as info:
        scenario_from_dict({"attack": {"phases": phases}})
    assert info.value.key == key and words in info.value.message
    assert "\n" not in str(info.value)


def test_the_first_phase_may_start_late():
    att = _attacker([{"rotor": 1, "start_s": 2.0, "signal": "constant"}], value_n=3.0)
    assert _walk(att, [1.0, 2.0]) == [(0, 0.0), (1, 3.0)]
