"""Golden results: refactors that are not meant to change behaviour keep flights bit-identical.

The files in tests/golden/ were captured by ``python tests/golden/capture.py`` on a commit
known to be right; each holds the deterministic summary of a flight plus SHA-256 digests of
its whole true trajectory and of every commanded thrust. A change that is *meant* to change
behaviour recaptures them and says so in its commit.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tfl_mav.tools.harness.golden import (
    LOCKSTEP_CASES,
    OFFLINE_CASES,
    fly_lockstep,
    fly_offline_case,
)

GOLDEN = Path(__file__).resolve().parent

_OFFLINE = json.loads((GOLDEN / "offline.json").read_text())
_LOCKSTEP = json.loads((GOLDEN / "lockstep.json").read_text())


@pytest.mark.parametrize("name", sorted(OFFLINE_CASES))
def test_offline_flight_is_bit_identical(name):
    assert fly_offline_case(*OFFLINE_CASES[name]) == _OFFLINE[name]


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(LOCKSTEP_CASES))
def test_lockstep_flight_over_mavlink_is_bit_identical(name, tmp_path):
    assert fly_lockstep(*LOCKSTEP_CASES[name], out=tmp_path) == _LOCKSTEP[name]
